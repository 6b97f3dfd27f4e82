"""Scenario TOML -> frozen dataclasses, validated with close-match hints."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from orange_plan.errors import InputError, ScenarioError, close_match_hint
from orange_plan.files import file_problem, require_file
from orange_plan.physics.battery import Battery, Losses
from orange_plan.physics.terms import EXTRA_TERM_IDS, model_coefficient_names
from orange_plan.physics.wind import wind_xy_mps

ROBOT_KINDS = ("ground", "aerial", "marine")
REQUIRED = object()
"""Schema default of a key that must be given."""
ABSENT = object()
"""Schema default of an optional key left out of the checked values when not given."""
BOOLEAN = object()
"""Schema check of a key that must be true or false."""


def positive(v):
    return None if v > 0 else "must be > 0"


def non_negative(v):
    return None if v >= 0 else "must be >= 0"


def _fraction_open(v):
    return None if 0 <= v < 1 else "must be a loss fraction in [0, 1) (efficiency in (0, 1])"


def _unit_interval(v):
    return None if 0 <= v <= 1 else "must be in [0, 1]"


def _duty(v):
    return None if 0 < v <= 1 else "must be in (0, 1] (fraction of mission time spent moving)"


def any_number(v):
    return None


def _celsius(v):
    return None if v > -273.15 else "must be above absolute zero (-273.15 C)"


# section -> key -> (default or REQUIRED, check). A check returns None or the complaint.
NUMBER_SCHEMA: dict[str, dict[str, tuple[Any, Callable]]] = {
    "robot": {
        "mass_kg": (REQUIRED, positive),
        "crr": (REQUIRED, _unit_interval),
        "drag_coeff_kg_per_m": (0.0, non_negative),
        "v_min_mps": (0.1, positive),
        "v_max_mps": (REQUIRED, positive),
        "accel_max_mps2": (0.5, positive),
        "hover_W": (0.0, non_negative),
        "turn_coeff_W_s_per_rad": (0.0, non_negative),
        "radius_m": (0.0, non_negative),
        "climb_mps": (ABSENT, positive),
        "descent_mps": (ABSENT, positive),
        "landing_mps": (ABSENT, positive),
    },
    "losses": {
        "battery": (REQUIRED, _fraction_open),
        "motor": (REQUIRED, _fraction_open),
        "mechanical": (REQUIRED, _fraction_open),
        "ancillary": (REQUIRED, _fraction_open),
    },
    "battery": {
        "rated_energy_Wh": (REQUIRED, positive),
        "cycles": (0.0, non_negative),
        "age_days": (0.0, non_negative),
        "k1_per_cycle": (0.0, non_negative),
        "k2_per_day": (0.0, non_negative),
    },
    "ancillary": {
        "s0_W": (0.0, non_negative),
        "s1_W_per_Hz": (0.0, non_negative),
        "sensor_rate_Hz": (0.0, non_negative),
        "compute_W": (0.0, non_negative),
        "comm_W": (0.0, non_negative),
    },
    "mission": {
        "duty_cycle": (REQUIRED, _duty),
        "sensor_radius_m": (1.0, positive),
        "time_limit_s": (None, positive),
        "clearance_m": (0.0, non_negative),
    },
    "environment": {
        "wind_speed_mps": (0.0, non_negative),
        "wind_from_deg": (0.0, any_number),
        "ambient_C": (20.0, _celsius),
    },
}
OTHER_KEYS = {
    "": {"name", "map", "robot", "losses", "battery", "ancillary", "mission", "environment", "model"},
    "robot": {"kind"},
    "mission": {"home_xy_m", "reserve"},
}
RESERVE_KINDS = {"confidence": "in (0, 1)", "fraction": "in [0, 1)", "energy_J": ">= 0"}
MODEL_EXTRA_TERMS = EXTRA_TERM_IDS
DEFAULT_PRIOR_RELATIVE_STDERR = 0.10
"""A priori (uncalibrated) standard error of each coefficient, relative to its value [-]."""
DEFAULT_DISCREPANCY_REL_SD = 0.25
"""A priori run-to-run standard deviation of a whole run's energy, relative to the predicted
energy [-], for a model not calibrated on several runs. Measured on the real recordings
(docs/benchmarks/calibration.md): the upper semi-deviation of calibrated models' held-out whole-run errors
(``identify.calibrate``) is 0.35 on the Husky A200 (44 runs) and 0.086 on the BMW i3 (16);
0.25 is their root mean square, one value per robot."""


@dataclass(frozen=True)
class Robot:
    """[robot]: the platform. Units in the names; see docs/formats.md."""

    kind: str
    mass_kg: float
    crr: float
    drag_coeff_kg_per_m: float
    v_min_mps: float
    v_max_mps: float
    accel_max_mps2: float
    hover_W: float
    turn_coeff_W_s_per_rad: float
    radius_m: float = 0.0
    """Radius of the disc that holds the robot's footprint [m]: every path keeps this far
    from obstacles, no-go zones and the boundary (0: a point robot)."""
    climb_mps: float | None = None
    """Vertical climb speed of an aerial robot [m/s] (None: ``planning.mission_check``'s
    default, capped at ``v_max_mps``)."""
    descent_mps: float | None = None
    """Vertical descent speed of an aerial robot [m/s] (None: the default, as ``climb_mps``)."""
    landing_mps: float | None = None
    """Descent speed of an aerial robot's final landing [m/s] (None: ``descent_mps``)."""


