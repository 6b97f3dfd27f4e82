"""Imported once, by the planning workers' forkserver only (``worker.PRELOAD``).

Importing it plans one small tour on a built-in 40 x 30 m world, so that every planning
worker forked afterwards starts with what a first plan loads and compiles: the speed
profile's numba kernel (from its disk cache), CasADi's IPOPT plugin and solvers, OMPL.
Measured on ``rusti_v1_box`` with 100 vertices: a worker's plan took 1.5 s without it and
0.25 s once those were loaded. A failed warm-up only costs that time: it is logged, never
raised (the forkserver must start).
"""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path

from orange_plan.bench.maps import write_world
from orange_plan.context import load_context
from orange_plan.service.missions import SessionKind

log = logging.getLogger("orange_plan.service")


def warm_up() -> None:
    """Plan a small mission as the service would (same session options)."""
    import shapely

    with tempfile.TemporaryDirectory(prefix="orange-plan-warm-up-") as folder:
        scenario = write_world(Path(folder), "warm_up", 40.0, 30.0,
                               [shapely.box(18.0, 10.0, 22.0, 20.0)], (2.0, 2.0))
        SessionKind.new(load_context(scenario), n_vertices=60, seed=0)


try:
    warm_up()
except Exception as exc:  # noqa: BLE001 - see the module docstring
    log.warning("planning worker warm-up failed (%s: %s); workers start cold",
                type(exc).__name__, exc)
