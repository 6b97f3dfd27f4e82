"""Simulator: routes, truth files, kinematics, power from the model's own terms, depletion."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import write_scenario
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.sim.route import Route, load_route
from orange_plan.sim.simulator import simulate, truth_model, with_payload
from orange_plan.sim.truth import Truth, Wind, load_truth, truth_from_dict
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.state import recording_state

# A loop in the 20 m x 10 m test yard: default ground (x < 10) and grass (x > 10), clear of
# the box obstacle at x 4..6, y 7..9.
LOOP = np.array([[1.0, 1.0], [18.0, 1.0], [18.0, 4.0], [1.0, 4.0], [1.0, 1.0]])


def route(speed=0.8) -> Route:
    return Route(LOOP, np.full(len(LOOP), speed), "loop")


@pytest.fixture
def ctx(tmp_path):
    return load_context(write_scenario(tmp_path))


# --- truth files ---------------------------------------------------------------------------


def test_truth_file_is_parsed(tmp_path):
    path = tmp_path / "truth.toml"
    path.write_text("[coefficients]\nrolling_kg = 15.0\n[wind]\nmean_mps = 3.0\nfrom_deg = 90\n"
                    "gust_std_mps = 1.0\ngust_tau_s = 4.0\nrecorded = false\n"
                    "[payload]\nextra_kg = 2.0\nfrom_s = 30\n[battery]\ncapacity_factor = 0.9\n"
                    "[noise]\npower_std_W = 0.5\n[stops]\nevery_s = 20\n", encoding="utf-8")
    truth = load_truth(path)
    assert truth.coefficients == {"rolling_kg": 15.0}
    assert truth.wind == Wind(3.0, 90.0, 1.0, 4.0, False)
    assert truth.wind.mean_xy_mps == pytest.approx((-3.0, 0.0))  # from the east: blows west
    assert (truth.payload_kg, truth.payload_from_s, truth.capacity_factor) == (2.0, 30.0, 0.9)
    assert truth.stop_every_s == 20.0
    assert load_truth(None) == Truth()


@pytest.mark.parametrize(("data", "match"), [
    ({"wnd": {}}, r"unknown table \[wnd\] \(did you mean 'wind'\?\)"),
    ({"wind": {"gust_std": 1.0}}, r"unknown key 'wind.gust_std' \(did you mean 'gust_std_mps'\?\)"),
    ({"noise": {"power_std_W": -1.0}}, r"noise.power_std_W = -1 must be >= 0"),
    ({"battery": {"capacity_factor": 0}}, r"capacity_factor = 0 must be > 0"),
    ({"wind": {"mean_mps": "fast"}}, r"wind.mean_mps must be a number, got 'fast'"),
    ({"wind": {"recorded": 1}}, r"wind.recorded must be true or false"),
])
def test_bad_truth_is_refused(data, match):
    with pytest.raises(InputError, match=match):
        truth_from_dict(data)


def test_truth_coefficient_must_exist(ctx):
    with pytest.raises(InputError, match="names 'hover_W', not a coefficient"):
        truth_model(ctx.model, Truth(coefficients={"hover_W": 3.0}))


# --- routes ----------------------------------------------------------------------------------


def test_route_from_plan_and_csv(tmp_path):
    plan = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"kind": "tour", "speed_mps": [0.5, 0.6, 0.7]},
         "geometry": {"type": "LineString", "coordinates": [[1, 1], [5, 1], [5, 3]]}}]}
    (tmp_path / "plan.geojson").write_text(json.dumps(plan), encoding="utf-8")
    r = load_route(tmp_path / "plan.geojson")
    assert r.xy_m.tolist() == [[1, 1], [5, 1], [5, 3]]
    assert r.speed_mps.tolist() == [0.5, 0.6, 0.7]
    assert r.length_m == pytest.approx(6.0)
    assert not r.closed and r.lap().closed and r.lap().length_m == pytest.approx(12.0)
    (tmp_path / "route.csv").write_text("x_m,y_m\n0,0\n3,4\n", encoding="utf-8")
    r = load_route(tmp_path / "route.csv")
    assert r.length_m == 5.0 and np.isnan(r.speed_mps).all()
    assert r.with_default_speed(0.4).speed_mps.tolist() == [0.4, 0.4]


@pytest.mark.parametrize(("name", "text", "match"), [
    ("r.csv", "x,y\n0,0\n1,1\n", r"lacks column\(s\) \['x_m', 'y_m'\]"),
    ("r.csv", "x_m,y_m\n0,0\n", "at least two distinct vertices"),
    ("r.csv", "x_m,y_m\n0,0\n1,abc\n", "must hold numbers"),
    ("r.csv", "x_m,y_m,speed_mps\n0,0,1\n1,1,-1\n", "speed_mps must be >= 0"),
    ("p.geojson", '{"type": "FeatureCollection", "features": []}', "no feature with kind = 'tour'"),
    ("p.geojson", "{not json", "not a valid plan GeoJSON file"),
])
def test_bad_route_is_refused(tmp_path, name, text, match):
    (tmp_path / name).write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=match):
        load_route(tmp_path / name)


def test_route_through_an_obstacle_is_refused(ctx):
    through_box = Route(np.array([[5.0, 5.0], [5.0, 9.5]]), np.full(2, 0.5), "x")
    with pytest.raises(InputError, match="route segment 0 leaves the free space"):
        simulate(ctx, through_box)


def test_route_scraping_an_obstacle_is_refused_by_the_robot_radius(tmp_path):
    """The box spans x 4..6: a route along x = 3.8 passes 0.2 m from it, inside a 0.3 m robot."""
    ctx = load_context(write_scenario(tmp_path, set={"robot.radius_m": 0.3}))
    beside_box = Route(np.array([[3.8, 5.0], [3.8, 9.5]]), np.full(2, 0.5), "x")
    with pytest.raises(InputError, match=r"route segment 0 leaves the free space of the map "
                       r"or passes closer to its edges than the robot keeps \(0.3 m"):
        simulate(ctx, beside_box)


# --- the simulation --------------------------------------------------------------------------


def test_power_is_the_models_own_power_on_the_recorded_motion(ctx):
    """No truth effects: the recording replays exactly through EnergyModel.power_W."""
    sim = simulate(ctx, route(), seed=1)
    rec = recording_from_frame(sim.frame, "sim")
    state = recording_state(rec, ctx.world, sensor_rate_Hz=ctx.conditions.sensor_rate_Hz)
    np.testing.assert_allclose(ctx.model.power_W(state), sim.frame["power_W"], atol=1e-9)
    assert sim.energy_J == pytest.approx(sim.frame["power_W"].sum() * 0.1)
    assert set(sim.frame["surface"]) == {"grass", "default"}
    assert sim.distance_m == pytest.approx(route().length_m, rel=1e-3)
    assert not sim.depleted


def test_kinematics_respect_accel_limit_and_speed(ctx):
    sim = simulate(ctx, route(0.8), seed=0)
    f = sim.frame
    assert f["accel_mps2"].abs().max() <= ctx.scenario.robot.accel_max_mps2 + 1e-9
    assert f["v_mps"].max() == pytest.approx(0.8)
    assert f["v_mps"].iloc[0] == 0.0 and f["v_mps"].iloc[-1] < 0.1  # starts and ends at rest
    # the heading changes of the loop (4 x 90 degrees) come out of the yaw rate
    assert np.sum(np.abs(f["yaw_rate_radps"])) * 0.1 == pytest.approx(1.5 * np.pi, rel=0.01)


def test_run_to_depletion_spends_the_truths_usable_energy_and_keeps_the_duty_cycle(ctx):
    truth = Truth(capacity_factor=0.5, stop_every_s=30.0)
    sim = simulate(ctx, route(), truth, seed=2, to_depletion=True)
    assert sim.depleted
    assert sim.energy_available_J == pytest.approx(0.5 * ctx.scenario.battery.usable_J)
    assert sim.energy_J == pytest.approx(sim.energy_available_J, abs=sim.frame["power_W"].max())
    assert sim.laps > 1
    assert sim.moving_time_s / sim.duration_s == pytest.approx(ctx.conditions.duty_cycle, abs=0.01)
    assert sim.frame["soc"].iloc[-1] == pytest.approx(0.0, abs=1e-3)


def test_truth_effects_change_the_energy(ctx):
    base = simulate(ctx, route(), seed=3).energy_J
    heavier = simulate(ctx, route(), Truth(payload_kg=5.0, payload_from_s=0.0), seed=3)
    assert heavier.energy_J > base
    assert (heavier.frame["payload_kg"] == 5.0).all()
    rough = simulate(ctx, route(), Truth(coefficients={"rolling_kg": 30.0}), seed=3)
    assert rough.energy_J > base
    noisy = simulate(ctx, route(), Truth(power_std_W=1.0, position_std_m=0.1), seed=3)
    assert noisy.energy_J == pytest.approx(base)  # noise is on the recording, not the battery
    assert not np.allclose(noisy.frame["x_m"], simulate(ctx, route(), seed=3).frame["x_m"])


def test_payload_scales_mass_coefficients(ctx):
    heavy = with_payload(ctx.model, ctx.scenario.robot.mass_kg, ctx.scenario.robot.mass_kg)
    assert heavy.coefficient("rolling_kg") == pytest.approx(2 * ctx.model.coefficient("rolling_kg"))
    assert heavy.coefficient("ancillary_W") == ctx.model.coefficient("ancillary_W")


def test_payload_scales_the_motor_current_rolling_torque_too():
    # the Husky's rolling_torque_kg_mps = m v_max / Omega is mass-proportional as well
    husky = load_context(Path(__file__).resolve().parents[1] / "scenarios" / "husky_a200.toml")
    m = husky.scenario.robot.mass_kg
    heavy = with_payload(husky.model, m, 0.5 * m)
    assert heavy.coefficient("rolling_torque_kg_mps") == pytest.approx(
        1.5 * husky.model.coefficient("rolling_torque_kg_mps"))
    assert heavy.coefficient("turning_torque_W") == husky.model.coefficient("turning_torque_W")


def test_same_seed_same_recording(ctx):
    truth = Truth(wind=Wind(2.0, 45.0, 1.0, 5.0), roughness_crr_std=0.01, power_std_W=0.3)
    a = simulate(ctx, route(), truth, seed=7).frame
    b = simulate(ctx, route(), truth, seed=7).frame
    assert a.equals(b)
    assert not a.equals(simulate(ctx, route(), truth, seed=8).frame)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rolling=st.floats(0.0, 50.0), wind=st.floats(0.0, 10.0), gust=st.floats(0.0, 5.0),
       payload=st.floats(-5.0, 20.0), speed=st.floats(0.2, 1.0), seed=st.integers(0, 1000))
def test_energy_never_negative_without_regen(ctx, rolling, wind, gust, payload, speed, seed):
    truth = Truth(coefficients={"rolling_kg": rolling}, wind=Wind(wind, 30.0, gust, 3.0),
                  payload_kg=payload, payload_from_s=5.0, roughness_crr_std=0.05)
    sim = simulate(ctx, route(speed), truth, seed=seed, max_duration_s=60.0)
    assert (sim.frame["power_W"] >= 0).all()
    assert sim.energy_J >= 0


def test_bad_sample_rate(ctx):
    with pytest.raises(InputError, match=r"sample_rate_Hz \(--rate-hz\) = 0 must be in \(0, 1000\]"):
        simulate(ctx, route(), sample_rate_Hz=0)


def test_a_drive_started_mid_battery_carries_the_state_of_charge(ctx):
    """A mission flown as several drives: the second starts where the first left the
    battery, so its soc and its depletion count the energy already drawn."""
    truth = Truth(capacity_factor=0.5)
    whole = 0.5 * ctx.scenario.battery.usable_J
    fresh = simulate(ctx, route(), truth, seed=3)
    later = simulate(ctx, route(), truth, seed=3, energy_start_J=0.25 * whole)
    assert later.energy_J == pytest.approx(fresh.energy_J)  # this drive's draw only
    soc0 = 1.0 - (0.25 * whole + fresh.frame["power_W"].iloc[0] * 0.1) / whole
    assert later.frame["soc"].iloc[0] == pytest.approx(soc0, rel=1e-3)
    assert (later.frame["soc"] < fresh.frame["soc"] - 0.24).all()
    empty = simulate(ctx, route(), truth, seed=3, to_depletion=True,
                     energy_start_J=0.9 * whole)
    full = simulate(ctx, route(), truth, seed=3, to_depletion=True)
    assert empty.depleted and empty.energy_J == pytest.approx(0.1 * full.energy_J, rel=0.02)


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf")])
def test_bad_start_energy_is_refused(ctx, bad):
    with pytest.raises(InputError, match="energy_start_J"):
        simulate(ctx, route(), energy_start_J=bad)
