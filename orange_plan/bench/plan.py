"""Benchmark of coverage planning with a guaranteed return (``orange-plan bench plan``).

Three methods, side by side on the same scenarios and the same truths:

(a) ``lawnmower``: a boustrophedon path at its best sweep angle (``planning.lawnmower``),
    turned home in flight by PX4's remaining-flight-time rule (``bench.px4_rtl``);
(b) ``distance``: the tour planner with a constant energy per metre (a distance budget, the
    usual practice): ``planner(ctx, cost="distance")``;
(c) ``physics``: the tour planner with the energy model: ``planner(ctx, cost="physics")``.

Each plan is flown by the simulator (``sim.simulator.simulate``, what ``orange-plan simulate``
runs; plans go through their plan GeoJSON (docs/formats.md) and ``load_route``) under ``seeds`` truths drawn
within the model's calibration uncertainty (``sim.perturb.calibration_truths``); the same
truths and seeds for the three methods. Per flight:

* coverage: area of ``planning.coverage.footprint(world, flown positions, r)`` (sensor radius
  r, free space only), positions up to the battery's exhaustion;
* stranded: the battery's usable energy ran out before the route ended, or the route did not
  end at home;
* energy left at home: the truth's usable energy minus the energy drawn (negative: stranded);
* coverage / bound: coverage over the physical bound of the plan summary (docs/json.md) with nothing kept back
  (``coverage_bound_m2``: the same for the three methods; the planner's own summary bound,
  which keeps its reserve back, is in ``--json`` as ``planner_bound_m2``).

Reported per scenario and method: medians over the flights, strandings as a count, planner
seconds (wall clock, median over a family's maps). The random family ("random") is
``family_size`` generated maps (``bench.maps``) with the seeds dealt round-robin over them.
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from orange_plan.errors import InputError, OrangeError
from orange_plan.sim.flight import HOME_TOLERANCE_M, flown_footprint

METHODS = ("lawnmower", "lawnmower_energy", "distance", "physics")
"""Method ids: (a), (e), (b), (c)."""

METHOD_LABELS = {"lawnmower": "(a) lawnmower",
                 "lawnmower_energy": "(e) lawnmower, energy rule",
                 "distance": "(b) distance",
                 "physics": "(c) physics"}
"""Short labels: (a) lawnmower + PX4 return rule, (e) the same lawnmower + the session's
energy rule, (b) the planner with a distance budget, (c) the planner with the energy model,
flown in closed loop."""

LAWNMOWERS = ("lawnmower", "lawnmower_energy")
"""Methods that fly the lawnmower (one plan, two return rules)."""

BUDGET_SHARES = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
"""Shares of the usable energy at which the coverage-against-budget curve is read [-]."""

DEFAULT_SCENARIOS = ("kiwibot_campus", "ar_drone_wind", "marine_survey", "husky_a200", "random")
"""Shipped scenarios (scenarios/NAME.toml) and the random family, in table order."""

TAGS = {"kiwibot_campus": "hilly", "ar_drone_wind": "windy", "marine_survey": "current",
        "husky_a200": "open", "random": "random family"}

TARGETS = {"coverage_of_bound_open": 0.80, "ratio_vs_lawnmower": 1.3, "strandings_physics": 0,
           "planner_s_kiwibot": 20.0, "planner_s_large": 90.0}

Planner = Callable[..., object]
"""``planner(ctx, cost="physics" | "distance") -> Plan`` (``planning.plan.Plan``)."""


# --- results ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Flight:
    """One simulated flight of one plan under one truth.

    Attributes
    ----------
    seed : truth / simulator seed
    coverage_m2 : area sensed [m^2]
    coverage_of_bound : coverage / the scenario's coverage_bound_m2 [-]
    energy_left_J : usable energy minus energy drawn at the end [J] (< 0: stranded)
    stranded : battery exhausted before the route ended, or not back home
    duration_s : mission time flown [s]
    turned_home_s : (a) only: mission time at which the return rule fired [s]
    """

    seed: int
    coverage_m2: float
    coverage_of_bound: float
    energy_left_J: float
    stranded: bool
    duration_s: float
    turned_home_s: float | None = None


@dataclass(frozen=True)
class MethodResult:
    """All flights of one method on one scenario (a family: all its maps).

    Attributes
    ----------
    scenario, method : names
    planner_seconds : wall-clock planning time, median over the scenario's maps [s]
    coverage_bound_m2 : physical bound (``coverage_bound_m2``), median over the maps [m^2]
    planned_coverage_m2 : the plan's own coverage figure, median over the maps [m^2]
    planner_bound_m2 : the planner's summary ``coverage_bound_m2`` (reserve kept back),
        median over the maps [m^2]
    flights : one per truth
    error : why the method produced no plan (then no flights)
    budget_curve : ((share of the usable energy, area sensed before the closed-loop rule
        turns home on the planning model [m^2]), ...), median over the maps
    """

    scenario: str
    method: str
    planner_seconds: float
    coverage_bound_m2: float
    planned_coverage_m2: float | None
    flights: tuple[Flight, ...] = ()
    error: str | None = None
    time_limit_s: float | None = None
    planner_bound_m2: float | None = None
    budget_curve: tuple | None = None

    def _median(self, key: str) -> float | None:
        values = [getattr(f, key) for f in self.flights]
        return float(statistics.median(values)) if values else None

    @property
    def coverage_m2(self) -> float | None:
        return self._median("coverage_m2")

    @property
    def coverage_of_bound(self) -> float | None:
        return self._median("coverage_of_bound")

    @property
    def energy_left_J(self) -> float | None:
        return self._median("energy_left_J")

    @property
    def strandings(self) -> int:
        return sum(f.stranded for f in self.flights)

    @property
    def over_time_limit(self) -> int:
        """Flights longer than the scenario's ``time_limit_s`` (stops included)."""
        if self.time_limit_s is None:
            return 0
        return sum(f.duration_s > self.time_limit_s for f in self.flights)

    def summary(self) -> dict:
        """Medians and counts (one table row)."""
        return {"scenario": self.scenario, "method": self.method,
                "coverage_m2": self.coverage_m2, "coverage_of_bound": self.coverage_of_bound,
                "energy_left_J": self.energy_left_J, "planner_seconds": self.planner_seconds,
                "strandings": self.strandings, "flights": len(self.flights),
                "over_time_limit": self.over_time_limit,
                "duration_s": self._median("duration_s"),
                "coverage_bound_m2": self.coverage_bound_m2,
                "planned_coverage_m2": self.planned_coverage_m2,
                "planner_bound_m2": self.planner_bound_m2, "error": self.error,
                "budget_curve": None if self.budget_curve is None
                else [list(point) for point in self.budget_curve]}


