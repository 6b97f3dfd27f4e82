"""Monte Carlo study of whole missions (``orange-plan bench mission``).

Many simulated missions, each in a world whose truth differs from the scenario, flown four
ways on the same map, under the same truth and seed:

(a) ``session``: the first tour flown in closed loop with ``planning.session.MissionSession``:
    the simulator flies the current route, the recording is fed to the session in chunks of
    ``chunk_s`` seconds and the robot does what each decision says: ``continue``; ``replan``
    (``session.replan()``, then the new tour is flown from where the robot is; at most one
    replan per ``replan_min_interval_s`` of mission time and ``max_replans`` per mission,
    a refused replan = go home); ``return_home`` (the roadmap's way home is flown).
(b) ``open_loop``: the same first tour flown as planned, whatever happens.
(c) ``lawnmower``: a boustrophedon (``planning.lawnmower``) turned home in flight by the
    PX4-style remaining-flight-time rule (``bench.px4_rtl``).
(e) ``lawnmower_energy``: the same boustrophedon flown by ``MissionSession`` as a closed loop
    (``fly_lawnmower_session``): turned home by the session's own live check (measured
    energy + the look-ahead + the way home + the reserve for the return alone, the battery's
    ``soc`` read), never replanned, so that the pattern and the rule can be told apart.
(d) ``oracle``: a tour planned with the true model (the truth's coefficients, payload, mean
    wind and usable energy; the same reserve rule and covariance), flown open loop.

**Worlds**: ``n_maps`` members of the generated random family (``bench.maps.random_scenario``)
of ``width_m`` x ``height_m``, the reserve set to ``confidence = 0.99``; mission ``i`` flies
map ``i mod n_maps``. Roadmaps of ``n_vertices`` vertices, BIT* refinement off.

**Truths** (``mission_truth``), seeded by the mission's seed, alternating between families:

* ``within``: a draw within the model's calibration uncertainty
  (``sim.perturb.calibration_truths``: coefficients from their covariance times a run factor
  from the run-to-run discrepancy, gusts, terrain roughness);
* ``beyond``: such a draw plus one effect the scenario does not have, in turn
  ``wind`` (a mean wind of 3-5 m/s from any direction, recorded by the robot),
  ``mass`` (a payload of +20-40 % of the robot's mass from the start),
  ``ageing`` (usable energy x 0.80-0.90: a more aged battery; the oracle knows it, the session
  sees it only through the battery's state of charge in its telemetry, ``soc``, and the PX4
  rule as implemented here, which counts energy against the configured capacity, not at all), ``terrain`` (rolling resistance x 1.3-1.6: softer
  ground, or an unmapped incline, than the map says).

**Accounting** (every method): the simulator cannot start mid-battery, so a mission is flown
as segments (one per route flown, each cut where the robot changed route) and the true energy
drawn is summed over them (``sum P dt`` of each segment's samples up to the cut). A mission is
**stranded** when that sum exceeds the truth's usable energy (scenario ``E_avail`` x the
truth's capacity factor) before the robot is home, or when it does not end within
``bench.plan.HOME_TOLERANCE_M`` of home. **Coverage** is the area of the sensor footprint of
the positions flown up to the battery's exhaustion (``bench.plan.flown_footprint``, free space
only). **Energy left at home** is the usable energy minus the energy drawn (negative:
stranded).

``run_one_mission(spec, seed) -> dict`` is pure and picklable (it writes its world into a
per-process cache folder and memoises the map's first tour and lawnmower), so the study is
dealt out to Dask workers like the runs of ``orange-plan sweep`` (``run_mission_study``:
``workers`` local processes, or an existing cluster's ``scheduler``).
"""

from __future__ import annotations

import atexit
import math
import os
import shutil
import statistics
import tempfile
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from orange_plan.errors import InputError, OrangeError
from orange_plan.sim.flight import Flown as _Flown
from orange_plan.sim.flight import fly_open_loop, stranding_upper_bound
from orange_plan.sim.flight import simulate_route as _simulate
from orange_plan.sweep.report import cell as _fmt

