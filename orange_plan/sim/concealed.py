"""Concealed-effect cases: simulated recordings holding physics the scenario's model lacks.

The test data of ``orange-plan diagnose``: each ``ConcealedCase`` is a recording
that contains one or two physical effects (``CONCEALABLE``) while the scenario handed to
diagnosis (``ConcealedCase.ctx``) leaves them out and no column of the recording labels them.
Null cases conceal nothing (the scenario may still have a mis-set coefficient of a term it
already has). Ground cases drive the Kiwibot on the hilly campus
(``scenarios/kiwibot_campus.toml``), aerial ones fly the AR.Drone over its field
(``scenarios/ar_drone_wind.toml``, battery enlarged to last the run), marine ones sail the
survey boat in its bay (``scenarios/marine_survey.toml``: a drift, as a load that rises or
falls through the run, ``_drift_trend``, and a null case whose drag is mis-set).

How a case is made
------------------
1. Motion: ``sim.simulator.simulate`` drives a random route (``_route``: turns, stops, hills
   or a surface as the effect needs; speeds drawn per vertex; a surface case's route is drawn
   again until a quarter to three quarters of the drive is on its surface, ``SURFACE_SHARE``)
   under the *truth* scenario, whose model has the concealed motion terms with their true
   coefficients (``rolling``, ``surface_rolling``, ``aero_drag``, ``grade``, ``inertia``,
   ``regen``, ``turning``, and ``drift_rolling``: the rolling coefficient changing through the
   run, ``concealed_recipes._drift_rolling``) or the
   simulator's truth-only effects (``wind``: mean + Ornstein-Uhlenbeck gusts, not recorded;
   ``payload``: mass change at ``payload_from_s``). Aerial runs lose the simulator's rest at
   both ends, so "stationary at the ends" means landed (``hover``).
2. Power terms the model has (``ancillary``, ``sensor_rate``, ``hover``, ``drift``) are added
   to the simulated power with the model's own terms (``EnergyModel.power_W`` of that term
   alone). ``sensor_rate``'s recording switches ``sensor_rate_Hz`` among 5/10/20/30 Hz;
   ``hover`` adds 30-60 s landed at rest (ancillary only) at both ends.
3. Effects with no Term, as post-processing of the true power P [W]:
   ``hvac``: ``P += hvac_heat_W_per_K max(0, 20 - T_a) + hvac_cool_W_per_K max(0, T_a - 20)``
   (setpoint 20 C, T_a the ``ambient_C`` column; ``hvac_deadband``: heating below 15-21 C
   and cooling above a set-point 2-6 K higher);
   ``battery_resistance``: ``P += k P^2`` (I^2 R at I = P / V: k = R / V^2 [1/W]);
   ``battery_temperature``: ``P += c max(0, 25 - T_b) P^2`` (T_b the ``battery_C`` column).
   The battery losses come last (they act on everything the battery delivers), and their
   runs stop now and then and climb hills (``_varied_load``): a loss ``k P^2`` differs from
   a rescaled model only through the load's spread, which a steady load makes smaller than
   the meter's noise (there, the loss is no longer in the recording to be found).
4. Measurement, on every case: the recorded power lags the motion by 0.1-0.5 s and carries an
   AR(1) disturbance (correlation time 5-20 s, sd 2-5 % of the mean power) and white noise
   (1-3 %); positions carry white noise; ``soc`` follows the true energy.

Every case has the same columns: ``t_s, x_m, y_m, z_m, v_mps, yaw_rate_radps, accel_mps2,
power_W, soc, sensor_rate_Hz, ambient_C, battery_C`` (docs/formats.md): ``ambient_C`` is a smooth
non-monotone walk over 0-35 C (3-10 K of it in ``hvac_trip`` cases) and ``battery_C`` warms
towards 25-30 C from a start at -10..20 C (-10..5 C in ``battery_temperature`` cases), so
neither column's presence or range gives a case away; ``payload_kg`` and the wind columns are
never written, and ``surface`` only by the labelled cases (``surface_label`` and the null
case ``null-ground-labels``: a terrain classifier's labels, late and sometimes wrong,
``_with_labels``), whose scenario's map has no surfaces. (Only ``hover`` cases start and end
landed: without those periods a hover power and an ancillary draw are the same constant.)

Effect sizes: the share of the run's energy the concealed term carries (30-min runs at 10 Hz,
seeds 0-4, docs/guide/diagnosis.md; the surface and battery shares were measured
before those routes changed): power terms are sized from the simulated mean
power (ancillary 14-22 %, sensor rate 9-16 %, drift 6-16 %, hvac 10-23 %, battery resistance
4-10 %, battery temperature 6-10 %); motion terms take physical coefficients (rolling 7-27 %,
surface rolling 5-28 %, drag 15-24 %, grade 14-28 %, turning 9-16 %, wind 5-9 %, payload
1-7 %). Inertia (0.4-2 %) and regen (6-11 %) mostly move energy between moments: the power's
residual RMS halves when they are modelled. Hover is the drone's main draw (72-77 %): a
5-30 % hover would not be a drone.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd
import tomli_w
from scipy.signal import lfilter

from orange_plan.atomic import atomic_path
from orange_plan.context import Context, context_of
from orange_plan.errors import InputError, OrangeError, close_match_hint
from orange_plan.examples import examples_dir
from orange_plan.physics.state import MotionState
from orange_plan.scenario import read_toml, scenario_from_dict
from orange_plan.sim.concealed_recipes import (  # noqa: F401 - the recipes' constants are public here
    BATTERY_WARM_C,
    HVAC_SETPOINT_C,
    RECIPES,
    SENSOR_RATES_HZ,
    TREND_SHAPES,
    TRIP_AMBIENT_SPAN_K,
    _mis_set,
    _Plan,
)
from orange_plan.sim.concealed_routes import STYLES, _pool_ok, _route, _style_surface  # noqa: F401
from orange_plan.sim.simulator import MAX_RATE_HZ, simulate
from orange_plan.sim.truth import Truth
from orange_plan.telemetry.recording import Recording, recording_from_frame, write_recording

CONCEALABLE: tuple[str, ...] = (
    "ancillary", "sensor_rate", "hover", "rolling", "surface_rolling", "aero_drag", "grade",
    "inertia", "regen", "turning", "wind", "payload", "hvac", "battery_resistance",
    "battery_temperature", "drift", "surface_label", "hvac_trip", "drift_rolling",
    "hvac_deadband",
)
"""Vocabulary ids a case can conceal, and two variants: ``surface_label``, per-surface
rolling on a map without surfaces, the recording carrying a terrain classifier's delayed
``surface`` labels (reported as ``surface_rolling``); ``hvac_trip``, the ``hvac`` effect on a
trip whose ambient temperature spans only 3-10 K (reported as ``hvac``); ``drift_rolling``,
the rolling coefficient changing through the run (reported as ``drift``); ``hvac_deadband``,
the ``hvac`` effect of a climate control that heats below one set-point and cools above a
higher one (reported as ``hvac``)."""

PAIRS: tuple[tuple[str, str], ...] = (
    ("turning", "payload"), ("wind", "payload"), ("surface_rolling", "battery_resistance"),
    ("hvac", "inertia"), ("drift", "turning"), ("inertia", "regen"),
)
"""Two concealed effects at once (``concealed_suite``)."""

KINDS: dict[str, tuple[str, ...]] = {
    "ancillary": ("ground", "aerial"), "sensor_rate": ("ground", "aerial"),
    "hover": ("aerial",), "rolling": ("ground",), "surface_rolling": ("ground",),
    "aero_drag": ("aerial",), "grade": ("ground",), "inertia": ("ground", "aerial"),
    "regen": ("ground",), "turning": ("ground",), "wind": ("aerial",),
    "payload": ("ground", "aerial"), "hvac": ("ground", "aerial", "marine"),
    "battery_resistance": ("ground", "aerial"), "battery_temperature": ("ground", "aerial"),
    "drift": ("ground", "aerial", "marine"), "surface_label": ("ground",),
    "hvac_trip": ("ground", "aerial"), "drift_rolling": ("ground",),
    "hvac_deadband": ("ground", "aerial"),
}
"""Robot kinds each term can be concealed on; the first is the default. (Ground drag at the
Kiwibot's 1.2 m/s is under 1 % of its power: too small to conceal. On the drone, a concealed
ancillary draw is a constant beside the hover power: only its default, ground, separates it.)"""

SCENARIOS = {"ground": "kiwibot_campus.toml", "aerial": "ar_drone_wind.toml",
             "marine": "marine_survey.toml"}
"""The example scenario of each kind (``scenarios/``)."""

AERIAL_PACK_S = 450.0
"""Flight time per AR.Drone pack at ~60 W with ~40 % left: the aerial battery is enlarged by
``duration / AERIAL_PACK_S`` so a long run does not empty it [s]."""


@dataclass(frozen=True)
class ConcealedCase:
    """One concealed-effect recording and the scenario diagnosis is given.

    Attributes
    ----------
    name : ``"turning/seed3"``, ``"wind+payload/seed1"``, ``"null-ground/seed2"``
    kind : ``"ground"``, ``"aerial"`` or ``"marine"``
    ctx : the scenario as diagnosis sees it: its model lacks the concealed effect(s)
    recording : the recording cleaned by telemetry's normal reading path
    frame : the same as a recording table (what ``write`` puts in the CSV)
    truth : concealed term id -> {parameter name: true value}; ``{}`` for null cases
    scenario_toml : the TOML mapping of ``ctx`` (map path relative to ``scenarios/``)
    measurement : the recording's measurement effects (not physics, not for diagnosis to
        name): ``lag_s`` of the power behind the motion, the AR(1) disturbance's ``ar_tau_s``
        and ``ar_sd_W``, ``white_sd_W``, ``position_sd_m``
    """

    name: str
    kind: str
    ctx: Context
    recording: Recording
    frame: pd.DataFrame
    truth: dict[str, dict[str, float]]
    scenario_toml: dict = field(repr=False, default_factory=dict)
    measurement: dict[str, float] = field(default_factory=dict)

    def write(self, folder) -> tuple[Path, Path]:
        """Write the scenario TOML and the recording CSV into ``folder`` (for the CLI).

        The map path is written absolute (the case's scenario lives in a scratch folder).
        Both files are written atomically. Returns (scenario path, recording path).
        """
        folder = Path(folder)
        stem = self.name.replace("/", "_")
        data = copy.deepcopy(self.scenario_toml)
        data["map"] = str(self.ctx.scenario.map_path)
        if not self.ctx.world.true_map.surfaces:  # a labelled case: the map without surfaces
            data["map"] = str(_write_map_without_surfaces(self.ctx.scenario.map_path,
                                                          folder / f"{stem}_map.geojson"))
        scenario_path = folder / f"{stem}.toml"
        with atomic_path(scenario_path, ".toml") as tmp:
            tmp.write_text(tomli_w.dumps(data), encoding="utf-8")
        return scenario_path, write_recording(self.frame, folder / f"{stem}.csv")


def _write_map_without_surfaces(source: Path, target: Path) -> Path:
    """Copy the map GeoJSON ``source`` to ``target`` without its surface features (its
    elevation raster copied beside it: a map names its raster in its own folder); atomic.
    Returns ``target``."""
    import json
    import shutil

    data = json.loads(Path(source).read_text(encoding="utf-8"))
    data["features"] = [f for f in data["features"]
                        if f.get("properties", {}).get("kind") != "surface"]
    if "elevation" in data:
        raster = Path(source).parent / data["elevation"]
        data["elevation"] = f"{target.stem}_{raster.name}"
        shutil.copyfile(raster, target.parent / data["elevation"])
    with atomic_path(target, ".geojson") as tmp:
        tmp.write_text(json.dumps(data), encoding="utf-8")
    return target


# --- conditions columns ---------------------------------------------------------------------


def _smooth_walk(rng, t_s: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """A smooth, non-monotone path over [lo, hi]: three random sinusoids with periods between
    a fifth and the whole of the run, rescaled to span the interval."""
    span = max(float(t_s[-1] - t_s[0]), 1.0)
    periods = rng.uniform(0.2, 1.0, 3) * span
    periods[0] = rng.uniform(0.3, 0.6) * span  # at least one full swing: not monotone
    phases = rng.uniform(0, 2 * np.pi, 3)
    amps = rng.uniform(0.5, 1.0, 3)
    wave = sum(a * np.sin(2 * np.pi * t_s / p + ph) for a, p, ph in zip(amps, periods, phases))
    wave = (wave - wave.min()) / max(float(np.ptp(wave)), 1e-9)
    return lo + (hi - lo) * wave


def _battery_temperature_C(rng, t_s: np.ndarray, cold: bool) -> np.ndarray:
    """Battery warming from a start temperature to 25-30 C (time constant 20-40 % of the run),
    with 0.2 C sensor noise [C]."""
    start = rng.uniform(-10.0, 5.0) if cold else rng.uniform(-10.0, 20.0)
    end, tau = rng.uniform(25.0, 30.0), rng.uniform(0.2, 0.4) * max(float(t_s[-1]), 1.0)
    return end + (start - end) * np.exp(-(t_s - t_s[0]) / tau) + rng.normal(0, 0.2, t_s.size)


def _sensor_schedule_Hz(rng, t_s: np.ndarray) -> np.ndarray:
    """Sensor rate switching among ``SENSOR_RATES_HZ`` every 1/12 to 1/5 of the run [Hz]."""
    span = max(float(t_s[-1] - t_s[0]), 1.0)
    edges, rates = [t_s[0]], []
    while edges[-1] <= t_s[-1]:
        edges.append(edges[-1] + rng.uniform(span / 12, span / 5))
        choices = [r for r in SENSOR_RATES_HZ if not rates or r != rates[-1]]
        rates.append(choices[int(rng.integers(len(choices)))])
    return np.asarray(rates)[np.searchsorted(edges, t_s, side="right") - 1]


# --- the case --------------------------------------------------------------------------------


def _check(terms: Sequence[str], kind: str | None, duration_s: float, rate_Hz: float) -> str:
    for t in terms:
        if t not in CONCEALABLE:
            raise InputError(f"concealed term '{t}' is not one of {', '.join(CONCEALABLE)}"
                             + close_match_hint(t, CONCEALABLE))
    if len(set(terms)) != len(terms) or len(terms) > 2:
        raise InputError(f"concealed terms {list(terms)} must be at most two different ids")
    if kind is None:
        kinds = [k for k in ("ground", "aerial") if all(k in KINDS[t] for t in terms)]
        kind = next((KINDS[t][0] for t in terms if KINDS[t][0] in kinds), kinds[0] if kinds
                    else "ground")
    if kind not in SCENARIOS:
        raise InputError(f"kind = {kind!r} must be one of {', '.join(SCENARIOS)}")
    wrong = [t for t in terms if kind not in KINDS[t]]
    if wrong:
        raise InputError(f"term '{wrong[0]}' cannot be concealed on a {kind} robot "
                         f"(only {', '.join(KINDS[wrong[0]])})")
    if not (math.isfinite(duration_s) and duration_s >= 60.0):
        raise InputError(f"duration_s = {duration_s!r} must be at least 60 s")
    if not (0 < rate_Hz <= MAX_RATE_HZ):
        raise InputError(f"rate_Hz = {rate_Hz!r} must be in (0, {MAX_RATE_HZ:g}] Hz")
    return kind


def concealed_case(terms: Sequence[str], seed: int, *, kind: str | None = None,
                   duration_s: float = 1800.0, rate_Hz: float = 10.0,
                   labels: bool = False) -> ConcealedCase:
    """One concealed-effect case (see the module docstring).

    Parameters
    ----------
    terms : concealed term ids (``CONCEALABLE``), one or two; empty: a null case
    seed : random seed; the same (terms, seed, kind, duration, rate) give the same case
    kind : ``"ground"``, ``"aerial"`` or ``"marine"``; None: the terms' default (``KINDS``),
        ground for nulls
    duration_s : length of the run [s] (at least 60)
    rate_Hz : recording rate [Hz]
    labels : write a terrain classifier's ``surface`` column and hand over the map without
        its surfaces (always so for ``surface_label``); a null case with labels drives a world
        whose surfaces all roll alike (``"null-ground-labels"``)

    Returns
    -------
    ConcealedCase

    Raises
    ------
    InputError
        Unknown or repeated term, a term the kind cannot carry, bad duration or rate.
    """
    terms = tuple(terms)
    kind = _check(terms, kind, duration_s, rate_Hz)
    rng = np.random.default_rng([int(seed), tuple(SCENARIOS).index(kind),
                                 *(CONCEALABLE.index(t) + 1 for t in terms)])
    scenario_path = examples_dir("scenarios", "--scenarios") / SCENARIOS[kind]
    base = read_toml(scenario_path, "scenario")
    if kind == "aerial":
        base["battery"]["rated_energy_Wh"] *= max(1.0, duration_s / AERIAL_PACK_S)
    plan = _Plan(kind, duration_s, copy.deepcopy(base), copy.deepcopy(base), concealed=terms)
    base_ctx = context_of(scenario_from_dict(base, scenario_path))
    plan.mass_over_omega_kg = base_ctx.scenario.robot.mass_kg / base_ctx.scenario.omega
    plan.surface_names = base_ctx.world.map.surface_names
    plan.route_style = "mixed" if kind == "ground" else "aerial"
    for term in sorted(terms, key=_ROUTE_PRIORITY.index):  # the route of the most demanding
        RECIPES[term](plan, rng)
    if not terms:
        _mis_set(plan, rng)
    plan.labels = plan.labels or labels
    truth_ctx = context_of(scenario_from_dict(plan.truth_toml, scenario_path))
    seen_ctx = context_of(scenario_from_dict(plan.seen_toml, scenario_path))
    if plan.labels:
        seen_ctx = without_surfaces(seen_ctx)
        if not terms:  # nothing concealed: the ground rolls alike, the labels say nothing
            truth_ctx = _rolling_alike(truth_ctx)
    frame, offset_s = _drive(plan, truth_ctx, rng, duration_s, rate_Hz)
    if "payload" in plan.truth:
        plan.truth["payload"]["payload_from_s"] = plan.sim_truth["payload_from_s"] + offset_s
    if plan.labels:
        frame = _with_labels(plan, context_of(scenario_from_dict(plan.truth_toml, scenario_path)),
                             seen_ctx, frame, rng, rate_Hz)
    frame = _finish(plan, truth_ctx, frame, rng)
    name = f"{case_label(terms, kind, plan.labels)}/seed{seed}"
    recording = recording_from_frame(frame, source=name)
    truth = {t: plan.truth[t] for t in terms}
    return ConcealedCase(name, kind, seen_ctx, recording, frame, truth, plan.seen_toml,
                         {k: float(v) for k, v in plan.measurement.items()})


def drawn_world(world):
    """``world`` on its map as given (no keep-away): where a recorded robot may have been."""
    return replace(world, map=world.true_map, keep_away_m=0.0)


_ROUTE_PRIORITY = ("turning", "surface_rolling", "surface_label", "grade", "regen", "aero_drag",
                   *(t for t in CONCEALABLE if t not in ("turning", "surface_rolling",
                                                         "surface_label", "grade", "regen",
                                                         "aero_drag")))
"""Recipe order: the first sets the route style, later ones keep it (``route_style`` is only
set by route-shaping terms, and the first such term wins)."""


def _drive(plan: _Plan, ctx: Context, rng, duration_s: float, rate_Hz: float):
    """Simulate the motion; returns the frame (true power, no noise) and the shift of the
    simulator's clock onto the recording's [s].

    The routes are drawn on the map as given, not the one the planner grows by the robot's
    size: a recording is of a robot driven anywhere it fits, and the benchmark's cases stay
    the same recordings whatever radius a scenario states."""
    ctx = replace(ctx, world=drawn_world(ctx.world))
    robot = ctx.scenario.robot
    # 30-60 s landed at each end, at most a sixth of a short run each
    landed_s = (np.minimum(rng.uniform(30.0, 60.0, 2), duration_s / 6) if plan.landed
                else np.zeros(2))
    drive_s = duration_s - float(landed_s.sum())
    lo = 0.8 if plan.route_style == "fast" else 0.6
    v_range = (max(robot.v_min_mps, lo * robot.v_max_mps), robot.v_max_mps)
    style = plan.route_style if plan.route_style != "fast" else "aerial"
    truth = Truth(**plan.sim_truth)
    for _ in range(SURFACE_TRIES):
        route = _route(rng, ctx.world, style, 1.2 * robot.v_max_mps * drive_s, v_range)
        frame = simulate(ctx, route, truth, seed=int(rng.integers(2**31)),
                         sample_rate_Hz=rate_Hz, max_duration_s=drive_s).frame
        if _surface_share_ok(ctx, style, frame):
            break
    else:
        raise OrangeError(f"no {style} route spent {SURFACE_SHARE[0]:.0%}-{SURFACE_SHARE[1]:.0%}"
                          f" of its time on the surface in {SURFACE_TRIES} tries")
    offset_s = 0.0
    if plan.kind == "aerial":  # no hovering rest at the ends: stationary at the ends = landed
        moving = np.flatnonzero(frame["v_mps"].to_numpy() > 0)
        frame = frame.iloc[moving[0]:moving[-1] + 1].reset_index(drop=True)
        offset_s = -float(frame["t_s"].iloc[0])
    frame["t_s"] = frame["t_s"] + offset_s
    frame["_airborne"] = True
    if plan.landed:
        frame, shift = _with_landed_ends(frame, ctx, landed_s, 1.0 / rate_Hz)
        offset_s += shift
    return frame, offset_s


SURFACE_SHARE = (0.25, 0.75)
"""Share of its driving time a surface case spends on its surface [-]: a surface's rolling is
its contrast with the others, so both must be driven (a route nearly all on the surface shows
the default coefficient mis-set; one that only brushes it, as a surface route that also
climbs the hills could, hides the surface under the noise)."""
SURFACE_TRIES = 50
"""Routes drawn before a surface case gives up on ``SURFACE_SHARE`` [-]."""


def _surface_share_ok(ctx: Context, style: str, frame: pd.DataFrame) -> bool:
    """True unless ``style`` is a surface route whose drive is outside ``SURFACE_SHARE``."""
    surface = _style_surface(style)
    if surface is None:
        return True
    on = _pool_ok(ctx.world, style, surface)(frame["x_m"].to_numpy(float),
                                             frame["y_m"].to_numpy(float))
    return SURFACE_SHARE[0] <= float(np.mean(on)) <= SURFACE_SHARE[1]


LABEL_LAG_S = (0.5, 3.0)
"""Range of a labelled case's classifier delay: its ``surface`` label at t names the ground at
t - lag [s]."""
LABEL_ERROR_SHARE = (0.02, 0.08)
"""Range of the share of samples a labelled case's classifier names wrongly, in bursts of
0.5-3 s (a shadow, a wet patch) [-]."""


def without_surfaces(ctx: Context) -> Context:
    """``ctx`` on its map with the surface polygons removed (the default surface kept)."""
    world = ctx.world
    return replace(ctx, world=world.with_map(replace(world.true_map, surfaces=())))


def _rolling_alike(ctx: Context) -> Context:
    """``ctx`` with every surface polygon rolling as the default ground (names and shapes
    kept: a route can still be drawn over them and a classifier still names them)."""
    world = ctx.world
    alike = tuple(replace(s, crr=world.default_crr) for s in world.true_map.surfaces)
    return replace(ctx, world=world.with_map(replace(world.true_map, surfaces=alike)))


def _with_labels(plan: _Plan, surfaced: Context, seen: Context, frame: pd.DataFrame, rng,
                 rate_Hz: float) -> pd.DataFrame:
    """The frame with a terrain classifier's ``surface`` column: the surface under the robot
    (``surfaced``'s map: its surface names, else its default surface's), delayed by a lag in
    ``LABEL_LAG_S`` and wrong in bursts (``LABEL_ERROR_SHARE``). A ``surface_label`` case's
    truth becomes each label's rolling coefficient on the column of the map handed over
    (``seen``: the default rolling coefficient everywhere), ``rolling_kg_<label>``, and the
    delay ``label_lag_s``."""
    world = surfaced.world
    code = world.surface_code_at(frame["x_m"].to_numpy(float), frame["y_m"].to_numpy(float))
    names = np.array([*world.map.surface_names, world.default_surface_name])
    true_labels = names[np.where(code >= 0, code, len(names) - 1)]
    lag_s = float(rng.uniform(*LABEL_LAG_S))
    shift = round(lag_s * rate_Hz)
    labels = np.r_[np.repeat(true_labels[:1], shift), true_labels[:len(true_labels) - shift]]
    seen_names = np.unique(true_labels)
    wrong = np.zeros(labels.size, bool)
    error_share = rng.uniform(*LABEL_ERROR_SHARE)
    while wrong.mean() < error_share and seen_names.size > 1:
        start = int(rng.integers(labels.size))
        burst = slice(start, start + max(1, int(rng.uniform(0.5, 3.0) * rate_Hz)))
        others = seen_names[seen_names != labels[start]]
        labels[burst] = others[int(rng.integers(others.size))]
        wrong[burst] = True
    frame["surface"] = labels
    if "surface_label" in plan.truth:
        plan.truth["surface_label"] = {**_label_truth(plan, surfaced, seen, seen_names),
                                       "label_lag_s": shift / rate_Hz}
    return frame


def _label_truth(plan: _Plan, surfaced: Context, seen: Context, names) -> dict:
    """Each label's true rolling coefficient on the seen model's rolling column [kg]: the
    truth's coefficient for that surface times its rolling coefficient over the seen map's
    default one (the seen model charges the default everywhere)."""
    crr = {s.name: s.crr for s in surfaced.world.map.surfaces}  # later features win
    model = surfaced.model
    out = {}
    for name in names:
        coeff = f"rolling_kg_{name}"
        kg = model.coefficient(coeff) if coeff in model.names else model.coefficient("rolling_kg")
        ratio = crr.get(name, surfaced.world.default_crr) / seen.world.default_crr
        out[f"rolling_kg_{str(name).lower()}"] = float(kg * ratio)
    return out


def _with_landed_ends(frame: pd.DataFrame, ctx: Context, landed_s, dt: float):
    """Rows at rest before take-off and after landing; power: the model at rest (no hover)."""
    def rest(n, row):
        part = pd.DataFrame({c: np.repeat(frame[c].iloc[row], n) for c in frame.columns})
        part[["v_mps", "yaw_rate_radps", "accel_mps2"]] = 0.0
        part["_airborne"] = False
        state = MotionState(speed_mps=np.zeros(n), sensor_rate_Hz=part["sensor_rate_Hz"]
                            .to_numpy(float))
        part["power_W"] = np.asarray(ctx.model.power_W(state), float) + np.zeros(n)
        return part

    n0, n1 = (max(1, round(s / dt)) for s in landed_s)
    before, after = rest(n0, 0), rest(n1, -1)
    t_end = float(frame["t_s"].iloc[-1])
    before["t_s"] = np.arange(n0) * dt
    shift = n0 * dt
    after["t_s"] = t_end + shift + dt * np.arange(1, n1 + 1)
    body = frame.assign(t_s=frame["t_s"] + shift)
    return pd.concat([before, body, after], ignore_index=True), shift


def _finish(plan: _Plan, ctx: Context, frame: pd.DataFrame, rng) -> pd.DataFrame:
    """Conditions columns, concealed power and battery effects, soc, measurement effects."""
    t = frame["t_s"].to_numpy(float)
    dt = float(np.median(np.diff(t)))
    frame["ambient_C"] = _smooth_walk(rng, t, *plan.ambient_C)
    frame["battery_C"] = _battery_temperature_C(rng, t, plan.battery_cold)
    if plan.sensor_schedule:
        frame["sensor_rate_Hz"] = _sensor_schedule_Hz(rng, t)
    power = frame["power_W"].to_numpy(float)
    for effect in (*plan.power_effects, *plan.battery_effects):
        power = effect(plan, frame, power, rng)
    usable_J = ctx.scenario.battery.usable_J
    frame["soc"] = np.clip(1.0 - np.cumsum(power) * dt / usable_J, 0.0, 1.0)
    mean_W = float(np.mean(np.abs(power)))
    lag_s = rng.uniform(0.1, 0.5)
    recorded = np.interp(t - lag_s, t, power)
    tau_s, ar_sd = rng.uniform(5.0, 20.0), rng.uniform(0.02, 0.05) * mean_W
    phi = math.exp(-dt / tau_s)
    shocks = rng.standard_normal(t.size) * ar_sd * math.sqrt(1 - phi**2)
    shocks[0] = rng.standard_normal() * ar_sd
    recorded = recorded + lfilter([1.0], [1.0, -phi], shocks)
    white_sd = rng.uniform(0.01, 0.03) * mean_W
    recorded = recorded + rng.standard_normal(t.size) * white_sd
    frame["power_W"] = recorded
    pos_sd = rng.uniform(0.03, 0.10) if plan.kind == "ground" else rng.uniform(0.2, 0.5)
    plan.measurement = {"lag_s": lag_s, "ar_tau_s": tau_s, "ar_sd_W": ar_sd,
                        "white_sd_W": white_sd, "position_sd_m": pos_sd}
    for c in ("x_m", "y_m"):
        frame[c] = frame[c] + rng.standard_normal(t.size) * pos_sd
    keep = ["t_s", "x_m", "y_m", "z_m", "v_mps", "yaw_rate_radps", "accel_mps2", "power_W",
            "soc", "sensor_rate_Hz", "ambient_C", "battery_C"]
    keep += ["surface"] if plan.labels else []
    return frame[keep].reset_index(drop=True)


def suite_requests() -> list[tuple[tuple[str, ...], str | None]]:
    """(terms, kind) of one seed of the suite: every term of ``CONCEALABLE`` (its default
    kind), every pair of ``PAIRS``, the marine drift, then the ground, aerial and marine null
    cases."""
    return [*(((t,), None) for t in CONCEALABLE), *((p, None) for p in PAIRS),
            (("drift",), "marine"), ((), "ground"), ((), "aerial"), ((), "marine")]


def case_label(terms: Sequence[str], kind: str | None, labels: bool = False) -> str:
    """The name of a case without its seed: ``"wind+payload"``, ``"null-ground"``, a term
    on a kind other than its default ``"drift-marine"``, and a null case with a classifier's
    surface ``labels`` ``"null-ground-labels"``."""
    if not terms:
        return f"null-{kind or 'ground'}{'-labels' if labels else ''}"
    label = "+".join(terms)
    return label if kind is None or kind == KINDS[terms[0]][0] else f"{label}-{kind}"


def suite_names() -> list[str]:
    """The names of one seed's cases (``concealed_suite``), in order, without the seed."""
    return [label for label, *_ in _suite_entries()]


def kept_by_name(known: Sequence[str], only: Collection[str] | None) -> list[bool]:
    """Which of the case names ``known`` the names ``only`` keep (None: all of them).

    Raises
    ------
    InputError
        A name in ``only`` that is not one of ``known`` (the closest named).
    """
    unknown = [n for n in (only or ()) if n not in known]
    if unknown:
        raise InputError(f"unknown case '{unknown[0]}'; known: {', '.join(known)}"
                         + close_match_hint(unknown[0], known))
    return [only is None or name in only for name in known]


def _suite_entries() -> list[tuple[str, tuple[str, ...], str | None, bool]]:
    """(name, terms, kind, labels) of one seed's cases: ``suite_requests``, then the ground
    null case with a classifier's surface labels."""
    requests = [*((terms, kind, False) for terms, kind in suite_requests()), ((), "ground", True)]
    return [(case_label(*request), *request) for request in requests]


def concealed_suite(seeds: Iterable[int], duration_s: float = 1800.0,
                    rate_Hz: float = 10.0,
                    only: Collection[str] | None = None) -> list[ConcealedCase]:
    """Every case of ``suite_requests`` for each seed, then the ground null case with a
    classifier's surface labels (seed by seed, in that order); with ``only``, the cases of
    those names (``suite_names``) alone, the others not generated.

    Raises
    ------
    InputError
        A name in ``only`` that is not a case of the suite.
    """
    entries = _suite_entries()
    kept = kept_by_name([name for name, *_ in entries], only)
    return [concealed_case(terms, seed, kind=kind, duration_s=duration_s, rate_Hz=rate_Hz,
                           labels=labels)
            for seed in seeds
            for (_name, terms, kind, labels), keep in zip(entries, kept) if keep]