@dataclass(frozen=True)
class Timing:
    """Planning time of one method on one scenario (no flights) [s]."""

    scenario: str
    method: str
    planner_seconds: float | None
    target_s: float | None
    error: str | None = None


@dataclass(frozen=True)
class PlanBenchResult:
    """The whole benchmark (``to_dict`` is the ``--json`` output)."""

    seeds: int
    results: list[MethodResult]
    timings: list[Timing] = field(default_factory=list)
    complete: bool = True

    def result(self, scenario: str, method: str) -> MethodResult | None:
        return next((r for r in self.results if r.scenario == scenario and r.method == method),
                    None)

    def ratio_vs_lawnmower(self, scenario: str, method: str = "physics") -> float | None:
        """Median coverage of ``method`` / median coverage of (a) on a scenario [-]."""
        a, c = self.result(scenario, "lawnmower"), self.result(scenario, method)
        if a is None or c is None or not a.coverage_m2 or c.coverage_m2 is None:
            return None
        return c.coverage_m2 / a.coverage_m2

    def rows(self) -> list[dict]:
        """One row per scenario and method: the table's columns."""
        rows = []
        for r in self.results:
            row = r.summary()
            row["ratio_vs_lawnmower"] = (None if r.method == "lawnmower"
                                         else self.ratio_vs_lawnmower(r.scenario, r.method))
            rows.append(row)
        return rows

    def to_dict(self) -> dict:
        return {"seeds": self.seeds, "complete": self.complete, "targets": TARGETS,
                "rows": self.rows(),
                "flights": [{"scenario": r.scenario, "method": r.method,
                             "flights": [asdict(f) for f in r.flights]} for r in self.results],
                "timings": [asdict(t) for t in self.timings]}


# --- scenarios ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ScenarioSpec:
    """A benchmark scenario: one scenario file, or a family of generated ones."""

    name: str
    paths: tuple[Path, ...]


