"""orange-plan: ORangE operational range estimation and energy-aware mission planning.

Implements the ORangE model of Tiwari, Xiao, Kyrki and Chong (simplified and generalised
operational range estimation) for ground, aerial and marine robots.
"""

__version__ = "0.1.0"