@dataclass(frozen=True)
class Ancillary:
    """[ancillary]: sensing, computing and communication loads (Eq. 5, 10) [W]."""

    s0_W: float
    s1_W_per_Hz: float
    sensor_rate_Hz: float
    compute_W: float
    comm_W: float

    @property
    def load_W(self) -> float:
        """Ancillary load before its loss eta_4 [W]."""
        return self.s0_W + self.s1_W_per_Hz * self.sensor_rate_Hz + self.compute_W + self.comm_W


@dataclass(frozen=True)
class Reserve:
    """[mission].reserve: ``kind`` is confidence, fraction or energy_J."""

    kind: str
    value: float


@dataclass(frozen=True)
class Mission:
    """[mission]: home override, duty cycle D, sensor footprint, reserve, time limit."""

    duty_cycle: float
    sensor_radius_m: float
    reserve: Reserve
    home_xy_m: tuple[float, float] | None = None
    time_limit_s: float | None = None
    clearance_m: float = 0.0
    """Extra gap kept beyond ``robot.radius_m`` from obstacles, no-go zones and the boundary [m]."""


@dataclass(frozen=True)
class Environment:
    """[environment]: wind (or water current) and ambient temperature."""

    wind_speed_mps: float
    wind_from_deg: float
    ambient_C: float

    @property
    def wind_xy_mps(self) -> tuple[float, float]:
        """Wind vector (x east, y north) from the meteorological direction [m/s]."""
        return wind_xy_mps(self.wind_speed_mps, self.wind_from_deg)


@dataclass(frozen=True)
class ModelSpec:
    """[model]: extra terms beyond the reference model, their coefficients, uncertainties."""

    terms: tuple[str, ...] = ()
    coefficients: Mapping[str, float] = field(default_factory=dict)
    stderr: Mapping[str, float] = field(default_factory=dict)
    prior_relative_stderr: float = DEFAULT_PRIOR_RELATIVE_STDERR
    discrepancy_rel_sd: float = DEFAULT_DISCREPANCY_REL_SD
    drift: tuple = ()
    """The ``drift`` term's ``(shape, tau_s, from_s)`` (``physics.terms.drift_term``); ()
    for the vocabulary's cold-start decay."""
    drift_rolling: tuple = ()
    """The ``drift_rolling`` term's ``(shape, tau_s, from_s)``
    (``physics.terms.drift_rolling_term``); () for the default decay."""
    hvac_ambient: tuple = ()
    """The ``hvac_ambient`` term's set-points ``(heat_below_C, cool_above_C)``
    (``physics.terms.hvac_ambient_term``); () for the vocabulary's single set-point."""