def repo_scenario(name: str) -> Path:
    """``NAME.toml`` of the example scenarios (or ``name`` itself if it is a file)."""
    from orange_plan.examples import examples_dir

    if Path(name).suffix == ".toml" and Path(name).is_file():
        return Path(name)
    path = examples_dir("scenarios", "a .toml path in --scenarios") / f"{name}.toml"
    if not path.is_file():
        raise InputError(f"--scenarios: no scenario '{name}' ({path}) and no such file; use a "
                         "shipped name, a .toml path or 'random'")
    return path


def scenario_specs(names: Sequence[str], folder: Path, family_size: int = 4,
                   family_kwargs: dict | None = None) -> list[ScenarioSpec]:
    """Resolve ``--scenarios`` names; ``random`` writes the family's maps into ``folder``."""
    from orange_plan.bench.maps import random_scenario

    specs = []
    for name in names:
        if name == "random":
            paths = tuple(random_scenario(folder, k, **(family_kwargs or {}))
                          for k in range(family_size))
            specs.append(ScenarioSpec("random", paths))
        else:
            path = repo_scenario(name)
            specs.append(ScenarioSpec(path.stem, (path,)))
    return specs


# --- one map -----------------------------------------------------------------------------


def coverage_bound_m2(ctx) -> float:
    """Physical coverage bound of a scenario, the same for every method [m^2].

    ``min(free area, 2 r L + pi r^2)`` (docs/json.md) with ``L`` the farthest the robot can drive:
    all the usable energy over the least energy per metre anywhere on the map
    (``planning.tour.min_energy_per_m``), and with a time limit at most
    ``v_max D time_limit_s``. Nothing is kept back: the planner's own summary bound
    subtracts its reserve, which a method without one (the lawnmower) can exceed.
    """
    from orange_plan.planning.tour import min_energy_per_m

    sc = ctx.scenario
    r = sc.mission.sensor_radius_m
    drive_m = sc.battery.usable_J / min_energy_per_m(ctx)
    if sc.mission.time_limit_s is not None:
        drive_m = min(drive_m, sc.robot.v_max_mps * ctx.conditions.duty_cycle
                      * sc.mission.time_limit_s)
    return float(min(ctx.world.true_map.free_space.area, 2 * r * drive_m + math.pi * r * r))


def flight_of(ctx, sim, seed: int, bound_m2: float, turned_home_s=None) -> Flight:
    """Coverage, energy left and stranding of a simulated run (module docstring)."""
    frame = sim.frame
    soc = frame["soc"].to_numpy(float)
    empty = np.flatnonzero(soc <= 0.0)
    end = int(empty[0]) + 1 if empty.size else len(frame)
    xy = frame[["x_m", "y_m"]].to_numpy(float)[:end]
    last = xy[-1]
    away = float(np.hypot(*(last - np.asarray(ctx.world.home_xy_m))))
    stranded = bool(empty.size) or sim.energy_J >= sim.energy_available_J or \
        away > HOME_TOLERANCE_M
    area = flown_footprint(ctx.world, xy, ctx.scenario.mission.sensor_radius_m).area
    return Flight(int(seed), float(area), float(area / bound_m2) if bound_m2 > 0 else math.nan,
                  float(sim.energy_available_J - sim.energy_J), stranded, float(sim.duration_s),
                  turned_home_s)


def _route_via_geojson(plan, folder: Path, name: str):
    """The plan as ``orange-plan simulate`` reads it: its plan file (docs/formats.md) through ``load_route``."""
    from orange_plan.sim.route import load_route

    path = folder / f"{name}.geojson"
    plan.write(path)
    return load_route(path)


@dataclass
class _MapRun:
    """Plans, bound and flights of the three methods on one map (mutable while it runs)."""

    seconds: dict = field(default_factory=dict)
    planned: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    flights: dict = field(default_factory=lambda: {m: [] for m in METHODS})
    bound_m2: float = math.nan
    time_limit_s: float | None = None
    planner_bound: dict = field(default_factory=dict)
    budget_curves: dict = field(default_factory=dict)


