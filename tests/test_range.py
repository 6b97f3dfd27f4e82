"""Operational range: the energy model (docs/guide/range.md) by hand against ``orange-plan range --json``; range properties."""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest
from conftest import REPO, feature, run_cli, scenario_dict, write_map, write_scenario
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.physics.model_builder import build_model
from orange_plan.physics.range import (
    generalised_range,
    radial_probe_paths,
    simplified_range,
)
from orange_plan.range_report import range_report
from orange_plan.scenario import scenario_from_dict

G = 9.81


def spec_by_hand(scenario_file):
    """The range equations straight from the TOML (and the map's default_surface), no package code."""
    sc = tomllib.loads(scenario_file.read_text(encoding="utf-8"))
    robot, losses, bat, anc = sc["robot"], sc["losses"], sc["battery"], sc["ancillary"]
    bat = {"cycles": 0, "age_days": 0, "k1_per_cycle": 0, "k2_per_day": 0, **bat}
    anc = {"s0_W": 0, "s1_W_per_Hz": 0, "sensor_rate_Hz": 0, "compute_W": 0, "comm_W": 0, **anc}
    e_avail = (3600 * bat["rated_energy_Wh"]
               * math.exp(-(bat["k1_per_cycle"] * bat["cycles"] + bat["k2_per_day"] * bat["age_days"]))
               * (1 - losses["battery"]))
    omega = (1 - losses["motor"]) * (1 - losses["mechanical"])
    p_anc = ((anc["s0_W"] + anc["s1_W_per_Hz"] * anc["sensor_rate_Hz"] + anc["compute_W"]
              + anc["comm_W"]) / (1 - losses["ancillary"]) + robot.get("hover_W", 0.0))
    map_data = json.loads((scenario_file.parent / sc["map"]).read_text(encoding="utf-8"))
    crr = map_data.get("default_surface", {}).get("crr", robot["crr"])
    m, c, duty = robot["mass_kg"], robot.get("drag_coeff_kg_per_m", 0.0), sc["mission"]["duty_cycle"]
    v = np.linspace(robot.get("v_min_mps", 0.1), robot["v_max_mps"], 200001)  # brute force
    d = e_avail / (p_anc / (v * duty) + (crr * m * G + c * v**2) / omega)
    k = int(np.argmax(d))
    return {"E_avail": e_avail, "omega": omega, "P_anc": p_anc, "crr": crr,
            "d_max": float(d[k]), "v_opt": float(v[k]), "c": c, "D": duty}


def range_json(path) -> dict:
    code, out, err = run_cli("range", path, "--json")
    assert code == 0, err
    return json.loads(out)


def assert_matches_spec(path, hand):
    got = range_json(path)
    assert got["energy"]["available_J"] == pytest.approx(hand["E_avail"], rel=1e-3)
    assert got["ancillary_power_W"] == pytest.approx(hand["P_anc"], rel=1e-3)
    assert got["omega"] == pytest.approx(hand["omega"], rel=1e-3)
    assert got["crr"] == pytest.approx(hand["crr"], rel=1e-3)
    assert got["d_max_m"] == pytest.approx(hand["d_max"], rel=1e-3)
    assert got["v_opt_mps"] == pytest.approx(hand["v_opt"], rel=1e-3)
    return got


EXAMPLES = ["rusti_v2_grass_2200mAh_v0952", "ar_drone_wind", "kiwibot_campus", "marine_survey"]


@pytest.mark.parametrize("name", EXAMPLES)
def test_range_matches_spec_by_hand_on_examples(name):
    path = REPO / "scenarios" / f"{name}.toml"
    if not path.is_file():
        pytest.skip(f"example scenario {path.name} not written yet")
    assert_matches_spec(path, spec_by_hand(path))


