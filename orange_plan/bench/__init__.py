"""Benchmarks of whole missions: ``bench plan`` (coverage with a guaranteed return).

``plan``: the benchmark runner and its results; ``px4_rtl``: the PX4-style return rule flown
in the simulator; ``maps``: the generated random family and the 2 km x 2 km map.
"""