def at_confidence(planner: Planner, confidence: float | None) -> Planner:
    """``planner`` with the scenario's reserve replaced by ``confidence = p`` (None: as the
    scenario says). The stranding target is zero strandings *at confidence 0.95*, so (b) and
    (c) plan with that reserve whatever rule a shipped scenario uses."""
    if confidence is None:
        return planner
    from orange_plan.scenario import Reserve

    def planned(ctx, **kwargs):
        sc = ctx.scenario
        mission = replace(sc.mission, reserve=Reserve("confidence", float(confidence)))
        # only the reserve changes: the conditions stay the context's
        return planner(replace(ctx, scenario=replace(sc, mission=mission)), **kwargs)

    return planned


def run_map(ctx, planner: Planner | None, seeds: Sequence[int], truth_seed: int,
            methods=METHODS, n_vertices: int = 5000, sample_rate_Hz: float = 10.0,
            step: Callable[[str], None] = lambda s: None) -> _MapRun:
    """Plan with each method on one map and fly each plan under ``len(seeds)`` truths."""
    from orange_plan.bench.px4_rtl import EnergyRule, ReturnRule, fly_with_return_rule
    from orange_plan.planning.lawnmower import plan_lawnmower
    from orange_plan.sim.perturb import calibration_truths
    from orange_plan.sim.simulator import simulate

    run = _MapRun(time_limit_s=ctx.scenario.mission.time_limit_s)
    name = ctx.scenario.name
    plans = {}
    for method in methods:
        step(f"{name}: planning ({METHOD_LABELS[method]})")
        t0 = time.perf_counter()
        try:
            if method in LAWNMOWERS:
                if "lawnmower" not in plans:
                    reach = lawnmower_reach(ctx, n_vertices)
                    plans["lawnmower"] = (plan_lawnmower(ctx, reach), driven_home(reach),
                                          reach)
                    lawn_s = time.perf_counter() - t0
                plans[method] = plans["lawnmower"]
                run.seconds[method] = lawn_s
                continue
            else:
                if planner is None:
                    raise InputError("no tour planner available")
                plans[method] = planner(ctx, cost=method)
        except Exception as exc:  # noqa: BLE001 - a failing method is reported, not fatal
            run.errors[method] = f"{type(exc).__name__}: {exc}"
            continue
        run.seconds[method] = time.perf_counter() - t0
    for method in ("physics", "distance"):
        plan = plans.get(method)
        if plan is not None:
            run.planned[method] = (plan.summary or {}).get("coverage_m2")
            run.planner_bound[method] = (plan.summary or {}).get("coverage_bound_m2")
    run.bound_m2 = coverage_bound_m2(ctx)
    truths = calibration_truths(ctx, len(seeds), seed=truth_seed)
    homing = _homing_kit(ctx, plans, n_vertices)
    run.budget_curves = budget_curves(ctx, plans, homing)
    with tempfile.TemporaryDirectory(prefix="orange-bench-") as tmp:
        routes = {m: _route_via_geojson(plans[m], Path(tmp), m) for m in ("distance", "physics")
                  if m in plans}
        for seed, truth in zip(seeds, truths):
            step(f"{name}: flights, seed {seed}")
            for method in [m for m in methods if m in plans and m not in run.errors]:
                try:
                    if method in LAWNMOWERS:
                        lawn, home, reach = plans["lawnmower"]
                        rule = ReturnRule() if method == "lawnmower" else EnergyRule()
                        sim, decision, _ = fly_with_return_rule(
                            ctx, lawn.xy_m, home, truth, seed, rule=rule, cost=reach.fast,
                            sample_rate_Hz=sample_rate_Hz)
                        turned = decision.t_s if decision.fired else None
                    elif method == "physics":
                        route, home, cost = closed_loop_route(plans[method], homing)
                        sim, decision, _ = fly_with_return_rule(
                            ctx, route, home, truth, seed, rule=EnergyRule(), cost=cost,
                            sample_rate_Hz=sample_rate_Hz)
                        turned = decision.t_s if decision.fired else None
                    else:
                        sim = simulate(ctx, routes[method], truth, seed=seed,
                                       sample_rate_Hz=sample_rate_Hz)
                        turned = None
                except OrangeError as exc:  # e.g. a plan that leaves the free space
                    run.errors[method] = f"flight: {exc}"
                    run.flights[method].clear()
                    continue
                run.flights[method].append(flight_of(ctx, sim, seed, run.bound_m2, turned))
    return run


@dataclass(frozen=True)
class _HomingKit:
    """What the closed-loop flights and the budget curves read on one map: the ways home,
    the fast edge costs (the rule's prediction of the path flown) and the coverage grid."""

    home: object
    cost: object
    grid: object


