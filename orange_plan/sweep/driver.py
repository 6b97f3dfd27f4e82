"""A whole sweep: skip the runs already stored, run the rest on Dask, store each as it ends."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import pandas as pd

from orange_plan.cluster import dask_client, run_tasks
from orange_plan.sweep.spec import Sweep
from orange_plan.sweep.store import ResultStore
from orange_plan.sweep.task import run_one


@dataclass
class SweepOutcome:
    """What a call of ``run_sweep`` did.

    Attributes
    ----------
    rows : every row of the sweep (one per run), in sweep order
    ran : runs computed by this call
    skipped : runs found already stored (resumed)
    compute_s : wall clock from the first submission to the last result [s]
    """

    rows: pd.DataFrame
    ran: int
    skipped: int
    compute_s: float


def pending_runs(sweep: Sweep, store: ResultStore):
    """The sweep's runs not yet stored (refusing a store that holds another sweep's runs)."""
    store.check_belongs(r.run_id for r in sweep.runs)
    done = store.done_ids()
    return [r for r in sweep.runs if r.run_id not in done]


def run_sweep(sweep: Sweep, store: ResultStore, workers: int = 2, scheduler: str | None = None,
              tick: Callable[[], None] | None = None) -> SweepOutcome:
    """Run the sweep's pending runs (``workers`` local processes, or ``scheduler``'s cluster);
    each row is stored as its run ends, then the store is consolidated.

    Raises
    ------
    InputError
        A store holding another sweep's runs, a bad ``workers`` or ``scheduler``.
    """
    todo = pending_runs(sweep, store)
    t0 = time.perf_counter()
    if todo:
        def keep(_key: str, row: dict) -> None:
            store.add(row)
            if tick is not None:
                tick()

        with dask_client(workers, scheduler) as client:
            t0 = time.perf_counter()
            run_tasks(client, run_one, [(r.run_id, (r,)) for r in todo], keep)
    compute_s = time.perf_counter() - t0
    rows = store.consolidate()
    return SweepOutcome(rows, len(todo), len(sweep.runs) - len(todo), compute_s)
