"""Driven returns home, kept across replans: their motion does not depend on the energy model.

Every plan re-evaluates the return home from each vertex of its walk with the current model
(``tour.home_legs``). A return's sub-steps (exact terrain along its polyline) and the speed
profile the robot drives on it (``physics.profile``: ramps, duty-cycle stops) depend on the
world, the cruise speed, the acceleration limit and the duty cycle, not on the model's
coefficients nor on the wind and sensor rate (they enter only the power evaluated on them), and a replan's walk shares most of its vertices, hence most of its return
paths, with the plan before it. So each return's sub-steps and samples are kept, keyed by
the exact coordinates of its polyline, and a replan only evaluates the model's power on
them: the energies are the numbers a fresh drive gives (the same samples through the same
model evaluation), at a fraction of the cost.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from orange_plan.physics.pathcost import subdivide
from orange_plan.physics.profile import SAMPLE_DT_S, STOP_EVERY_S, drive_returns

MAX_PATHS = 1024
"""Return paths kept (least recently used dropped first): a campus tour's walk has ~130
distinct returns, so several replans' worth. About 0.2 MB per 500 m of return."""


class DrivenReturns:
    """Sub-steps and driven samples of return polylines, for one world and drive setting.

    ``driven(cost, paths)`` gives them for ``paths`` under ``cost`` (an ``EdgeCostContext``
    with an acceleration limit): kept ones are reused, the others driven (all at once) and
    kept. A different world (by identity), cruise speed, acceleration limit or duty cycle
    empties the store first, so nothing is reused across those.
    """

    def __init__(self, max_paths: int = MAX_PATHS):
        if max_paths < 1:
            raise ValueError(f"max_paths = {max_paths} must be >= 1")
        self.max_paths = max_paths
        self.hits = self.misses = 0
        self._kept: OrderedDict[bytes, tuple[object, dict]] = OrderedDict()
        self._world, self._setting = None, None
        self._lock = threading.Lock()  # a session's planner may serve several threads

    def __len__(self) -> int:
        return len(self._kept)

    def driven(self, cost, paths) -> tuple[list, list[dict]]:
        """(Steps, samples) of each polyline of ``paths`` (each (n, 2) [m]) driven from rest to
        rest at ``cost.speed_mps``: the ``physics.profile.drive_returns`` dicts."""
        setting = (float(cost.speed_mps), float(cost.accel_max_mps2),
                   cost.conditions.duty_cycle)
        keys = [np.ascontiguousarray(xy, dtype=float).tobytes() for xy in paths]
        with self._lock:
            if cost.world is not self._world or setting != self._setting:
                self._kept.clear()
                self._world, self._setting = cost.world, setting
            new = {key: np.asarray(xy, float) for key, xy in zip(keys, paths)
                   if key not in self._kept}
            self.misses += len(new)
            self.hits += len(keys) - len(new)
            if new:
                self._drive(cost, new)
            for key in keys:
                self._kept.move_to_end(key)
            found = [self._kept[key] for key in keys]
            while len(self._kept) > self.max_paths:
                self._kept.popitem(last=False)
        return [steps for steps, _ in found], [kin for _, kin in found]

    def _drive(self, cost, new: dict) -> None:
        steps = [subdivide(cost.world, xy[:-1], xy[1:]) for xy in new.values()]
        speeds = [st.per_step(np.full(st.n_segments, cost.speed_mps)) for st in steps]
        kins = drive_returns(steps, speeds, cost.accel_max_mps2, cost.conditions.duty_cycle,
                             SAMPLE_DT_S, STOP_EVERY_S)
        self._kept.update(zip(new, zip(steps, kins)))