def _homing_kit(ctx, plans: dict, n_vertices: int) -> _HomingKit:
    """The lawnmower's roadmap (every method's way home, so the rules compare on equal
    terms), built here when the lawnmower was not planned."""
    from orange_plan.planning.coverage import coverage_grid

    if "lawnmower" in plans:
        _, home, reach = plans["lawnmower"]
    else:
        reach = lawnmower_reach(ctx, n_vertices)
        home = driven_home(reach)
    grid = coverage_grid(ctx.world, ctx.scenario.mission.sensor_radius_m)
    return _HomingKit(home, reach.fast, grid)


def lawnmower_reach(ctx, n_vertices: int):
    """The roadmap and costs the lawnmower is planned and flown on: the tour planner's (its
    size, seed 0 and cruise speed, ``tour.tour_speed_mps``), so the lawnmower route is the
    one the planner's sweeps are measured against."""
    from orange_plan.planning.plan import StartState
    from orange_plan.planning.reach import prepare_reach
    from orange_plan.planning.tour import tour_speed_mps

    return prepare_reach(ctx, n_vertices=n_vertices, seed=0,
                         speed_mps=tour_speed_mps(ctx, StartState()))


def driven_home(reach):
    """``HomePaths`` of a reach, its energies fitted to returns as driven (ramps, stops and
    the final wait: what the simulator flies)."""
    import functools

    from orange_plan.bench.px4_rtl import HomePaths
    from orange_plan.planning.tour import driven_energy_J

    return HomePaths(reach).calibrate(functools.partial(driven_energy_J, reach.exact))


def closed_loop_route(plan, homing: _HomingKit):
    """(route, ways home, costs) of a plan flown in closed loop (``Plan.closed_loop_route``:
    the tour to its turn point, then its continuation), the ways home at the cruise speed its
    sweep was scored at (else the plan's median speed); a plan without a continuation is
    flown whole (the rule may still turn it home early)."""
    import copy

    route = plan.closed_loop_route()[0]
    home = copy.copy(homing.home)
    home.speed_mps = float((plan.summary or {}).get("closed_loop_speed_mps",
                                                    np.median(plan.speed_mps)))
    return route, home, homing.cost


def budget_curves(ctx, plans: dict, homing: _HomingKit) -> dict:
    """Coverage against budget: for each method's route, the area sensed before the
    closed-loop rule turns it home with ``share`` of the usable energy, on the planning model
    (``planning.sweeps.route_needs``) [m^2] -> {method: [[share, m2], ...]}. An order that
    covers what is near home first keeps more when the mission must turn home early."""
    from orange_plan.planning.sweeps import route_needs, score_step_m

    usable = ctx.scenario.battery.usable_J
    limit = ctx.scenario.mission.time_limit_s
    r = ctx.scenario.mission.sensor_radius_m
    routes = {}
    if "lawnmower" in plans:
        routes["lawnmower"] = plans["lawnmower"][0].xy_m
    for method in ("distance", "physics"):
        if method in plans:
            routes[method] = closed_loop_route(plans[method], homing)[0]
    curves = {}
    for method, route in routes.items():
        # what each point of the route needs does not depend on the budget: found once
        needs = route_needs(ctx, homing.cost, homing.home, route,
                            math.inf if limit is None else limit, score_step_m(ctx))
        areas = needs.closed_m2_over(homing.grid, [share * usable for share in BUDGET_SHARES], r)
        curves[method] = [[share, m2] for share, m2 in zip(BUDGET_SHARES, areas)]
    return curves


# --- the benchmark -----------------------------------------------------------------------


def _merge(spec: ScenarioSpec, runs: list[_MapRun], methods) -> list[MethodResult]:
    out = []
    for method in methods:
        secs = [r.seconds[method] for r in runs if method in r.seconds]
        planned = [r.planned[method] for r in runs if r.planned.get(method) is not None]
        errors = [r.errors[method] for r in runs if method in r.errors]
        pbound = [r.planner_bound[method] for r in runs if r.planner_bound.get(method)]
        flights = tuple(f for r in runs for f in r.flights[method])
        curve = _median_curve([r.budget_curves.get(
            "lawnmower" if method in LAWNMOWERS else method) for r in runs])
        out.append(MethodResult(
            spec.name, method, float(statistics.median(secs)) if secs else math.nan,
            float(statistics.median(r.bound_m2 for r in runs)),
            float(statistics.median(planned)) if planned else None, flights,
            errors[0] if errors else None, runs[0].time_limit_s if runs else None,
            float(statistics.median(pbound)) if pbound else None, curve))
    return out