@dataclass(frozen=True)
class Scenario:
    """One robot, one battery, one map, one mission."""

    name: str
    path: Path
    map_path: Path
    robot: Robot
    losses: Losses
    battery: Battery
    ancillary: Ancillary
    mission: Mission
    environment: Environment
    model: ModelSpec

    @property
    def omega(self) -> float:
        """Manoeuvring efficiency Omega [-]."""
        return self.losses.omega

    @property
    def keep_away_m(self) -> float:
        """Distance every path keeps from obstacles, no-go zones and the boundary:
        ``robot.radius_m + mission.clearance_m`` [m]."""
        return self.robot.radius_m + self.mission.clearance_m

    @property
    def ancillary_power_W(self) -> float:
        """Battery-side ancillary power P_anc [W]."""
        return self.ancillary.load_W / (1.0 - self.losses.ancillary) + self.robot.hover_W


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file.

    Raises
    ------
    ScenarioError
        One line naming the file, the key and the problem (missing key, unknown key with a
        close-match hint, wrong type, out-of-range value, missing map file).
    """
    path = Path(path)
    return scenario_from_dict(read_toml(path, "scenario"), path)


MIN_CAPACITY_FRACTION = 1e-3
"""Capacity left after decay, exp(-(k1 C + k2 t)), below which the battery is exhausted."""


def _check_not_exhausted(battery: Battery, where: str) -> None:
    """Refuse a battery that capacity decay has emptied: every range and plan would be 0 m."""
    fraction = battery.capacity_J / battery.rated_energy_J if battery.rated_energy_J else 0.0
    if fraction < MIN_CAPACITY_FRACTION:
        raise ScenarioError(
            f"{where}: the battery is exhausted: capacity decay exp(-(k1_per_cycle*cycles + "
            f"k2_per_day*age_days)) leaves {fraction:.3g} of the rated energy (below "
            f"{MIN_CAPACITY_FRACTION:g}); check battery.cycles, age_days, k1_per_cycle, k2_per_day"
        )


def read_toml(path: Path, kind: str, error: type[InputError] = ScenarioError) -> dict:
    """Parse a TOML file; a missing file or bad TOML is one ``error`` line naming the file."""
    require_file(path, kind, error)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{path}: not a valid TOML file ({exc})") from None
    except RecursionError:
        raise error(f"{path}: not a valid TOML file (nested too deeply)") from None


def scenario_from_dict(data: Mapping[str, Any], path: Path) -> Scenario:
    """Validate a parsed scenario mapping; ``path`` locates the map and names errors."""
    where = str(path)
    _check_keys(data, OTHER_KEYS[""], "", where)
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise ScenarioError(f"{where}: name must be a non-empty string")
    if "map" not in data:
        raise ScenarioError(f"{where}: missing key 'map' (path of the map GeoJSON)")
    if not isinstance(data["map"], str):
        raise ScenarioError(f"{where}: map must be a path string, got {data['map']!r}")
    map_path = (path.parent / data["map"]).resolve()
    problem = file_problem(map_path, data["map"], "map GeoJSON")
    if problem:
        raise ScenarioError(f"{where}: map file {problem}")

    values = {sec: _numbers(data, sec, where) for sec in NUMBER_SCHEMA}
    robot_tbl = data.get("robot", {})
    kind = robot_tbl.get("kind", REQUIRED)
    if kind is REQUIRED:
        raise ScenarioError(f"{where}: missing key 'robot.kind' (one of {', '.join(ROBOT_KINDS)})")
    if kind not in ROBOT_KINDS:
        raise ScenarioError(
            f"{where}: robot.kind = {kind!r} must be one of {', '.join(ROBOT_KINDS)}"
            + close_match_hint(str(kind), ROBOT_KINDS)
        )
    robot = Robot(kind=kind, **values["robot"])
    if robot.v_min_mps > robot.v_max_mps:
        raise ScenarioError(
            f"{where}: robot.v_min_mps = {robot.v_min_mps} exceeds robot.v_max_mps = {robot.v_max_mps}"
        )
    losses = Losses(**values["losses"])
    battery = Battery(storage_loss=losses.battery, **values["battery"])
    _check_not_exhausted(battery, where)
    mission_tbl = data.get("mission", {})
    mission = Mission(
        home_xy_m=_home(mission_tbl.get("home_xy_m"), where),
        reserve=_reserve(mission_tbl.get("reserve", {"fraction": 0.0}), where),
        **values["mission"],
    )
    return Scenario(
        name=name,
        path=path,
        map_path=map_path,
        robot=robot,
        losses=losses,
        battery=battery,
        ancillary=Ancillary(**values["ancillary"]),
        mission=mission,
        environment=Environment(**values["environment"]),
        model=_model_spec(data.get("model", {}), where),
    )


def _check_keys(table: Mapping[str, Any], allowed, section: str, where: str,
                error: type[InputError] = ScenarioError) -> None:
    for key in table:
        if key not in allowed:
            dotted = f"{section}.{key}" if section else key
            raise error(f"{where}: unknown key '{dotted}'" + close_match_hint(key, allowed))


def _number(value, dotted: str, where: str, error: type[InputError] = ScenarioError) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise error(f"{where}: {dotted} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise error(f"{where}: {dotted} must be finite, got {value!r}")
    return float(value)


def check_table(table, schema: Mapping[str, tuple[Any, Callable]], section: str, where: str,
                error: type[InputError] = ScenarioError, other_keys=()) -> dict[str, Any]:
    """Validate one TOML table against ``schema``: key -> (default, check).

    The default is a value, ``REQUIRED`` or ``ABSENT`` (not given: left out of the result);
    a check returns None or the complaint (``BOOLEAN``: the value must be true or false).
    Unknown keys (other than ``other_keys``) are refused with a close-match hint. Used by
    scenario files and by the simulator's truth files.
    """
    if not isinstance(table, Mapping):
        raise error(f"{where}: [{section}] must be a table, got {table!r}")
    _check_keys(table, set(schema) | set(other_keys), section, where, error)
    out = {}
    for key, (default, check) in schema.items():
        dotted = f"{section}.{key}"
        if key not in table:
            if default is REQUIRED:
                raise error(f"{where}: missing key '{dotted}'")
            if default is not ABSENT:
                out[key] = default
            continue
        if check is BOOLEAN:
            if not isinstance(table[key], bool):
                raise error(f"{where}: {dotted} must be true or false, got {table[key]!r}")
            out[key] = table[key]
            continue
        value = _number(table[key], dotted, where, error)
        problem = check(value)
        if problem:
            raise error(f"{where}: {dotted} = {value:g} {problem}")
        out[key] = value
    return out


def _numbers(data, section: str, where: str) -> dict[str, Any]:
    return check_table(data.get(section, {}), NUMBER_SCHEMA[section], section, where,
                       other_keys=OTHER_KEYS.get(section, set()))


def _home(value, where: str):
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != 2:
        raise ScenarioError(f"{where}: mission.home_xy_m must be [x, y] in metres, got {value!r}")
    return (_number(value[0], "mission.home_xy_m[0]", where),
            _number(value[1], "mission.home_xy_m[1]", where))


def _reserve(value, where: str) -> Reserve:
    if not isinstance(value, Mapping) or len(value) != 1:
        raise ScenarioError(
            f"{where}: mission.reserve must be one of {{ confidence = p }}, {{ fraction = f }}, "
            f"{{ energy_J = E }}, got {value!r}"
        )
    (kind, raw), = value.items()
    if kind not in RESERVE_KINDS:
        raise ScenarioError(
            f"{where}: unknown key 'mission.reserve.{kind}'" + close_match_hint(kind, RESERVE_KINDS)
        )
    v = _number(raw, f"mission.reserve.{kind}", where)
    ok = {"confidence": 0 < v < 1, "fraction": 0 <= v < 1, "energy_J": v >= 0}[kind]
    if not ok:
        raise ScenarioError(f"{where}: mission.reserve.{kind} = {v:g} must be {RESERVE_KINDS[kind]}")
    return Reserve(kind, v)


def _model_spec(table, where: str) -> ModelSpec:
    if not isinstance(table, Mapping):
        raise ScenarioError(f"{where}: [model] must be a table")
    terms = table.get("terms", [])
    if not isinstance(terms, list) or not all(isinstance(t, str) for t in terms):
        raise ScenarioError(f"{where}: model.terms must be a list of term ids, got {terms!r}")
    for t in terms:
        if t not in MODEL_EXTRA_TERMS:
            raise ScenarioError(
                f"{where}: model.terms holds unknown term '{t}' (known extra terms: "
                f"{', '.join(MODEL_EXTRA_TERMS)})" + close_match_hint(t, MODEL_EXTRA_TERMS)
            )
    allowed_coefs = model_coefficient_names(terms)
    coefficients, stderr = {}, {}
    fractions = {"prior_relative_stderr": DEFAULT_PRIOR_RELATIVE_STDERR,
                 "discrepancy_rel_sd": DEFAULT_DISCREPANCY_REL_SD}
    drift = {t: _drift_spec(table, terms, where, t) for t in DRIFT_TERMS}
    hvac_setpoints = _hvac_setpoints(table, terms, where)
    for key, value in table.items():
        if key == "terms" or key in SHAPE_KEYS:
            continue
        if key in fractions:
            fractions[key] = _number(value, f"model.{key}", where)
            if fractions[key] < 0:
                raise ScenarioError(f"{where}: model.{key} = {fractions[key]:g} must be >= 0")
        elif key == "stderr":
            if not isinstance(value, Mapping):
                raise ScenarioError(f"{where}: model.stderr must be a table of coefficient = value")
            for name, sv in value.items():
                stderr[name] = _number(sv, f"model.stderr.{name}", where)
                if stderr[name] < 0:
                    raise ScenarioError(f"{where}: model.stderr.{name} must be >= 0")
        elif key in allowed_coefs or ("surface_rolling" in terms and key.startswith("rolling_kg_")):
            coefficients[key] = _number(value, f"model.{key}", where)
        else:
            options = set(allowed_coefs) | {"terms", "stderr", *fractions}
            raise ScenarioError(f"{where}: unknown key 'model.{key}'" + close_match_hint(key, options))
    return ModelSpec(tuple(terms), coefficients, stderr, **fractions, drift=drift["drift"],
                     drift_rolling=drift["drift_rolling"], hvac_ambient=hvac_setpoints)


DRIFT_TERMS = ("drift", "drift_rolling")
"""Terms with a shape over mission time, each set by ``<term>_shape``, ``<term>_tau_s`` and
``<term>_from_s`` in [model]."""
DRIFT_KEYS = tuple(f"{t}_{k}" for t in DRIFT_TERMS for k in ("shape", "tau_s", "from_s"))
"""[model] keys of the drift terms' shapes (``physics.terms.drift_term``)."""
HVAC_SETPOINT_KEYS = ("hvac_ambient_heat_below_C", "hvac_ambient_cool_above_C")
"""[model] keys of the ``hvac_ambient`` term's set-points (``physics.terms.hvac_ambient_term``)."""
SHAPE_KEYS = DRIFT_KEYS + HVAC_SETPOINT_KEYS
"""Every [model] key that shapes a term rather than giving a coefficient."""


