"""``bench concealed``: how long concealed-effect cases take to generate, and how far the
scenario handed to diagnosis misses each one (``predict``'s whole-run energy error).

The second figure is what diagnosis starts from: the share of the recorded energy that the
concealed physics carries as the scenario's model sees it (signed: > 0 over-predicts).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from orange_plan.sim.concealed import case_label, concealed_case, kept_by_name, suite_requests
from orange_plan.telemetry.replay import replay_context


@dataclass(frozen=True)
class ConcealedRow:
    """One generated case: ``seconds`` to generate it, its size, and the scenario model's
    whole-run ``energy_error_pct`` and ``rmse_W`` on it."""

    case: str
    label: str
    kind: str
    seconds: float
    samples: int
    mean_power_W: float
    energy_error_pct: float
    rmse_W: float

    def to_dict(self) -> dict:
        return asdict(self)


def labels_of(only: Sequence[str] | None) -> list[tuple[tuple[str, ...], str | None]]:
    """The suite's (terms, kind) requests, restricted to the labels ``only``.

    Raises
    ------
    InputError
        A label that is not one of the suite's.
    """
    requests = suite_requests()
    if not only:
        return requests
    kept = kept_by_name([case_label(t, k) for t, k in requests], only)
    return [r for r, keep in zip(requests, kept) if keep]


def concealed_benchmark(seeds: Sequence[int], duration_s: float, rate_Hz: float,
                        only: Sequence[str] | None = None,
                        progress: Callable[[], None] | None = None) -> list[ConcealedRow]:
    """Generate every requested case for every seed, timed, and replay it (predict)."""
    rows = []
    for seed in seeds:
        for terms, kind in labels_of(only):
            start = time.perf_counter()
            case = concealed_case(terms, seed, kind=kind, duration_s=duration_s, rate_Hz=rate_Hz)
            seconds = time.perf_counter() - start
            replay = replay_context(case.recording, case.ctx)
            rows.append(ConcealedRow(case.name, case_label(terms, kind), case.kind, seconds,
                                     len(case.frame), float(np.mean(replay.recorded_W)),
                                     replay.energy_error_pct, replay.rmse_W))
            if progress is not None:
                progress()
    return rows


def summarise_concealed(rows: Sequence[ConcealedRow]) -> list[dict]:
    """Per label: cases, median generation seconds, median and range of |energy error| [%]."""
    out = []
    for label in dict.fromkeys(r.label for r in rows):
        mine = [r for r in rows if r.label == label]
        err = np.abs([r.energy_error_pct for r in mine])
        out.append({"label": label, "kind": mine[0].kind, "cases": len(mine),
                    "seconds_median": float(np.median([r.seconds for r in mine])),
                    "abs_energy_error_pct_median": float(np.median(err)),
                    "abs_energy_error_pct_min": float(err.min()),
                    "abs_energy_error_pct_max": float(err.max()),
                    "rmse_W_median": float(np.median([r.rmse_W for r in mine]))})
    return out