def _median_curve(curves) -> tuple | None:
    """Point-by-point median of the maps' budget curves (same shares), or None."""
    curves = [c for c in curves if c]
    if not curves:
        return None
    shares = [share for share, _ in curves[0]]
    return tuple((share, float(statistics.median(c[k][1] for c in curves)))
                 for k, share in enumerate(shares))


def run_plan_bench(specs: Sequence[ScenarioSpec], planner: Planner | None, seeds: int = 20,
                   methods=METHODS, n_vertices: int = 5000, sample_rate_Hz: float = 10.0,
                   large_folder: Path | None = None,
                   step: Callable[[str], None] = lambda s: None,
                   on_progress: Callable[[PlanBenchResult], None] | None = None
                   ) -> PlanBenchResult:
    """Run the benchmark over ``specs`` (module docstring).

    Parameters
    ----------
    specs : scenarios (``scenario_specs``)
    planner : ``planner(ctx, cost=...) -> Plan`` for (b) and (c); None: (a) only
    seeds : truths per scenario (a family deals them round-robin over its maps)
    methods : subset of ``METHODS``
    n_vertices : roadmap size of the lawnmower's detours and return paths (the planner's:
        then the lawnmower (e) flies is the one the planner (c) starts from)
    sample_rate_Hz : simulator rate [Hz]
    large_folder : where to write the 2 km x 2 km map and time the planner on it (None: skip)
    on_progress : called with the partial result after each scenario

    Raises
    ------
    InputError
        If ``seeds`` < 1 or a method is unknown.
    """
    from orange_plan.context import load_context

    if seeds < 1:
        raise InputError(f"--seeds = {seeds} must be >= 1")
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(f"unknown method '{unknown[0]}' (have {', '.join(METHODS)})")
    results: list[MethodResult] = []
    timings: list[Timing] = []
    for spec in specs:
        runs = []
        for k, path in enumerate(spec.paths):
            mine = list(range(seeds))[k:: len(spec.paths)]
            if not mine:
                continue
            ctx = load_context(path)
            runs.append(run_map(ctx, planner, mine, truth_seed=1000 * k + 17, methods=methods,
                                n_vertices=n_vertices, sample_rate_Hz=sample_rate_Hz, step=step))
        results += _merge(spec, runs, methods)
        if spec.name == "kiwibot_campus" and "physics" in methods:
            r = results[-len(methods) + list(methods).index("physics")]
            timings.append(Timing(spec.name, "physics", r.planner_seconds,
                                  TARGETS["planner_s_kiwibot"], r.error))
        if on_progress is not None:
            on_progress(PlanBenchResult(seeds, list(results), list(timings), complete=False))
    if large_folder is not None and planner is not None:
        timings.append(time_large_map(planner, large_folder, step))
    return PlanBenchResult(seeds, results, timings, complete=True)


def time_large_map(planner: Planner, folder: Path, step=lambda s: None) -> Timing:
    """Planning time of (c) on the generated 2 km x 2 km map with 300 obstacles and a DEM."""
    from orange_plan.bench.maps import large_scenario
    from orange_plan.context import load_context

    ctx = load_context(large_scenario(folder))
    step("large map (2 km x 2 km, 300 obstacles, DEM): planning (c)")
    t0 = time.perf_counter()
    try:
        planner(ctx, cost="physics")
    except OrangeError as exc:
        return Timing(ctx.scenario.name, "physics", None, TARGETS["planner_s_large"], str(exc))
    return Timing(ctx.scenario.name, "physics", time.perf_counter() - t0,
                  TARGETS["planner_s_large"])


# --- presentation ------------------------------------------------------------------------


def _fmt(value, spec: str, scale: float = 1.0) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value / scale, spec)


