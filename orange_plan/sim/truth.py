"""The simulator's truth: what the real world does that the planning model does not know.

A TRUTH.toml file holds only the truth-only effects; everything else (the terms, their
maths, the map) comes from the scenario. Every table and key is optional::

    [coefficients]          # overrides of the lumped coefficients theta (model.names)
    drag_kg_per_m = 0.35    #   e.g. the real robot is draggier than the scenario says

    [wind]                  # replaces the scenario's [environment] wind
    mean_mps = 6.0          #   mean wind speed [m/s]
    from_deg = 270.0        #   meteorological direction it blows from [deg]
    gust_std_mps = 2.0      #   std of Ornstein-Uhlenbeck gusts on each horizontal axis [m/s]
    gust_tau_s = 8.0        #   gust correlation time [s]
    recorded = true         #   write the true wind into wind_mps / wind_from_deg

    [payload]
    extra_kg = 1.0          #   mass picked up at from_s (negative: dropped) [kg]
    from_s = 600.0          #   mission time of the change [s]

    [terrain]
    roughness_crr_std = 0.005  # std of a spatially correlated crr perturbation [-]
    roughness_length_m = 2.0   # its correlation length along the path [m]

    [battery]
    capacity_factor = 0.95  #   true usable energy / the scenario's (ageing, cold) [-]

    [noise]
    power_std_W = 1.0       #   white noise on the recorded power [W]
    position_std_m = 0.05   #   white noise on the recorded x_m, y_m [m]

    [stops]
    every_s = 60.0          #   moving time between duty-cycle stops [s]

Notes
-----
Payload scales the mass-proportional coefficients (``model_builder.LUMPED`` rows marked
``mass``: rolling, surface rolling, grade, inertia, rolling torque) by ``(m + extra) / m``
and, for a robot with a hover term, scales the hover power by ``((m + extra) / m) ** 1.5``
(momentum theory: induced power grows as weight^1.5).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from orange_plan.errors import InputError, close_match_hint
from orange_plan.physics.profile import STOP_EVERY_S
from orange_plan.physics.wind import wind_xy_mps
from orange_plan.scenario import (
    ABSENT,
    BOOLEAN,
    any_number,
    check_table,
    non_negative,
    positive,
    read_toml,
)


@dataclass(frozen=True)
class Wind:
    """True wind: mean vector plus Ornstein-Uhlenbeck gusts (see module docstring)."""

    mean_mps: float = 0.0
    from_deg: float = 0.0
    gust_std_mps: float = 0.0
    gust_tau_s: float = 10.0
    recorded: bool = True

    @property
    def mean_xy_mps(self) -> tuple[float, float]:
        """Mean wind vector (x east, y north) [m/s] (reference-model convention)."""
        return wind_xy_mps(self.mean_mps, self.from_deg)


@dataclass(frozen=True)
class Truth:
    """Truth-only effects of a simulation (all default to "none").

    Attributes
    ----------
    coefficients : overrides of the scenario model's lumped coefficients
    wind : true wind, or None to use the scenario's wind without gusts
    payload_kg, payload_from_s : mass change and when it happens [kg], [s]
    roughness_crr_std, roughness_length_m : crr perturbation std [-] and length [m]
    capacity_factor : true usable energy / scenario usable energy [-]
    power_std_W, position_std_m : recording noise [W], [m]
    stop_every_s : moving time between duty-cycle stops [s]
    """

    coefficients: dict[str, float] = field(default_factory=dict)
    wind: Wind | None = None
    payload_kg: float = 0.0
    payload_from_s: float = 0.0
    roughness_crr_std: float = 0.0
    roughness_length_m: float = 2.0
    capacity_factor: float = 1.0
    power_std_W: float = 0.0
    position_std_m: float = 0.0
    stop_every_s: float = STOP_EVERY_S


_SCHEMA: dict[str, dict[str, tuple[str, Any]]] = {
    # table -> key -> (Truth field or "wind.<field>", check of ``scenario.check_table``)
    "wind": {"mean_mps": ("wind.mean_mps", non_negative), "from_deg": ("wind.from_deg", any_number),
             "gust_std_mps": ("wind.gust_std_mps", non_negative),
             "gust_tau_s": ("wind.gust_tau_s", positive), "recorded": ("wind.recorded", BOOLEAN)},
    "payload": {"extra_kg": ("payload_kg", any_number), "from_s": ("payload_from_s", non_negative)},
    "terrain": {"roughness_crr_std": ("roughness_crr_std", non_negative),
                "roughness_length_m": ("roughness_length_m", positive)},
    "battery": {"capacity_factor": ("capacity_factor", positive)},
    "noise": {"power_std_W": ("power_std_W", non_negative),
              "position_std_m": ("position_std_m", non_negative)},
    "stops": {"every_s": ("stop_every_s", positive)},
}


def load_truth(path: str | Path | None) -> Truth:
    """Read a TRUTH.toml file (None: no truth-only effects).

    Raises
    ------
    InputError
        Missing file, bad TOML, unknown table or key (with a close-match hint), bad value.
    """
    if path is None:
        return Truth()
    path = Path(path)
    return truth_from_dict(read_toml(path, "truth", InputError), str(path))


def truth_from_dict(data: dict, where: str = "truth") -> Truth:
    """Validate a parsed truth mapping (see the module docstring for the format)."""
    tables = set(_SCHEMA) | {"coefficients"}
    values: dict[str, Any] = {}
    wind: dict[str, Any] = {}
    for table, content in data.items():
        if table not in tables:
            raise InputError(f"{where}: unknown table [{table}]" + close_match_hint(table, tables))
        if table == "coefficients":
            schema = {k: (ABSENT, any_number) for k in content} if isinstance(content, dict) else {}
            values["coefficients"] = check_table(content, schema, table, where, InputError)
            continue
        schema = {key: (ABSENT, check) for key, (_, check) in _SCHEMA[table].items()}
        for key, value in check_table(content, schema, table, where, InputError).items():
            target = _SCHEMA[table][key][0]
            if target.startswith("wind."):
                wind[target[5:]] = value
            else:
                values[target] = value
    if wind:
        values["wind"] = Wind(**wind)
    return Truth(**values)