def _hvac_setpoints(table, terms, where: str) -> tuple:
    """``(heat_below_C, cool_above_C)`` of the ``hvac_ambient`` term from [model]
    ``hvac_ambient_heat_below_C`` and ``hvac_ambient_cool_above_C``; one given alone leaves
    the other at the vocabulary's set-point (20 C), or at the given one where 20 C would
    cross it. () when neither is given."""
    from orange_plan.physics.terms import HVAC_SETPOINT_C, HVAC_SETPOINT_RANGE_C

    given = [key for key in HVAC_SETPOINT_KEYS if key in table]
    if not given:
        return ()
    if "hvac_ambient" not in terms:
        raise ScenarioError(f"{where}: model.{given[0]} needs 'hvac_ambient' in model.terms")
    heat_key, cool_key = HVAC_SETPOINT_KEYS
    first = _number(table[given[0]], f"model.{given[0]}", where)
    heat = _number(table.get(heat_key, min(first, HVAC_SETPOINT_C)), f"model.{heat_key}", where)
    cool = _number(table.get(cool_key, max(first, HVAC_SETPOINT_C)), f"model.{cool_key}", where)
    lo, hi = HVAC_SETPOINT_RANGE_C
    if not (lo <= heat <= cool <= hi):
        raise ScenarioError(f"{where}: model.{heat_key} = {heat:g} and model.{cool_key} = "
                            f"{cool:g} must satisfy {lo:g} <= heat <= cool <= {hi:g} (degC)")
    return (heat, cool)