def test_range_hand_values_on_small_scenario(scenario_path):
    got = assert_matches_spec(scenario_path, spec_by_hand(scenario_path))
    # E_avail = 36000 exp(-(0.001*100 + 0.002*50)) (1 - 0.1) = 26526.88 J
    # P_anc = (2 + 0.1*10 + 3 + 1) / (1 - 0.2) = 8.75 W; Omega = 0.8 * 0.9 = 0.72
    # no drag: fastest is best, v_opt = 1 m/s;
    # per metre: 8.75 / (1 * 0.8) + 0.05 * 10 * 9.81 / 0.72 = 10.9375 + 6.8125 = 17.75 J/m
    assert got["v_opt_mps"] == 1.0
    assert got["energy_per_m_J"] == pytest.approx(17.75)
    assert got["d_max_m"] == pytest.approx(26526.876 / 17.75, rel=1e-6)
    e = got["energy"]
    assert e["ancillary_J"] + e["traversal_J"] == pytest.approx(e["available_J"])
    assert e["mechanical_work_J"] + e["motor_loss_eta2_J"] + e["mechanical_loss_eta3_J"] == \
        pytest.approx(e["traversal_J"])
    assert e["motor_loss_eta2_J"] == pytest.approx(0.2 * e["traversal_J"])
    assert e["ancillary_loss_eta4_J"] == pytest.approx(0.2 * e["ancillary_J"])
    assert e["capacity_J"] - e["battery_loss_eta1_J"] == pytest.approx(e["available_J"])


def test_drag_makes_v_opt_interior(tmp_path):
    path = write_scenario(tmp_path, set={"robot.drag_coeff_kg_per_m": 2.0, "robot.v_max_mps": 3.0})
    hand = spec_by_hand(path)
    got = assert_matches_spec(path, hand)
    # v* = (P_anc Omega / (2 c D))^(1/3) = (8.75 * 0.72 / (2 * 2 * 0.8))^(1/3) = 1.96875^(1/3)
    v_star = (hand["P_anc"] * hand["omega"] / (2 * hand["c"] * hand["D"])) ** (1 / 3)
    assert v_star == pytest.approx(1.2533, abs=1e-4)
    assert 0.2 < got["v_opt_mps"] < 3.0
    assert got["v_opt_mps"] == pytest.approx(v_star, rel=1e-3)


def test_generalised_equals_simplified_on_flat_calm_default_ground(tmp_path):
    write_map(tmp_path, [feature("boundary", "Polygon", [[[0, 0], [20, 0], [20, 10], [0, 10], [0, 0]]]),
                         feature("home", "Point", [5.0, 5.0])])
    path = write_scenario(tmp_path, set={"robot.drag_coeff_kg_per_m": 0.3})
    got = range_json(path)
    assert got["generalised"]["d_max_m"] == pytest.approx(got["d_max_m"], rel=1e-9)
    assert got["generalised"]["v_opt_mps"] == pytest.approx(got["v_opt_mps"], rel=1e-6)


def test_wind_shortens_generalised_range(tmp_path):
    write_map(tmp_path, [feature("boundary", "Polygon", [[[0, 0], [20, 0], [20, 10], [0, 10], [0, 0]]]),
                         feature("home", "Point", [5.0, 5.0])])
    calm = write_scenario(tmp_path, set={"robot.drag_coeff_kg_per_m": 0.3}, name="calm.toml")
    windy = write_scenario(tmp_path, set={"robot.drag_coeff_kg_per_m": 0.3,
                                          "environment.wind_speed_mps": 3.0}, name="windy.toml")
    ctx_calm, ctx_windy = load_context(calm), load_context(windy)
    d_calm = generalised_range(ctx_calm.scenario, ctx_calm.model, ctx_calm.world).d_max_m
    d_windy = generalised_range(ctx_windy.scenario, ctx_windy.model, ctx_windy.world).d_max_m
    # out and back, |a|(a.u) sums to 2(v^2 + w^2) > 2 v^2 for a head/tail pair
    assert d_windy < d_calm
    probes = radial_probe_paths(ctx_calm.world)
    assert len(probes) == 16 and all(np.allclose(p[0], p[-1]) for p in probes)


@pytest.fixture(scope="module")
def scenario_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("range_props")
    write_map(folder)
    return folder


def simple_d_max(folder, **changes) -> float:
    sc = scenario_from_dict(scenario_dict(set=changes), folder / "s.toml")
    return simplified_range(sc, build_model(sc), sc.robot.crr).d_max_m