METHODS = ("session", "open_loop", "lawnmower", "lawnmower_energy", "oracle")
"""Method ids: (a), (b), (c), (e), (d)."""

METHOD_LABELS = {"session": "(a) session + replanning",
                 "open_loop": "(b) first plan, open loop",
                 "lawnmower": "(c) lawnmower + PX4 RTL",
                 "lawnmower_energy": "(e) lawnmower + energy rule",
                 "oracle": "(d) oracle (true model)"}

FAMILIES = ("within", "beyond")
BEYOND_KINDS = ("wind", "mass", "ageing", "terrain")

TARGETS = {"strandings_session": 0, "session_over_oracle": 0.85, "missions": 500,
           "confidence": 0.99}

FEED_COLUMNS = ("t_s", "power_W", "x_m", "y_m", "z_m", "v_mps", "yaw_rate_radps", "accel_mps2",
                "wind_mps", "wind_from_deg", "soc")
"""Recording columns the session is fed (what a robot's telemetry would carry; ``soc`` is the
battery's state of charge, which shows an aged battery)."""

STUDY_CONFIDENCE = 0.99
"""The scenario's reserve for this study (``mission.reserve.confidence``)."""


@dataclass(frozen=True)
class MissionSpec:
    """Everything one mission depends on besides its seed (picklable).

    Attributes
    ----------
    map_seed : member of the random family (``bench.maps.random_scenario`` seed)
    family : "within" or "beyond" the calibration uncertainty
    kind : "calibration" (within) or one of ``BEYOND_KINDS``
    width_m, height_m : world size [m]
    n_vertices : roadmap size of every planner and of the session's way home
    sample_rate_Hz : simulator rate [Hz]
    chunk_s : telemetry fed to the session per batch [s]
    replan_min_interval_s : mission time between two replans at least [s]
    max_replans : replans per mission at most
    confidence : the scenario's reserve confidence
    replanning : (a) acts on "replan" decisions (False: it only returns home when told)
    heavier_kg : extra hand-made payload on top of the truth [kg] (tests: a truth far heavier
        than the model)
    methods : methods flown
    """

    map_seed: int
    family: str = "within"
    kind: str = "calibration"
    width_m: float = 120.0
    height_m: float = 80.0
    n_vertices: int = 1000
    sample_rate_Hz: float = 5.0
    chunk_s: float = 10.0
    replan_min_interval_s: float = 30.0
    max_replans: int = 8
    confidence: float = STUDY_CONFIDENCE
    replanning: bool = True
    heavier_kg: float = 0.0
    methods: tuple[str, ...] = METHODS


