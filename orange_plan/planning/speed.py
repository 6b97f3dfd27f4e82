"""Speed profile along a path: per-piece speeds minimising energy (or time), CasADi + IPOPT.

Problem statement (``SpeedProblem``): a path cut into N straight pieces i with length L_i,
grade, direction and rolling coefficient; choose speeds v_i to

    minimise   sum_i E_i(v_i)                      (objective "energy", reference-model energy)
    or         sum_i L_i / (v_i D)                 (objective "time": mission time)
    subject to v_min <= v_i <= v_max
               |v_{i+1}^2 - v_i^2| <= 2 a_max L_i  (constant-acceleration limit)
               sum_i L_i / (v_i D) <= T            (optional time limit, energy objective)
               sum_i E_i(v_i) <= E_budget          (energy budget, time objective)

``E_i`` is ``EnergyModel.segment_energy`` evaluated on CasADi MX symbols: the very term code
the planner evaluates on numpy arrays (no physics written twice).

How it is solved (``SpeedSolver``): one parametric MX ``nlpsol`` (IPOPT) per (N, objective),
built once and cached; the pieces' geometry is the parameter vector, so a new path of the
same N only re-solves, warm-started from the previous speeds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from orange_plan.errors import InputError, PlanningError
from orange_plan.mission import check_time_limit
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.pathcost import Steps, path_energy, subdivide
from orange_plan.physics.state import MotionState
from orange_plan.planning.paths import dedupe

if TYPE_CHECKING:
    from orange_plan.context import Context

TIGHTEN_ROUNDS = 4
"""Re-solves allowed to bring the driven profile within a time limit or energy budget."""

FIELDS = ("length_m", "cos_t", "sin_t", "dir_x", "dir_y", "crr", "surface_code")


@dataclass(frozen=True)
class PathPieces(Steps):
    """A path cut into N straight pieces with their terrain (the speed problem's data): the
    ``physics.pathcost.Steps`` of one step per piece, with the pieces' end points.

    Attributes
    ----------
    xy_m : the N + 1 piece end points [m]
    (and every ``Steps`` attribute: length_m, cos_t, sin_t, dir_x, dir_y, crr, surface_code)
    """

    xy_m: np.ndarray

    @property
    def n(self) -> int:
        return len(self.length_m)

    def values(self) -> dict[str, np.ndarray]:
        """The per-piece arrays the speed problem is parametrised by (``FIELDS``)."""
        return {f: np.asarray(getattr(self, f), float) for f in FIELDS}


def cut_path(world, path_xy, n_pieces: int) -> PathPieces:
    """Resample a polyline into ``n_pieces`` pieces of (nearly) equal length, keeping corners.

    Each original segment gets a number of pieces proportional to its length (at least one),
    so the pieces follow the path exactly.
    """
    p = dedupe(path_xy)
    if len(p) < 2:
        raise InputError("the path has zero length")
    seg = np.hypot(*np.diff(p, axis=0).T)
    if n_pieces < len(seg):
        raise InputError(f"n_pieces = {n_pieces} is fewer than the path's {len(seg)} segments")
    count = np.maximum(1, np.floor(seg / seg.sum() * n_pieces).astype(int))
    while count.sum() < n_pieces:  # hand the remainder to the longest pieces
        count[np.argmax(seg / count)] += 1
    while count.sum() > n_pieces:
        count[np.argmax(np.where(count > 1, seg / count, -1))] -= 1
    pts = [p[0]]
    for a, b, c in zip(p[:-1], p[1:], count):
        t = np.arange(1, c + 1)[:, None] / c
        pts.extend(a + (b - a) * t)
    xy = np.array(pts)
    steps = subdivide(world, xy[:-1], xy[1:], step_m=np.inf)  # one step per piece
    return PathPieces(**vars(steps), xy_m=xy)


@dataclass(frozen=True)
class SpeedProblem:
    """What the speed optimiser is asked (the statement, apart from how it is solved).

    Attributes
    ----------
    pieces : the path's pieces
    v_min_mps, v_max_mps : speed bounds [m/s]
    accel_max_mps2 : acceleration / deceleration limit [m/s^2]
    conditions : duty cycle, sensor rate and wind (``physics.conditions``)
    objective : "energy" or "time"
    time_limit_s : mission-time limit for "energy" (None: none) [s]
    energy_budget_J : energy limit for "time" [J]
    piece_v_max_mps : optional per-piece speed cap below v_max (e.g. where a sensor must keep
        up) [m/s]; clipped to [v_min, v_max]
    """

    pieces: PathPieces
    v_min_mps: float
    v_max_mps: float
    accel_max_mps2: float
    conditions: Conditions
    objective: str = "energy"
    time_limit_s: float | None = None
    energy_budget_J: float | None = None
    piece_v_max_mps: np.ndarray | None = None

    def __post_init__(self):
        if self.objective not in ("energy", "time"):
            raise InputError(f"objective = {self.objective!r} must be 'energy' or 'time'")
        if not 0 < self.v_min_mps <= self.v_max_mps:
            raise InputError(f"need 0 < v_min_mps <= v_max_mps, got {self.v_min_mps}, "
                             f"{self.v_max_mps}")
        if not self.accel_max_mps2 > 0:
            raise InputError(f"accel_max_mps2 = {self.accel_max_mps2} must be > 0")
        if self.objective == "time" and self.energy_budget_J is None:
            raise InputError("objective 'time' needs an energy_budget_J")
        fastest = float(np.sum(self.pieces.length_m)
                        / (self.v_max_mps * self.conditions.duty_cycle))
        if self.time_limit_s is not None and self.time_limit_s < fastest:
            raise InputError(f"time_limit_s = {self.time_limit_s:g} s is shorter than the path "
                             f"takes at v_max ({fastest:.6g} s)")


@dataclass(frozen=True)
class SpeedProfile:
    """Optimised speeds and the exact figures of the resulting motion.

    Attributes
    ----------
    xy_m : piece end points (N + 1, 2) [m]; speed_mps : per piece (N,) [m/s]
    energy_J : ``path_energy`` at these speeds (exact terrain, reference-model sub-steps, the driven
        profile with its ramps and stops when a World is given) [J]
    duration_s : mission time [s]
    iterations : IPOPT iterations; solve_seconds : wall-clock of the solve [s]
    pieces_energy_J : energy as the NLP sees it (one step per piece) [J]; ``energy_J`` re-
        integrates with the reference-model sub-steps when a World is given
    pieces_duration_s : mission time as the NLP sees it (constant speed per piece) [s]
    objective : the solver's own objective at its optimum: energy [J] for "energy", mission
        time [s] for "time" (the CasADi transcription, clip included)
    """

    xy_m: np.ndarray
    speed_mps: np.ndarray
    energy_J: float
    duration_s: float
    iterations: int
    solve_seconds: float
    pieces_energy_J: float
    pieces_duration_s: float
    objective: float = float("nan")


class SpeedSolver:
    """Builds one parametric IPOPT solver per (N, objective) and warm-starts it.

    Parameters
    ----------
    model : the EnergyModel (its terms are evaluated on MX symbols)
    ipopt_options : extra IPOPT options
    """

    def __init__(self, model, ipopt_options: dict | None = None):
        self.model = model
        self.options = dict(ipopt_options or {})
        self._solvers: dict = {}
        self._last: dict = {}

    def _solver(self, problem: SpeedProblem):
        import casadi as ca

        key = (problem.pieces.n, problem.objective, problem.conditions, problem.accel_max_mps2)
        if key in self._solvers:
            return self._solvers[key]
        n = problem.pieces.n
        v, clipped = ca.MX.sym("v", n), ca.MX.sym("s", n)
        par = {f: ca.MX.sym(f, n) for f in FIELDS}
        limit = ca.MX.sym("limit")
        state = self._state(problem, v, par)
        seg = self.model.segment_energy(state, par["length_m"], problem.conditions.duty_cycle)
        # Transcription of the no-recovery clip: max(0, F) is not differentiable and IPOPT
        # oscillates across its kink on descents; the epigraph s >= F, s >= 0 is exact at the
        # optimum (minimising pushes s down to max(0, F)), and the model charges s in its place.
        force = self.model.traction_force_N(state)
        traversal = par["length_m"] * self.model.charged_force_N(force, positive_part=clipped)
        energy = ca.sum1(seg.ancillary_J + traversal)
        time = ca.sum1(seg.mission_time_s)
        length = par["length_m"]
        dv2 = v[1:] ** 2 - v[:-1] ** 2
        accel = 2 * problem.accel_max_mps2 * length[:-1]
        g = [dv2 - accel, -dv2 - accel, force - clipped]
        if problem.objective == "energy":
            f, g = energy, [*g, time - limit]
        else:
            f, g = time, [*g, energy - limit]
        nlp = {"x": ca.vertcat(v, clipped), "p": ca.vertcat(*[par[k] for k in FIELDS], limit), "f": f,
               "g": ca.vertcat(*g)}
        opts = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False,
                **{f"ipopt.{k}": val for k, val in self.options.items()}}
        solver = ca.nlpsol(f"speed_{n}_{problem.objective}", "ipopt", nlp, opts)
        self._solvers[key] = solver
        return solver

    def _state(self, problem: SpeedProblem, speed, par) -> MotionState:
        """Motion state of the pieces (numpy or MX ``speed`` and ``par``)."""
        wind_x, wind_y = problem.conditions.wind_xy_mps
        return MotionState(speed_mps=speed, cos_t=par["cos_t"], sin_t=par["sin_t"],
                           dir_x=par["dir_x"], dir_y=par["dir_y"],
                           wind_x_mps=wind_x, wind_y_mps=wind_y,
                           crr=par["crr"], sensor_rate_Hz=problem.conditions.sensor_rate_Hz,
                           surface_code=par["surface_code"],
                           channels=problem.conditions.channels)

    def solve(self, problem: SpeedProblem, model_world=None, warm_start=None) -> SpeedProfile:
        """Optimise the speeds; re-evaluate the result exactly with ``path_energy``.

        Parameters
        ----------
        problem : the statement
        model_world : World for the exact re-evaluation (None: figures from the NLP)
        warm_start : initial speeds (N,); default the previous solution of this N

        Raises
        ------
        PlanningError
            If IPOPT does not converge (e.g. an energy budget below what the path needs), or
            the driven profile cannot be brought within the time limit or energy budget.

        Notes
        -----
        With a World the limit is checked on the driven profile (``physics.profile``: from
        and to rest, duty-cycle stops), which takes longer and draws more than the NLP's
        constant-speed pieces; the NLP's limit is tightened by the overshoot and the problem
        solved again, up to ``TIGHTEN_ROUNDS`` times (the overshoot hardly depends on the speeds).
        """
        time_bound = problem.objective == "energy"
        limit = problem.time_limit_s if time_bound else problem.energy_budget_J
        profile = self._solve_once(problem, model_world, warm_start, limit)
        if model_world is None or limit is None:
            return profile
        pc = problem.pieces
        fastest_s = float(np.sum(pc.length_m)
                          / (problem.v_max_mps * problem.conditions.duty_cycle))
        for _ in range(TIGHTEN_ROUNDS):
            exact, pieces = ((profile.duration_s, profile.pieces_duration_s) if time_bound
                             else (profile.energy_J, profile.pieces_energy_J))
            if exact <= limit:
                return profile
            nlp_limit = pieces - (exact - limit)
            if time_bound and nlp_limit < fastest_s:
                break
            profile = self._solve_once(problem, model_world, profile.speed_mps, nlp_limit)
        if time_bound:
            check = check_time_limit(profile.duration_s, limit)
            if check.within:
                return profile
            raise PlanningError(f"speed profile: {check.reason} (ramps and duty-cycle stops "
                                "included)")
        if profile.energy_J <= limit:
            return profile
        raise PlanningError(f"speed profile: driven energy {profile.energy_J:,.0f} J exceeds the "
                            f"energy budget {limit:,.0f} J (ramps and duty-cycle stops included)")

    def _solve_once(self, problem: SpeedProblem, model_world, warm_start, limit) -> SpeedProfile:
        """One IPOPT solve with the NLP's limit ``limit`` (time or energy; None: none)."""
        import time as _time

        pc = problem.pieces
        solver = self._solver(problem)
        no_limit = 1e30
        p = np.concatenate([*pc.values().values(), [no_limit if limit is None else limit]])
        x0 = warm_start if warm_start is not None else self._last.get(pc.n)
        if x0 is None:
            x0 = np.full(pc.n, 0.5 * (problem.v_min_mps + problem.v_max_mps))
        x0 = np.clip(x0, problem.v_min_mps, _piece_caps(problem))
        force0 = self.model.traction_force_N(self._state(problem, x0, pc.values()))
        n = pc.n
        lbx = np.r_[np.full(n, problem.v_min_mps), np.zeros(n)]
        ubx = np.r_[_piece_caps(problem), np.full(n, np.inf)]
        t0 = _time.perf_counter()
        r = solver(x0=np.r_[x0, np.maximum(force0, 0.0)], p=p, lbx=lbx, ubx=ubx, ubg=0.0)
        seconds = _time.perf_counter() - t0
        stats = solver.stats()
        if not stats["success"]:
            raise PlanningError(f"speed optimisation did not converge: {stats['return_status']}")
        speed = np.asarray(r["x"]).ravel()[:n]
        self._last[pc.n] = speed
        e = self.model.segment_energy(self._state(problem, speed, pc.values()), pc.length_m,
                                      problem.conditions.duty_cycle)
        pieces_J = float(np.sum(e.ancillary_J + e.traversal_J))
        pieces_s = float(np.sum(e.mission_time_s))
        energy, duration = pieces_J, pieces_s
        if model_world is not None:
            exact = path_energy(self.model, model_world, pc.xy_m, speed, problem.conditions,
                                problem.accel_max_mps2)
            energy, duration = exact.total_J, exact.duration_s
        return SpeedProfile(pc.xy_m, speed, energy, duration, int(stats["iter_count"]), seconds,
                            pieces_J, pieces_s, float(r["f"]))


def _piece_caps(problem: SpeedProblem) -> np.ndarray:
    """Upper speed bound of each piece [m/s]."""
    cap = np.full(problem.pieces.n, problem.v_max_mps)
    if problem.piece_v_max_mps is not None:
        cap = np.minimum(cap, np.asarray(problem.piece_v_max_mps, float))
    return np.clip(cap, problem.v_min_mps, problem.v_max_mps)


def speed_problem(ctx: Context, pieces: PathPieces, objective: str = "energy",
                  time_limit_s: float | None = None,
                  energy_budget_J: float | None = None) -> SpeedProblem:
    """The speed problem of a scenario's robot on ``pieces`` (limits from the scenario)."""
    r = ctx.scenario.robot
    accel = getattr(r, "accel_max_mps2", None) or 0.5
    if time_limit_s is None and objective == "energy":
        time_limit_s = ctx.scenario.mission.time_limit_s
    return SpeedProblem(pieces, r.v_min_mps, r.v_max_mps, accel, ctx.conditions, objective,
                        time_limit_s, energy_budget_J)