def plan_table(result: PlanBenchResult):
    """The results table: one row per scenario and method (medians over the flights)."""
    from rich.table import Table

    title = (f"bench plan: medians over {result.seeds} truths per scenario"
             + ("" if result.complete else " (PARTIAL)"))
    caption = ("(a) lawnmower + PX4 return rule, (b) planner with a distance budget, "
               "(c) planner with the energy model; ratio: coverage / that of (a)")
    t = Table(title=title, caption=caption, header_style="bold")
    for col in ("scenario", "method", "coverage m2", "cov/bound", "left kJ", "planner s",
                "stranded", "ratio"):
        t.add_column(col, justify="left" if col in ("scenario", "method") else "right")
    for row in result.rows():
        name = row["scenario"]
        if row["error"] and not row["flights"]:
            t.add_row(name, METHOD_LABELS[row["method"]], f"[red]{row['error'][:60]}[/]",
                      "", "", _fmt(row["planner_seconds"], ".1f"), "", "")
            continue
        t.add_row(name, METHOD_LABELS[row["method"]], _fmt(row["coverage_m2"], ",.0f"),
                  _fmt(row["coverage_of_bound"], ".1%"), _fmt(row["energy_left_J"], ",.1f", 1e3),
                  _fmt(row["planner_seconds"], ".1f"),
                  f"{row['strandings']}/{row['flights']}",
                  _fmt(row["ratio_vs_lawnmower"], ".2f"))
    for tm in result.timings:
        t.add_row(tm.scenario, f"{METHOD_LABELS[tm.method]} time", "", "", "",
                  _fmt(tm.planner_seconds, ".1f") if tm.error is None else "[red]failed[/]",
                  f"target <= {tm.target_s:g} s" if tm.target_s else "", "")
    return t


def plan_figure(result: PlanBenchResult, path) -> Path:
    """PNG: left, median coverage / bound against strandings, one marker per scenario and
    method; right, coverage against budget (the area sensed before the closed-loop rule turns
    home with a share of the usable energy, on the planning model), per scenario and method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from orange_plan.atomic import save_figure

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13.0, 5.6))
    markers = {"lawnmower": "s", "lawnmower_energy": "P", "distance": "^", "physics": "o"}
    styles = {"lawnmower": ":", "distance": "--", "physics": "-"}
    scen = list(dict.fromkeys(r.scenario for r in result.results))
    colours = plt.get_cmap("tab10")
    for r in result.results:
        colour = colours(scen.index(r.scenario) % 10)
        if r.coverage_of_bound is not None:
            share = r.strandings / max(len(r.flights), 1)
            ax.scatter(r.coverage_of_bound * 100, share * 100, marker=markers[r.method], s=60,
                       color=colour, edgecolor="k", linewidth=0.5)
        if r.budget_curve and r.method in styles and r.coverage_bound_m2 > 0:
            shares, m2 = np.asarray(r.budget_curve, float).T
            bx.plot(100 * shares, 100 * m2 / r.coverage_bound_m2, styles[r.method],
                    color=colour, lw=1.6)
    for m, mk in markers.items():
        ax.scatter([], [], marker=mk, color="grey", label=METHOD_LABELS[m])
    for i, s in enumerate(scen):
        ax.scatter([], [], marker="o", color=colours(i % 10), label=s)
    ax.set_xlabel("coverage / physical bound, median [%]")
    ax.set_ylabel("flights stranded [%]")
    ax.set_title(f"flown: {result.seeds} truths per scenario")
    ax.grid(alpha=0.3)
    # Below the axes: inside, it hid the markers of the upper left corner.
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3,
              frameon=False)
    # from just below 0 (markers at 0 stay whole) to the worst share, at least 5 %
    worst = max((100 * r.strandings / max(len(r.flights), 1) for r in result.results),
                default=0.0)
    top = max(5.0, 1.1 * worst)
    ax.set_ylim(-0.04 * top, top)
    labels = {"lawnmower": "(a)/(e) lawnmower", "distance": METHOD_LABELS["distance"],
              "physics": METHOD_LABELS["physics"]}
    for m, ls in styles.items():
        bx.plot([], [], ls, color="grey", label=labels[m])
    bx.set_xlabel("energy budget / usable energy [%]")
    bx.set_ylabel("coverage before turning home / physical bound [%]")
    bx.set_title("coverage against budget (planning model, closed-loop rule)")
    bx.set_xlim(0, 100)
    bx.set_ylim(bottom=0)
    bx.grid(alpha=0.3)
    bx.legend(fontsize=7, loc="upper left", frameon=False)
    fig.tight_layout()
    return save_figure(fig, path)