def mission_specs(n: int, n_maps: int = 10, **kwargs) -> list[MissionSpec]:
    """``n`` missions: map ``i mod n_maps``, families alternating, beyond kinds in turn."""
    specs = []
    for i in range(n):
        family = FAMILIES[i % 2]
        kind = "calibration" if family == "within" else BEYOND_KINDS[(i // 2) % len(BEYOND_KINDS)]
        specs.append(MissionSpec(i % n_maps, family, kind, **kwargs))
    return specs


# --- worlds (memoised per process) ---------------------------------------------------------

MAP_KITS_KEPT = 8
"""Map kits a process keeps (each holds a context, a roadmap, a tour and return paths: tens of
MB); the least recently used goes first. A run's missions cycle through ``--maps`` maps."""
_KITS: OrderedDict = OrderedDict()
_FOLDERS: dict[int, Path] = {}


@dataclass
class _MapKit:
    ctx: object
    plan: object | None  # first tour (None: the planner refused)
    plan_error: str | None
    lawn_xy: np.ndarray | None
    home: object  # px4_rtl.HomePaths
    reach: object


def _folder() -> Path:
    """This process's folder of generated worlds, removed when the process exits (a forked
    worker makes its own and leaves its parent's alone)."""
    pid = os.getpid()
    if pid not in _FOLDERS:
        _FOLDERS[pid] = Path(tempfile.mkdtemp(prefix="orange-bench-mission-"))
        atexit.register(_remove_folder, _FOLDERS[pid], pid)
    return _FOLDERS[pid]


def _remove_folder(path: Path, pid: int) -> None:
    if os.getpid() == pid:
        shutil.rmtree(path, ignore_errors=True)


def _remember(key, make: Callable[[], object], kept: int | None = None):
    """``make()`` memoised under ``key``, keeping the ``kept`` (default ``MAP_KITS_KEPT``)
    most recently used."""
    if key in _KITS:
        _KITS.move_to_end(key)
        return _KITS[key]
    value = _KITS[key] = make()
    while len(_KITS) > (MAP_KITS_KEPT if kept is None else kept):
        _KITS.popitem(last=False)
    return value


def study_scenario(folder: Path, spec: MissionSpec) -> Path:
    """Write the spec's random-family world with the study's reserve; return its TOML."""
    import tomllib

    import tomli_w

    from orange_plan.bench.maps import random_scenario

    path = random_scenario(folder / f"{spec.width_m:g}x{spec.height_m:g}", spec.map_seed,
                           width_m=spec.width_m, height_m=spec.height_m)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    data["mission"]["reserve"] = {"confidence": float(spec.confidence)}
    path.write_text(tomli_w.dumps(data), encoding="utf-8")
    return path


def map_kit(spec: MissionSpec) -> _MapKit:
    """Context, first tour, lawnmower and return paths of the spec's map (memoised)."""
    from orange_plan.bench.plan import driven_home, lawnmower_reach
    from orange_plan.context import load_context
    from orange_plan.planning.lawnmower import plan_lawnmower
    from orange_plan.planning.tour import plan_tour

    def make() -> _MapKit:
        ctx = load_context(study_scenario(_folder(), spec))
        try:
            plan, error = plan_tour(ctx, n_vertices=spec.n_vertices, seed=0,
                                    bitstar_legs=0), None
        except OrangeError as exc:
            plan, error = None, f"{type(exc).__name__}: {exc}"
        reach = lawnmower_reach(ctx, spec.n_vertices)
        lawn = plan_lawnmower(ctx, reach)
        return _MapKit(ctx, plan, error, np.asarray(lawn.xy_m, float), driven_home(reach), reach)

    key = (spec.map_seed, spec.width_m, spec.height_m, spec.n_vertices, spec.confidence)
    return _remember(key, make)


# --- truths -------------------------------------------------------------------------------


def mission_truth(ctx, spec: MissionSpec, seed: int):
    """The mission's truth (module docstring) and a short description of what it changes."""
    from orange_plan.sim.perturb import DISCREPANCY, calibration_truths
    from orange_plan.sim.truth import Wind

    truth = calibration_truths(ctx, 1, seed=int(seed))[0]
    rng = np.random.default_rng([int(seed), 7])
    note = "calibration draw"
    mass = ctx.scenario.robot.mass_kg
    if spec.family == "beyond":
        if spec.kind == "wind":
            speed, frm = float(rng.uniform(3.0, 5.0)), float(rng.uniform(0.0, 360.0))
            truth = replace(truth, wind=Wind(speed, frm, DISCREPANCY.gust_fraction * speed,
                                             DISCREPANCY.gust_tau_s, True))
            note += f", wind {speed:.1f} m/s from {frm:.0f} deg"
        elif spec.kind == "mass":
            extra = float(rng.uniform(0.2, 0.4)) * mass
            truth = replace(truth, payload_kg=extra, payload_from_s=0.0)
            note += f", payload {extra:.1f} kg"
        elif spec.kind == "ageing":
            factor = float(rng.uniform(0.80, 0.90))
            truth = replace(truth, capacity_factor=factor)
            note += f", usable energy x {factor:.2f}"
        elif spec.kind == "terrain":
            factor = float(rng.uniform(1.3, 1.6))
            coeffs = {k: (v * factor if k.startswith("rolling_kg") else v)
                      for k, v in truth.coefficients.items()}
            truth = replace(truth, coefficients=coeffs)
            note += f", rolling resistance x {factor:.2f}"
        else:
            raise InputError(f"unknown beyond kind {spec.kind!r} (have {BEYOND_KINDS})")
    if spec.heavier_kg:
        truth = replace(truth, payload_kg=truth.payload_kg + spec.heavier_kg, payload_from_s=0.0)
        note += f" + {spec.heavier_kg:g} kg"
    return truth, note


def oracle_context(ctx, truth):
    """``ctx`` with the true model: coefficients (x payload), mean wind and usable energy."""
    from orange_plan.sim.simulator import truth_model, with_payload

    model = with_payload(truth_model(ctx.model, truth), ctx.scenario.robot.mass_kg,
                         truth.payload_kg)
    sc = ctx.scenario
    battery = replace(sc.battery, rated_energy_Wh=sc.battery.rated_energy_Wh
                      * truth.capacity_factor)
    oracle = replace(ctx.with_scenario(replace(sc, battery=battery)), model=model)
    if truth.wind is None:
        return oracle
    wind = truth.wind.mean_xy_mps
    return replace(oracle, conditions=oracle.conditions.with_wind(wind))


# --- flights ------------------------------------------------------------------------------


def fly_lawnmower(kit: _MapKit, truth, seed: int, rate: float, rule=None) -> dict:
    """(c): the lawnmower turned home by the PX4-style rule (or another ``rule``)."""
    from orange_plan.bench.px4_rtl import ReturnRule, fly_with_return_rule

    sim, decision, _ = fly_with_return_rule(kit.ctx, kit.lawn_xy, kit.home, truth, seed,
                                            rule=rule or ReturnRule(), cost=kit.reach.fast,
                                            sample_rate_Hz=rate)
    flown = _Flown(1.0 / rate, [], [], sim.energy_available_J,
                   returned_by_rule=bool(decision.fired))
    flown.add(sim.frame)
    return flown.outcome(kit.ctx)


def fly_lawnmower_session(kit: _MapKit, spec: MissionSpec, truth, seed: int) -> dict:
    """(e): the lawnmower flown by ``MissionSession`` as a closed loop (``closed_loop=True``:
    the live check alone turns it home; no replans): the session's own energy rule, with its
    look-ahead, its return reserve and the battery's ``soc``, on the baseline's pattern."""
    return fly_session(kit, replace(spec, replanning=False), truth, seed,
                       plan=lawnmower_plan(kit), closed_loop=True)


def lawnmower_plan(kit: _MapKit):
    """The lawnmower route as a plan (home -> lanes -> home at the cruise speed; no margins:
    a closed loop does not read them)."""
    from orange_plan.planning.plan import Plan

    xy = np.asarray(kit.lawn_xy, float)
    n, zeros = len(xy), np.zeros(len(xy))
    return Plan(xy, zeros, np.full(n, kit.home.speed_mps), zeros, zeros, zeros, zeros,
                np.empty((0, 2)), None, {})


def fly_session(kit: _MapKit, spec: MissionSpec, truth, seed: int, plan=None,
                closed_loop: bool = False) -> dict:
    """(a): the first tour flown in closed loop with ``MissionSession`` (module docstring):
    the session's route (``MissionSession.route_xy_m``: a plan that follows a sweep goes on
    past its guaranteed extent along its continuation until the live check turns it home).

    Each route (the first tour, a replanned tour, the way home) is one simulated segment; the
    recording is fed in ``chunk_s`` batches (mission time carried over) until the decision
    changes the route; the segment is cut at the last sample fed.
    """
    from orange_plan.planning.session import MissionSession

    ctx, rate = kit.ctx, spec.sample_rate_Hz
    session = MissionSession(ctx, kit.plan if plan is None else plan,
                             n_vertices=spec.n_vertices, seed=0,
                             planner_kwargs={"bitstar_legs": 0}, closed_loop=closed_loop)
    xy, speed = session.route_xy_m, session.route_speed_mps
    flown = _Flown(1.0 / rate, [], [], math.nan)
    chunk = max(1, round(spec.chunk_s * rate))
    t_next, last_replan, segment, returning = 0.0, -math.inf, 0, False
    actions = []
    while True:
        # the battery carries over: its state of charge goes on from where the last segment cut
        sim = _simulate(ctx, xy, speed, truth, 1000 * int(seed) + segment, rate,
                        flown.energy_drawn_J)
        flown.e_avail = sim.energy_available_J
        frame = sim.frame
        segment += 1
        if returning:
            flown.add(frame)
            break
        t = frame["t_s"].to_numpy(float) - float(frame["t_s"].iloc[0]) + t_next
        cut, action = None, None
        for a in range(0, len(frame), chunk):
            batch = frame.iloc[a:a + chunk][[c for c in FEED_COLUMNS if c in frame]].copy()
            batch["t_s"] = t[a:a + chunk]
            d = session.feed(batch)
            actions.append(d.action)
            now = float(batch["t_s"].iloc[-1])
            if d.action == "return_home":
                cut, action = a + len(batch), "home"
                break
            if (d.action == "replan" and spec.replanning and flown.replans < spec.max_replans
                    and now - last_replan >= spec.replan_min_interval_s
                    and a + len(batch) < len(frame)):
                cut, last_replan = a + len(batch), now
                try:
                    session.replan()
                    action = "replan"
                    flown.replans += 1
                except InputError:  # nothing new fits: go home
                    action = "home"
                break
        if cut is None:
            flown.add(frame)
            break
        flown.add(frame, cut)
        t_next = float(t[cut - 1]) + 1.0 / rate
        here = frame[["x_m", "y_m"]].to_numpy(float)[cut - 1]
        if action == "replan":
            xy, speed = session.route_xy_m, session.route_speed_mps
            if np.hypot(*(np.asarray(xy[0]) - here)) > 1e-6:  # the tour starts where we are
                xy = np.vstack([here, xy])
                speed = np.r_[speed[0], speed]
        else:
            flown.returned_by_rule = True
            # what the session says to drive home: in closed loop the stretch ahead its
            # margin still pays for, then the way home it costed (the bench's own
            # shortest-return tree may join home straight over a hill the roadmap goes round)
            xy = session.homeward_xy_m()
            if xy is None or len(xy) < 2:
                xy = kit.home.path(here)
            speed = np.full(len(xy), kit.home.speed_mps)
            returning = True
            flown.return_predicted_J = session.homeward_energy_J
            flown.return_reserve_J = float(d.reserve_J)
        if len(xy) < 2 or float(np.sum(np.hypot(*np.diff(xy, axis=0).T))) < 1e-6:
            break
    flown.note = f"{actions.count('replan')} replan / {actions.count('return_home')} home advised"
    return flown.outcome(ctx)


def run_one_mission(spec: MissionSpec, seed: int) -> dict:
    """One mission flown by every method of ``spec.methods`` (pure: same inputs, same dict).

    Returns
    -------
    dict with ``seed``, ``map_seed``, ``family``, ``kind``, ``truth`` (what it changes),
    ``seconds`` (wall clock) and per method a dict (``coverage_m2``, ``energy_left_J``,
    ``stranded``, ``duration_s``, ``replans``, ``returned_early``, ``plan_seconds``) or
    ``{"error": "..."}`` when the method had no plan.
    """
    t0 = time.perf_counter()
    kit = map_kit(spec)
    ctx, rate = kit.ctx, spec.sample_rate_Hz
    truth, note = mission_truth(ctx, spec, seed)
    out = {"seed": int(seed), "map_seed": spec.map_seed, "family": spec.family,
           "kind": spec.kind, "truth": note}
    for method in spec.methods:
        t1 = time.perf_counter()
        try:
            if method in ("session", "open_loop") and kit.plan is None:
                raise InputError(kit.plan_error or "no first tour")
            if method == "session":
                res = fly_session(kit, spec, truth, seed)
            elif method == "open_loop":
                res = fly_open_loop(ctx, kit.plan, truth, seed, rate)
            elif method == "lawnmower":
                res = fly_lawnmower(kit, truth, seed, rate)
            elif method == "lawnmower_energy":
                res = fly_lawnmower_session(kit, spec, truth, seed)
            elif method == "oracle":
                from orange_plan.planning.tour import plan_tour

                try:
                    plan = plan_tour(oracle_context(ctx, truth), n_vertices=spec.n_vertices,
                                     seed=0, bitstar_legs=0)
                    res = fly_open_loop(ctx, plan, truth, seed, rate)
                except InputError as exc:  # the true battery cannot fly any tour: stay home
                    res = {"coverage_m2": 0.0, "energy_left_J": float(
                        ctx.scenario.battery.usable_J * truth.capacity_factor),
                        "stranded": False, "duration_s": 0.0, "replans": 0,
                        "returned_early": False, "note": f"stayed home: {exc}"}
            else:
                raise InputError(f"unknown method {method!r} (have {', '.join(METHODS)})")
        except OrangeError as exc:
            res = {"error": f"{type(exc).__name__}: {exc}"}
        res["seconds"] = time.perf_counter() - t1
        out[method] = res
    out["seconds"] = time.perf_counter() - t0
    return out


# --- the study ----------------------------------------------------------------------------


def _median(values):
    values = [v for v in values if v is not None and math.isfinite(v)]
    return float(statistics.median(values)) if values else None


def summarise(missions: Sequence[dict], methods=METHODS, family: str | None = None) -> list[dict]:
    """One row per method: counts and medians over the missions (of one family or all)."""
    chosen = [m for m in missions if family is None or m["family"] == family]
    rows = []
    for method in methods:
        ok = [m for m in chosen if method in m and "error" not in m[method]]
        oracle_ok = [m for m in ok if "oracle" in m and "error" not in m["oracle"]]
        ratios = [m[method]["coverage_m2"] / m["oracle"]["coverage_m2"] for m in oracle_ok
                  if m["oracle"]["coverage_m2"] > 0]
        k = sum(m[method]["stranded"] for m in ok)
        cov = _median([m[method]["coverage_m2"] for m in ok])
        cov_oracle = _median([m["oracle"]["coverage_m2"] for m in oracle_ok])
        rows.append({
            "family": family or "all", "method": method, "missions": len(ok),
            "errors": sum(1 for m in chosen if method in m and "error" in m[method]),
            "strandings": k, "stranding_upper95": stranding_upper_bound(k, len(ok)),
            "energy_left_at_home_kJ": _median([m[method]["energy_left_J"] / 1e3 for m in ok
                                                if not m[method]["stranded"]]),
            "coverage_m2": cov,
            "coverage_over_oracle": (cov / cov_oracle) if cov is not None and cov_oracle else None,
            "coverage_over_oracle_median": _median(ratios),
            "replans": _median([m[method].get("replans", 0) for m in ok]),
            "returned_early": sum(bool(m[method].get("returned_early")) for m in ok),
            "seconds": _median([m[method]["seconds"] for m in ok]),
        })
    return rows


def study_result(missions: Sequence[dict], n_planned: int, seed: int, runtime_s: float,
                 spec: MissionSpec, complete: bool) -> dict:
    """The ``--json`` / ``--out`` object."""
    missions = sorted(missions, key=lambda m: m["index"]) if missions and "index" in missions[0] \
        else list(missions)
    rows = summarise(missions, spec.methods)
    by_family = [r for f in FAMILIES for r in summarise(missions, spec.methods, f)]
    by_kind = []
    for kind in ("calibration", *BEYOND_KINDS):
        sub = [m for m in missions if m["kind"] == kind]
        for r in summarise(sub, spec.methods):
            r["family"] = kind
            by_kind.append(r)
    session = next((r for r in rows if r["method"] == "session"), None)
    ratio = session["coverage_over_oracle"] if session else None
    return {"missions": len(missions), "missions_planned": n_planned, "seed": seed,
            "complete": complete, "runtime_s": runtime_s, "spec": asdict(spec) | {"map_seed": None},
            "targets": TARGETS, "session_over_oracle": ratio,
            "session_over_oracle_median": session["coverage_over_oracle_median"] if session
            else None,
            "rows": rows, "by_family": by_family, "by_kind": by_kind, "flights": missions}


def run_mission_study(n: int, seed: int = 0, n_maps: int = 10, workers: int = 1,
                      spec_kwargs: dict | None = None,
                      tick: Callable[[], None] | None = None,
                      on_progress: Callable[[dict], None] | None = None,
                      progress_every: int = 10, scheduler: str | None = None) -> dict:
    """Fly ``n`` missions (``mission_specs``; mission ``i`` has seed ``seed + i``).

    The missions run on Dask like ``orange-plan sweep``'s runs (``orange_plan.cluster``): a local
    cluster of ``workers`` processes, or the existing cluster of ``scheduler``
    (tcp://HOST:PORT); ``on_progress`` gets the partial result every ``progress_every``
    missions.

    Raises
    ------
    InputError
        If ``n`` < 1, ``n_maps`` < 1, ``workers`` < 1 or a bad ``scheduler``.
    """
    if n < 1:
        raise InputError(f"--missions = {n} must be >= 1")
    if n_maps < 1:
        raise InputError(f"--maps = {n_maps} must be >= 1")
    if workers < 1:
        raise InputError(f"--workers = {workers} must be >= 1")
    specs = mission_specs(n, n_maps, **(spec_kwargs or {}))
    t0 = time.perf_counter()
    done: list[dict] = []

    def finish(i: int, result: dict) -> None:
        result["index"] = i
        done.append(result)
        if tick is not None:
            tick()
        if on_progress is not None and len(done) % progress_every == 0 and len(done) < n:
            on_progress(study_result(done, n, seed, time.perf_counter() - t0, specs[0], False))

    # the sweep's path: Dask, a local cluster of ``workers`` processes or ``scheduler``'s
    from orange_plan.cluster import dask_client, run_tasks
    from orange_plan.sweep.spec import run_id

    keys = {f"mission-{run_id({'spec': asdict(spec), 'seed': seed + i})}": i
            for i, spec in enumerate(specs)}
    with dask_client(workers, scheduler) as client:
        run_tasks(client, run_one_mission, [(k, (specs[i], seed + i)) for k, i in keys.items()],
                  lambda key, result: finish(keys[key], result))
    return study_result(done, n, seed, time.perf_counter() - t0, specs[0], True)


# --- presentation ------------------------------------------------------------------------


SHORT_LABELS = {"session": "(a) session", "open_loop": "(b) open loop",
                "lawnmower": "(c) lawnmower", "lawnmower_energy": "(e) lawnmower, energy",
                "oracle": "(d) oracle"}


def table_rows(result: dict) -> list[dict]:
    """All missions, then each truth family, then each kind of truth: one row per method."""
    rows = [*result["rows"], *result["by_family"],
            *(r for r in result["by_kind"] if r["family"] != "calibration")]
    return [r for r in rows if r["missions"] or r["errors"]]


def mission_table(result: dict):
    """The terminal table: one row per truth set and method."""
    from rich.table import Table

    title = (f"bench mission: {result['missions']} missions"
             + ("" if result["complete"] else f" of {result['missions_planned']} (PARTIAL)")
             + f", reserve confidence {result['spec']['confidence']:g}")
    caption = ("p95: 95 % upper bound of the stranding probability; left: median energy left "
               "at home (missions that got home); cov/or.: median coverage / the oracle's")
    t = Table(title=title, caption=caption, header_style="bold")
    for col in ("truths", "method", "n", "stranded", "p95", "left kJ", "cov m2", "cov/or.",
                "replans"):
        left = col in ("truths", "method")
        t.add_column(col, justify="left" if left else "right", no_wrap=left)
    last = None
    for r in table_rows(result):
        if last is not None and r["family"] != last:
            t.add_section()
        last = r["family"]
        t.add_row(r["family"], SHORT_LABELS[r["method"]], str(r["missions"]),
                  str(r["strandings"]), _fmt(r["stranding_upper95"], ".1%"),
                  _fmt(r["energy_left_at_home_kJ"], ".2f"), _fmt(r["coverage_m2"], ",.0f"),
                  _fmt(r["coverage_over_oracle"], ".2f"), _fmt(r["replans"], ".0f"))
    return t


def mission_figure(result: dict, path) -> Path:
    """PNG of ``mission_plot`` (written atomically)."""
    from orange_plan.atomic import save_figure

    return save_figure(mission_plot(result), path)


def mission_plot(result: dict):
    """Coverage relative to the oracle against the share of missions stranded, one marker
    per method and truth family (matplotlib Figure). The stranded axis runs as far as the
    data need (never past 100 %); methods at the same place share one label."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.5, 4.8))
    markers = {"session": "o", "open_loop": "^", "lawnmower": "s", "lawnmower_energy": "P",
               "oracle": "D"}
    colours = {"all": "k", "within": "tab:blue", "beyond": "tab:red"}
    points = []  # (share %, coverage %, method) of the all-truths markers
    shares, coverages = [0.0], [100.0 * TARGETS["session_over_oracle"]]
    for r in [*result["rows"], *result["by_family"]]:
        if not r["missions"] or r["coverage_over_oracle"] is None:
            continue
        share = 100.0 * r["strandings"] / r["missions"]
        coverage = 100.0 * r["coverage_over_oracle"]
        shares.append(share)
        coverages.append(coverage)
        big = r["family"] == "all"
        ax.scatter(share, coverage, marker=markers[r["method"]], s=90 if big else 45,
                   color=colours[r["family"]], edgecolor="k", linewidth=0.5,
                   zorder=4 if big else 3, alpha=1.0 if big else 0.85)
        if big:
            points.append((share, coverage, r["method"]))
    ax.axhline(100 * TARGETS["session_over_oracle"], color="grey", ls="--", lw=1,
               label=f"target for (a): {100 * TARGETS['session_over_oracle']:.0f} % of the oracle")
    for m, mk in markers.items():
        ax.scatter([], [], marker=mk, color="lightgrey", edgecolor="k", label=METHOD_LABELS[m])
    for f, c in colours.items():
        ax.scatter([], [], marker="o", color=c, label=f"truths: {f}")
    top = max(shares)
    pad = 0.06 * max(top, 10.0)  # room for the markers, the axis ends at the data
    ax.set_xlim(-pad, max(top, 5.0) + pad)  # none stranded: still a readable 0-5 % scale
    lo, hi = min(coverages), max(coverages)
    ypad = 0.08 * max(hi - lo, 10.0)
    ax.set_ylim(lo - ypad, hi + ypad)
    _label_points(ax, points)
    ax.set_xlabel("missions stranded [%]")
    ax.set_ylabel("median coverage / oracle's median [%]")
    ax.set_title(f"bench mission: {result['missions']} missions, reserve confidence "
                 f"{result['spec']['confidence']:g}"
                 + ("" if result["complete"] else " (partial)"))
    ax.grid(alpha=0.3)
    # beside the axes: a legend inside could sit on a marker
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    fig.tight_layout()
    return fig


def _label_points(ax, points: list) -> None:
    """One label per place: methods whose markers (nearly) coincide are named together
    ("(b) open loop, (d) oracle"), a label on the right half of the axes reads leftwards."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    places: list[list] = []
    for x, y, method in points:
        for place in places:
            if abs(place[0] - x) < 0.04 * (x1 - x0) and abs(place[1] - y) < 0.06 * (y1 - y0):
                place[2].append(method)
                break
        else:
            places.append([x, y, [method]])
    for x, y, methods in places:
        text = ", ".join(SHORT_LABELS[m] for m in sorted(methods, key=list(SHORT_LABELS).index))
        right = x > 0.5 * (x0 + x1)
        ax.annotate(text, (x, y), textcoords="offset points", xytext=(-9 if right else 9, -3),
                    ha="right" if right else "left", fontsize=8, gid="method-label")
