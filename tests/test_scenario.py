"""Scenario TOML loading (docs/formats.md, scenario): values, defaults, the [model] table and every error."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import write_scenario

from orange_plan.errors import InputError, ScenarioError
from orange_plan.physics.model_builder import build_model, reference_term_ids
from orange_plan.physics.terms import DEFAULT_REGEN_EFFICIENCY
from orange_plan.scenario import (
    DEFAULT_DISCREPANCY_REL_SD,
    DEFAULT_PRIOR_RELATIVE_STDERR,
    NUMBER_SCHEMA,
    REQUIRED,
    Reserve,
    load_scenario,
)


def test_loads_base_scenario(scenario_path):
    sc = load_scenario(scenario_path)
    assert sc.name == "test_yard" and sc.robot.kind == "ground"
    assert sc.map_path == (scenario_path.parent / "yard.geojson").resolve()
    assert sc.robot.mass_kg == 10.0 and sc.robot.v_max_mps == 1.0
    # Omega = 0.8 * 0.9; P_anc = (2 + 0.1 * 10 + 3 + 1) / 0.8
    assert sc.omega == pytest.approx(0.72)
    assert sc.ancillary_power_W == pytest.approx(8.75)
    assert sc.mission.reserve == Reserve("fraction", 0.1)
    assert sc.battery.storage_loss == sc.losses.battery == 0.1


def test_defaults_when_optional_keys_are_absent(tmp_path):
    path = write_scenario(tmp_path, drop=["robot.v_min_mps", "robot.drag_coeff_kg_per_m",
                                          "environment", "mission.reserve", "ancillary",
                                          "battery.cycles", "mission.sensor_radius_m", "name"])
    sc = load_scenario(path)
    robot = NUMBER_SCHEMA["robot"]
    assert sc.robot.v_min_mps == robot["v_min_mps"][0] == 0.1
    assert sc.robot.drag_coeff_kg_per_m == 0.0 and sc.robot.hover_W == 0.0
    assert sc.environment.wind_xy_mps == (0.0, 0.0) and sc.environment.ambient_C == 20.0
    assert sc.mission.reserve == Reserve("fraction", 0.0)
    assert sc.ancillary_power_W == 0.0
    assert sc.battery.cycles == 0.0 and sc.mission.sensor_radius_m == 1.0
    assert sc.name == "scenario"  # the file stem


def test_required_keys_match_schema():
    required = {f"{s}.{k}" for s, t in NUMBER_SCHEMA.items() for k, (d, _) in t.items()
                if d is REQUIRED}
    assert required == {"robot.mass_kg", "robot.crr", "robot.v_max_mps", "losses.battery",
                        "losses.motor", "losses.mechanical", "losses.ancillary",
                        "battery.rated_energy_Wh", "mission.duty_cycle"}


@pytest.mark.parametrize(
    ("from_deg", "expected"),
    [
        (0.0, (0.0, -2.0)),  # from the north: blows south
        (90.0, (-2.0, 0.0)),  # from the east: blows west
        (225.0, (math.sqrt(2), math.sqrt(2))),  # from the south-west: blows north-east
    ],
)
def test_wind_vector_is_meteorological(tmp_path, from_deg, expected):
    path = write_scenario(tmp_path, set={"environment.wind_speed_mps": 2.0,
                                         "environment.wind_from_deg": from_deg})
    np.testing.assert_allclose(load_scenario(path).environment.wind_xy_mps, expected, atol=1e-12)


def test_model_table_extra_terms(tmp_path):
    path = write_scenario(tmp_path, set={"model": {"terms": ["inertia", "regen"],
                                                   "regen_efficiency": 0.6,
                                                   "stderr": {"inertia_kg": 0.5}}})
    sc = load_scenario(path)
    model = build_model(sc)
    assert model.term_ids[-2:] == ("inertia", "regen")
    assert model.coefficient("regen_efficiency") == 0.6
    assert model.coefficient("inertia_kg") == pytest.approx(10 / 0.72)  # default m / Omega
    sd = model.stderr()
    assert sd["inertia_kg"] == 0.5
    # no stderr given: prior_relative_stderr * |value|
    assert sd["rolling_kg"] == pytest.approx(DEFAULT_PRIOR_RELATIVE_STDERR * 10 / 0.72)


def test_model_table_defaults_and_surface_rolling(tmp_path):
    path = write_scenario(tmp_path, set={"model": {"terms": ["regen", "surface_rolling"],
                                                   "rolling_kg_grass": 20.0,
                                                   "prior_relative_stderr": 0.0}})
    model = build_model(load_scenario(path), surface_names=("grass", "tile"))
    assert model.coefficient("regen_efficiency") == DEFAULT_REGEN_EFFICIENCY
    assert model.coefficient("rolling_kg_grass") == 20.0
    assert model.coefficient("rolling_kg_tile") == pytest.approx(10 / 0.72)
    assert not model.cov.any()


def test_reference_terms_switch_on_with_their_values(tmp_path):
    sc = load_scenario(write_scenario(tmp_path))
    assert reference_term_ids(sc) == ["ancillary", "sensor_rate", "rolling", "grade"]
    sc = load_scenario(write_scenario(tmp_path, set={"robot.kind": "aerial", "robot.crr": 0.0,
                                                     "robot.hover_W": 50.0,
                                                     "robot.drag_coeff_kg_per_m": 0.1,
                                                     "robot.turn_coeff_W_s_per_rad": 1.0}))
    assert reference_term_ids(sc) == ["ancillary", "sensor_rate", "hover", "aero_drag", "grade",
                                      "turning"]


def test_a_model_coefficient_switches_its_reference_term_on(tmp_path):
    # a calibrated scenario may hold a drag fitted negative: its physical key is clipped at 0
    sc = load_scenario(write_scenario(tmp_path, set={"model": {"drag_kg_per_m": -0.5,
                                                               "stderr": {"drag_kg_per_m": 0.2}}}))
    assert reference_term_ids(sc) == ["ancillary", "sensor_rate", "rolling", "aero_drag", "grade"]
    model = build_model(sc)
    assert model.coefficient("drag_kg_per_m") == -0.5 and model.stderr()["drag_kg_per_m"] == 0.2


def test_model_discrepancy_default_and_value(tmp_path):
    assert build_model(load_scenario(write_scenario(tmp_path))).discrepancy_rel_sd == (
        DEFAULT_DISCREPANCY_REL_SD)
    path = write_scenario(tmp_path, set={"model": {"discrepancy_rel_sd": 0.07}})
    assert load_scenario(path).model.discrepancy_rel_sd == 0.07
    assert build_model(load_scenario(path)).discrepancy_rel_sd == 0.07


@pytest.mark.parametrize(
    ("set_", "drop", "match"),
    [
        ({}, ["robot.mass_kg"], r"missing key 'robot.mass_kg'"),
        ({}, ["map"], r"missing key 'map'"),
        ({}, ["robot.kind"], r"missing key 'robot.kind'"),
        ({"robot.mas_kg": 3.0}, [], r"unknown key 'robot.mas_kg' \(did you mean 'mass_kg'\?\)"),
        ({"misson": {}}, [], r"unknown key 'misson' \(did you mean 'mission'\?\)"),
        ({"robot.mass_kg": -1.0}, [], r"robot.mass_kg = -1 must be > 0"),
        ({"robot.mass_kg": "abc"}, [], r"robot.mass_kg must be a number, got 'abc'"),
        ({"robot.mass_kg": True}, [], r"robot.mass_kg must be a number"),
        ({"robot.mass_kg": math.inf}, [], r"robot.mass_kg must be finite"),
        ({"robot.crr": -0.1}, [], r"robot.crr = -0.1 must be in \[0, 1\]"),
        ({"robot.kind": "grnd"}, [], r"robot.kind = 'grnd' must be one of .*did you mean 'ground'"),
        ({"robot.v_min_mps": 2.0}, [], r"v_min_mps = 2.0 exceeds robot.v_max_mps = 1.0"),
        ({"losses.motor": 1.0}, [], r"losses.motor = 1 must be a loss fraction in \[0, 1\)"),
        ({"losses.ancillary": -0.1}, [], r"losses.ancillary = -0.1 must be a loss fraction"),
        ({"mission.duty_cycle": 0.0}, [], r"mission.duty_cycle = 0 must be in \(0, 1\]"),
        ({"mission.reserve": {"confidence": 1.0}}, [], r"reserve.confidence = 1 must be in \(0, 1\)"),
        ({"mission.reserve": {"fracton": 0.1}}, [], r"did you mean 'fraction'"),
        ({"mission.reserve": {"fraction": 0.1, "energy_J": 4.0}}, [], r"mission.reserve must be one"),
        ({"mission.home_xy_m": [1.0]}, [], r"home_xy_m must be \[x, y\]"),
        ({"environment.ambient_C": -300.0}, [], r"ambient_C = -300 must be above absolute zero"),
        ({"map": "nowhere.geojson"}, [], r"map file 'nowhere.geojson' not found"),
        ({"robot": "heavy"}, [], r"\[robot\] must be a table"),
        ({"model": {"terms": ["inertai"]}}, [], r"unknown term 'inertai'.*did you mean 'inertia'"),
        ({"model": {"regen_eff": 0.5, "terms": ["regen"]}}, [],
         r"unknown key 'model.regen_eff' \(did you mean 'regen_efficiency'\?\)"),
        ({"model": {"stderr": {"rolling_kg": -1.0}}}, [], r"model.stderr.rolling_kg must be >= 0"),
        ({"model": {"discrepancy_rel_sd": -0.1}}, [], r"model.discrepancy_rel_sd = -0.1 must be >= 0"),
        ({"model": {"discrepancy_sd": 0.1}}, [],
         r"unknown key 'model.discrepancy_sd' \(did you mean 'discrepancy_rel_sd'\?\)"),
    ],
)
def test_bad_scenarios(tmp_path, set_, drop, match):
    path = write_scenario(tmp_path, set=set_, drop=drop)
    with pytest.raises(ScenarioError, match=match) as info:
        load_scenario(path)
    assert str(path) in str(info.value)  # names the file
    assert "\n" not in str(info.value)


def test_model_stderr_of_unknown_coefficient(tmp_path):
    path = write_scenario(tmp_path, set={"model": {"stderr": {"rolling_k": 1.0}}})
    with pytest.raises(ScenarioError, match=r"unknown coefficient 'rolling_k'.*'rolling_kg'"):
        build_model(load_scenario(path))


def test_not_toml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("this is = = not toml\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match="not a valid TOML file"):
        load_scenario(bad)
    with pytest.raises(InputError, match="scenario file not found"):
        load_scenario(tmp_path / "absent.toml")