def _drift_spec(table, terms, where: str, term: str = "drift") -> tuple:
    """``(shape, tau_s, from_s)`` of drift term ``term`` from [model] ``<term>_shape`` (decay,
    linear or step), ``<term>_tau_s`` (> 0) and ``<term>_from_s`` (>= 0); () when none is
    given."""
    from orange_plan.physics.terms import DRIFT_SHAPES, DRIFT_TAU_S

    given = [key for key in (f"{term}_{k}" for k in ("shape", "tau_s", "from_s")) if key in table]
    if not given:
        return ()
    if term not in terms:
        raise ScenarioError(f"{where}: model.{given[0]} needs '{term}' in model.terms")
    shape = table.get(f"{term}_shape", "decay")
    if shape not in DRIFT_SHAPES:
        raise ScenarioError(f"{where}: model.{term}_shape = {shape!r} must be one of "
                            f"{', '.join(DRIFT_SHAPES)}")
    tau = _number(table.get(f"{term}_tau_s", DRIFT_TAU_S), f"model.{term}_tau_s", where)
    start = _number(table.get(f"{term}_from_s", 0.0), f"model.{term}_from_s", where)
    if not (tau > 0 and start >= 0):
        raise ScenarioError(f"{where}: model.{term}_tau_s must be > 0 and model.{term}_from_s "
                            ">= 0")
    return (shape, tau, start)