@settings(max_examples=25, deadline=None)
@given(mass=st.floats(0.5, 200.0), factor=st.floats(1.01, 3.0), drag=st.floats(0.0, 2.0))
def test_d_max_decreases_with_mass(scenario_folder, mass, factor, drag):
    light = simple_d_max(scenario_folder, **{"robot.mass_kg": mass, "robot.drag_coeff_kg_per_m": drag})
    heavy = simple_d_max(scenario_folder, **{"robot.mass_kg": mass * factor,
                                             "robot.drag_coeff_kg_per_m": drag})
    assert heavy < light


@settings(max_examples=25, deadline=None)
@given(wh=st.floats(0.5, 500.0), factor=st.floats(1.01, 3.0), drag=st.floats(0.0, 2.0))
def test_d_max_increases_with_battery_energy(scenario_folder, wh, factor, drag):
    small = simple_d_max(scenario_folder, **{"battery.rated_energy_Wh": wh,
                                             "robot.drag_coeff_kg_per_m": drag})
    big = simple_d_max(scenario_folder, **{"battery.rated_energy_Wh": wh * factor,
                                           "robot.drag_coeff_kg_per_m": drag})
    assert big > small
    assert big == pytest.approx(small * factor, rel=1e-9)  # range is linear in E_avail


def test_breakdown_hover_takes_no_ancillary_loss(tmp_path):
    # aerial: hover 50 W in [robot], replaced by 40 W in [model]; eta_4 = 0.2 acts on the
    # ancillary loads only: (ancillary_J - 40 W * mission time) * 0.2
    path = write_scenario(tmp_path, set={"robot.kind": "aerial", "robot.crr": 0.0,
                                         "robot.hover_W": 50.0, "model": {"hover_W": 40.0}})
    got = range_json(path)
    e, t = got["energy"], got["mission_time_s"]
    assert got["ancillary_power_W"] == pytest.approx(8.75 + 40.0)
    assert e["ancillary_loss_eta4_J"] == pytest.approx((e["ancillary_J"] - 40.0 * t) * 0.2)
    assert e["ancillary_loss_eta4_J"] == pytest.approx(8.75 * 0.2 * t)


def test_generalised_range_refuses_a_model_that_draws_nothing(tmp_path):
    from orange_plan.errors import InputError
    from orange_plan.physics.model import EnergyModel
    from orange_plan.physics.terms import TERMS

    ctx = load_context(write_scenario(tmp_path))
    free = EnergyModel([TERMS["ancillary"]], {"ancillary_W": 0.0}, omega=0.8)
    with pytest.raises(InputError, match=r"energy per metre is 0 J/m \(not positive\)"):
        generalised_range(ctx.scenario, free, ctx.world)


def test_time_limit_bounds_the_range(tmp_path):
    """A 60 s mission cannot take the robot further than v_max D 60 s, whatever the battery:
    the energy model's figures stay, flagged, with the range the limit allows."""
    ctx = load_context(write_scenario(tmp_path, set={"mission.time_limit_s": 60.0}))
    free = simplified_range(ctx.scenario, ctx.model, ctx.world.default_crr)
    assert free.mission_time_s > 60.0 and free.within_time_limit and free.reason is None
    report = range_report(ctx)
    v_max, duty = ctx.scenario.robot.v_max_mps, ctx.conditions.duty_cycle
    for r in (report.simplified, report.generalised):
        assert not r.within_time_limit and "exceeds mission.time_limit_s = 60 s" in r.reason
        assert r.time_limited.mission_time_s <= 60.0 * (1 + 1e-9)
        # time binds before energy at every speed here, so the fastest speed goes furthest
        assert r.time_limited.v_opt_mps == pytest.approx(v_max)
        assert r.time_limited.d_max_m == pytest.approx(60.0 * v_max * duty)
    assert report.simplified.d_max_m == pytest.approx(free.d_max_m)  # Eq. 6 unchanged


def test_a_loose_time_limit_changes_nothing(tmp_path):
    ctx = load_context(write_scenario(tmp_path, set={"mission.time_limit_s": 1e9}))
    free = simplified_range(ctx.scenario, ctx.model, ctx.world.default_crr)
    assert range_report(ctx).simplified == free
