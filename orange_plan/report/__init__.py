"""``orange-plan report paper``: the ORangE paper's validation regenerated with the simulator.

A layer above ``sim``, ``identify`` and ``planning`` (none of them imports it): one module per
experiment (``rusti_v1``, ``rusti_v2``, ``ar_drone``, ``real_data``, ``wear``), ``trials`` for
what they share (truth draws, runs to depletion, range estimates, statistics) and
``markdown`` for the written report; ``paper`` runs them all.
"""
