"""Planning in a worker process the service can stop.

Planning a mission's first tour and every replan (the roadmap, the coverage candidates and
their legs, the search) is the only work of the service whose memory and time grow with what
a client asks for. It runs in a child process (started from a ``forkserver`` that has the
planner imported already, so a child starts in milliseconds) under the request's budget:

- memory: the child's address space may grow by at most ``Limits.plan_memory_bytes``
  (``resource.setrlimit(RLIMIT_AS)``); an allocation beyond it fails in the child only;
- time: the child is killed after ``Limits.plan_seconds``;
- at most ``Limits.planners`` children run at once; a request that finds them all busy for
  ``Limits.plan_seconds`` is answered 503 (try again later).

A request over its budget is answered 422 with one line naming the budget; the server and
its other missions are untouched. The child answers with a plan's GeoJSON or the
error the planner raised (``InputError``: 422, as when planning in the server).
"""

from __future__ import annotations

import errno
import multiprocessing
import os
import resource
import threading
from dataclasses import dataclass

from orange_plan.errors import InputError, OrangeError

PRELOAD = ["orange_plan.service.worker", "orange_plan.service.missions",
           "orange_plan.service.warm_up"]
"""Modules the forkserver imports once, so that each planning child starts ready (and a
child's memory budget is not spent on mapping shared libraries): ``warm_up`` plans a small
tour on import."""

OUT_OF_MEMORY = ("failed to map segment", "load shared object", "cannot allocate memory",
                 "can't start new thread", "bad_alloc")
"""How a failed allocation shows when it is not a MemoryError: a shared library that could
not be mapped (the server, on the same installation, has loaded it), a thread without a
stack, a C++ allocation."""


class PlanningBudgetExceeded(InputError):
    """A plan needed more memory or time than the service gives one request."""


class PlannerBusy(OrangeError):
    """Every planning worker stayed busy for the whole wait."""


class PlannerFailed(OrangeError):
    """The planning process ended without an answer (not the client's fault)."""


@dataclass(frozen=True)
class Budget:
    """What one planning request may use.

    Attributes
    ----------
    memory_bytes : address space the worker may add to what it starts with [bytes]
    seconds : wall-clock time of one plan [s]
    workers : planning processes at once
    """

    memory_bytes: int
    seconds: float
    workers: int


class Planners:
    """Runs planning functions in child processes, within a ``Budget``."""

    def __init__(self, budget: Budget):
        self.budget = budget
        self._slots = threading.BoundedSemaphore(max(1, int(budget.workers)))

    def start(self) -> None:
        """Start the forkserver now (it then loads the planner in the background), so that
        the first plan does not wait for it."""
        from multiprocessing import forkserver

        self._context()
        forkserver.ensure_running()

    def run(self, func, *args, what: str = "planning"):
        """``func(*args)`` in a child process; its return value (picklable), or the error.

        Raises
        ------
        PlanningBudgetExceeded
            Over the memory or time budget (the child is stopped).
        PlannerBusy
            No worker became free within the time budget.
        PlannerFailed
            The child ended without an answer (killed by a signal, crashed).
        OrangeError
            What ``func`` raised (InputError for a request that cannot be planned).
        """
        if not self._slots.acquire(timeout=self.budget.seconds):
            raise PlannerBusy(f"all {self.budget.workers} planning workers stayed busy for "
                              f"{self.budget.seconds:g} s; try again later")
        try:
            status, value = self._in_child(func, args)
        finally:
            self._slots.release()
        if status == "ok":
            return value
        if status == "error":
            raise value
        raise self._failure(status, value, what)

    def _in_child(self, func, args) -> tuple[str, object]:
        mp = self._context()
        receive, send = mp.Pipe(duplex=False)
        child = mp.Process(target=_child, args=(send, func, args, self.budget.memory_bytes),
                           name="orange-plan-planner", daemon=True)
        child.start()
        send.close()  # the child's end: EOF here once the child is gone
        try:
            if not receive.poll(self.budget.seconds):
                return "time", None
            try:
                return receive.recv()
            except EOFError:  # the child died before answering
                child.join(5.0)
                return "died", child.exitcode
            except Exception as exc:  # noqa: BLE001 - an answer that cannot be unpickled
                return "crash", f"unreadable answer ({type(exc).__name__}: {exc})"
        finally:
            receive.close()
            if child.is_alive():
                child.kill()
            child.join(5.0)
            child.close()

    @staticmethod
    def _context():
        mp = multiprocessing.get_context("forkserver")
        mp.set_forkserver_preload(PRELOAD)
        return mp

    def _failure(self, status: str, value, what: str) -> OrangeError:
        budget = self.budget
        if status == "memory":
            return PlanningBudgetExceeded(
                f"{what} needed more than the service's memory budget of "
                f"{budget.memory_bytes / 2**30:.3g} GiB for one request and was stopped; ask "
                "for fewer roadmap vertices (n_vertices) or a larger sensor_radius_m")
        if status == "time":
            return PlanningBudgetExceeded(
                f"{what} took longer than the service's time budget of {budget.seconds:g} s "
                "for one request and was stopped; ask for fewer roadmap vertices (n_vertices) "
                "or a larger sensor_radius_m")
        if status == "died":
            return PlannerFailed(f"{what}: the planning process ended without an answer "
                                 f"(exit code {value})")
        return PlannerFailed(f"{what}: the planning process failed: {value}")


def _child(send, func, args, memory_bytes: int) -> None:
    """In the child: limit the address space, run, send ("ok", value) or the failure."""
    base = _address_space_bytes()
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = base + int(memory_bytes)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    answer = _answer(func, args)
    try:
        send.send(answer)
    except MemoryError:  # the answer itself did not fit: over the budget all the same
        send.send(("memory", None))
    finally:
        send.close()


def _answer(func, args) -> tuple[str, object]:
    try:
        return "ok", func(*args)
    except MemoryError:
        return "memory", None
    except OrangeError as exc:
        return "error", exc
    except Exception as exc:  # noqa: BLE001 - reported to the server as a failed planner
        if getattr(exc, "errno", None) == errno.ENOMEM or \
                any(sign in str(exc).lower() for sign in OUT_OF_MEMORY):
            return "memory", None
        return "crash", f"{type(exc).__name__}: {exc}"


def _address_space_bytes() -> int:
    """This process's current virtual memory size [bytes] (Linux ``/proc/self/statm``)."""
    with open("/proc/self/statm", encoding="ascii") as f:
        pages = int(f.read().split()[0])
    return pages * os.sysconf("SC_PAGE_SIZE")
