"""Runs independent tasks on Dask: a local cluster on this machine, or an existing scheduler.

The local cluster is worker processes (the tasks are Python-bound, the GIL would serialise
threads) with one thread each, on 127.0.0.1, without the dashboard (it would need bokeh).
Tasks are submitted under their own key: Dask reruns a task whose worker died, and a second
client sweeping the same runs on a shared cluster shares the results instead of recomputing.
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from orange_plan.errors import InputError

SCHEDULER_RE = re.compile(r"^(tcp|tls)://[^\s/:]+:\d{1,5}$")

DEATH_TIMEOUT_S = 20
"""A local worker that has lost its scheduler (the sweep process was killed) exits after this
long instead of lingering [s]."""

CONNECT_TIMEOUT_S = 10
"""How long to try to reach an existing scheduler [s]."""


@contextlib.contextmanager
def dask_client(workers: int = 2, scheduler: str | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: of ``scheduler`` (used as it is), else of a new local cluster
    of ``workers`` processes; closed (and the local cluster shut down) on exit.

    Raises
    ------
    InputError
        For ``workers`` < 1, a malformed ``scheduler`` address or one that does not answer.
    """
    import dask
    from distributed import Client, LocalCluster

    if scheduler is not None:
        if not SCHEDULER_RE.match(scheduler):
            raise InputError(f"--scheduler {scheduler!r} must look like tcp://HOST:PORT")
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler {scheduler}: no Dask scheduler answers ({exc})") \
                from None
        with client:
            yield client
        return
    if workers < 1:
        raise InputError(f"--workers = {workers} must be >= 1")
    environ = worker_environ()
    with dask.config.set({ENVIRON_KEY: environ}), _environ_kept(environ), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                         host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR,
                         death_timeout=DEATH_TIMEOUT_S) as cluster, Client(cluster) as client:
        yield client


ENVIRON_KEY = "distributed.nanny.pre-spawn-environ"


@contextlib.contextmanager
def _environ_kept(keys) -> Iterator[None]:
    """Undo, on exit, what Dask's nanny writes into this process's own environment before
    spawning a worker (``os.environ.update(pre_spawn_env)``), which would otherwise reach
    every later subprocess of this process."""
    import os

    saved = {k: os.environ.get(k) for k in keys}
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def worker_environ() -> dict:
    """Dask's environment for worker processes without ``MALLOC_TRIM_THRESHOLD_``.

    Dask sets it to 64 KiB to hand freed memory back to the system early; our runs allocate
    and free many mid-sized numpy arrays, and with it a run took twice as long (measured:
    3.8 s instead of 1.9 s for a campus run, most of the extra in the kernel), and two workers
    slowed each other down further. glibc's own adaptive threshold is kept instead.
    """
    import dask

    environ = dict(dask.config.get(ENVIRON_KEY, {}))
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    return environ


def run_tasks(client, fn: Callable, tasks: Sequence[tuple[str, tuple]],
              on_result: Callable[[str, Any], None]) -> None:
    """Run ``fn(*args)`` for each ``(key, args)`` of ``tasks`` on the cluster; call
    ``on_result(key, result)`` in the caller's process as each finishes (any order).

    A task's exception is raised here once its task has failed (after Dask's retries of
    tasks whose worker died); results that arrived before it have been handed over.
    """
    from distributed import as_completed

    futures = {}
    for key, args in tasks:
        fut = client.submit(fn, *args, key=f"orange-plan-{key}", pure=False)
        futures[fut] = key
    try:
        for fut, result in as_completed(futures, with_results=True):
            on_result(futures[fut], result)
            fut.release()
    finally:
        client.cancel(list(futures))
