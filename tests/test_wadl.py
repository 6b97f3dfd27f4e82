"""DJI Matrice 100 survey flights (WADL): the importer, the shipped scenario, the route check
against recorded energy, and the benchmark's pieces."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, run_cli

from orange_plan.errors import RecordingError
from orange_plan.telemetry.importers import guess_format, read_log
from orange_plan.telemetry.importers.wadl import read_wadl
from orange_plan.telemetry.recording import recording_from_frame

DATA = REPO.parent / "shared" / "data" / "wadl_m100"
FLIGHTS = ("20191123_183923_waddle4", "20200112_121402_waddle1", "20191202_153622_waddle1")
"""A short CURVED test route, a NORMAL survey (stops at every waypoint) and a survey flown at
transit speed."""
R1_BN = ("20191226_212249_waddle3", "20200112_121402_waddle1", "20200112_130607_waddle1",
         "20200121_194301_waddle1", "20200122_161452_waddle1")
"""Every flight of route r1-BN: flown five times, CURVED and NORMAL, over 3 weeks."""


def needs_flight(flight_id: str) -> Path:
    path = DATA / f"{flight_id}.csv"
    if not path.is_file():
        pytest.skip(f"real data not found at ../shared/data/wadl_m100/{flight_id}.csv")
    return path


def meta_of(path: Path) -> dict:
    return json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))


# --- the importer on a made-up flight (no data needed) --------------------------------------


def write_flight(folder: Path, with_events: bool = True) -> Path:
    """A 60 s flight: up 20 m at home, 40 m north, down again; 300 W, then 400 W."""
    folder.mkdir(parents=True, exist_ok=True)
    battery = pd.DataFrame({
        "t_s": [10.0, 30.0, 50.0], "voltage_V": [24.0, 23.5, 23.0],
        "current_A": [12.5, 400 / 23.5, 400 / 23.0], "power_W": [300.0, 400.0, 400.0],
        "soc": [0.9, 0.89, 0.88], "battery_C": [20.0, 21.0, 22.0], "x_m": [0.0, 0.0, 0.0],
        "y_m": [0.0, 20.0, 40.0], "z_m": [20.0, 20.0, 20.0], "s_m": [20.0, 40.0, 60.0],
        "mode": ["GPS_WAYPOINT"] * 3, "soc_glitch": [False] * 3, "smart_battery": [True] * 3})
    battery.to_csv(folder / "f.csv", index=False)
    pd.DataFrame({"wp": [1, 2], "x_m": [0.0, 0.0], "y_m": [0.0, 40.0], "z_m": [20.0, 20.0],
                  "speed_to_next_mps": [2.0, np.nan], "stay_s": [0.0, 0.0],
                  "corner_radius_m": [0.2, 0.2]}).to_csv(folder / "f.route.csv", index=False)
    if with_events:
        pd.DataFrame({"wp": [1, 2], "t_s": [10.0, 50.0], "x_m": [0.0, 0.0], "y_m": [0.0, 40.0],
                      "z_m": [20.0, 20.0]}).to_csv(folder / "f.wp_events.csv", index=False)
    (folder / "f.json").write_text(json.dumps({"duration_s": 60.0, "landing_x_m": 0.0,
                                               "landing_y_m": 40.0}), encoding="utf-8")
    return folder / "f.csv"


def test_a_flight_is_put_on_a_one_second_grid(tmp_path):
    path = write_flight(tmp_path / "flights")
    assert guess_format(path) == "wadl"
    frame = read_wadl(path)
    assert np.allclose(frame["t_s"], np.arange(61.0))
    # climb 20 m in 10 s, 40 m north in 40 s, land 20 m in 10 s
    at = frame.set_index("t_s")
    assert (at.loc[5.0, "z_m"], at.loc[30.0, "y_m"], at.loc[55.0, "z_m"]) == (10.0, 20.0, 10.0)
    assert np.allclose(at.loc[[5.0, 30.0, 55.0], "v_mps"], [2.0, 1.0, 2.0])
    # power held before the first reading, linear between readings
    assert at.loc[0.0, "power_W"] == pytest.approx(300.0)
    assert at.loc[20.0, "power_W"] == pytest.approx((300.0 + 400.0) / 2, rel=0.01)
    rec = recording_from_frame(frame, source=str(path))
    assert rec.energy_J == pytest.approx(300 * 10 + 350 * 20 + 400 * 30, rel=0.01)


def test_a_flight_without_its_waypoint_events_is_refused(tmp_path):
    path = write_flight(tmp_path / "flights", with_events=False)
    with pytest.raises(RecordingError, match="waypoint events is missing"):
        read_wadl(path)


def test_a_battery_table_without_its_metadata_is_not_wadl(tmp_path):
    path = write_flight(tmp_path / "flights")
    path.with_suffix(".json").unlink()
    with pytest.raises(RecordingError, match="cannot tell the log format"):
        guess_format(path)


# --- the importer on real flights ------------------------------------------------------------


@pytest.mark.parametrize("flight", FLIGHTS)
def test_real_flights_import_with_their_recorded_energy(flight):
    path = needs_flight(flight)
    frame, fmt = read_log(path)
    assert fmt == "wadl"
    rec = recording_from_frame(frame, source=str(path))
    meta = meta_of(path)
    # the set's energy is the integral of V I from take-off to touch-down
    assert rec.energy_J == pytest.approx(meta["energy_J"], rel=2e-3)
    assert rec.duration_s == pytest.approx(meta["duration_s"], abs=1.0)
    # reconstructed positions: the planned path, take-off and landing included
    assert rec.distance_m == pytest.approx(meta["route_planned_length_incl_landing_m"], rel=0.03)
    events = pd.read_csv(path.with_name(f"{flight}.wp_events.csv"))
    z = np.interp(events["t_s"], rec.frame["t_s"], rec.frame["z_m"])
    # on the 1 s grid a waypoint is passed within half a second: <= 2 m at <= 4 m/s vertically
    assert np.allclose(z, events["z_m"], atol=2.0)
    assert (rec.frame["v_mps"] >= 0).all() and rec.frame["v_mps"].max() < 20.0


def test_the_transit_speed_flights_are_marked():
    from orange_plan.bench.flights import load_flight

    flight = load_flight(needs_flight(FLIGHTS[2]))
    assert flight.speed_anomaly and flight.route == "w1-r3-HKT"
    assert not load_flight(needs_flight(FLIGHTS[0])).speed_anomaly


# --- the shipped scenario --------------------------------------------------------------------


def test_the_calibrated_scenario_is_physically_plausible():
    from orange_plan.context import load_context

    ctx = load_context(REPO / "scenarios" / "dji_m100.toml")
    theta, sd = ctx.model.as_dict(), ctx.model.stderr()
    # hover: the published ~28 min on 130 Wh with no payload is ~280 W; the flights' mean
    # power is 349-390 W with climbs, drag and electronics on top
    assert 280.0 < theta["hover_W"] < 380.0 and sd["hover_W"] < 5.0
    # m / Omega for the climb: at least the mass (Omega <= 1), at most 3x it (Omega >= 1/3)
    mass = ctx.scenario.robot.mass_kg
    assert mass <= theta["grade_kg"] < 3 * mass
    # c / Omega: 0.5 rho Cd A of a 0.65 m quadrotor, positive and below 0.2 kg/m
    assert 0.0 < theta["drag_kg_per_m"] < 0.2
    assert 0.0 < ctx.model.discrepancy_rel_sd < 0.1
    assert ctx.scenario.robot.landing_mps < ctx.scenario.robot.descent_mps


# --- the route check against recorded energy ---------------------------------------------


def test_check_predicts_route_r1_bn_from_its_plan_alone():
    """The five flights of route r1-BN, from the uploaded mission alone (take-off, legs at the
    planned speeds, CURVED corners or NORMAL stops, landing), against their recorded energy.

    Tolerance: ``bench flights`` measures the route prediction within 10.7 % on 90 % of the 66
    nominal flights, held out by route (3.4 % median); the shipped scenario is fitted on all
    flights (these included), so 10 % per flight and 5 % on the route's mean are not lenient.
    """
    from orange_plan.bench.flights import wadl_mission
    from orange_plan.context import load_context
    from orange_plan.planning.mission_check import check_mission

    ctx = load_context(REPO / "scenarios" / "dji_m100.toml")
    errors = []
    for flight in R1_BN:
        path = needs_flight(flight)
        meta = meta_of(path)
        checked = check_mission(wadl_mission(path, meta), ctx, in_map_frame=False)
        errors.append((checked.energy_J - meta["energy_J"]) / meta["energy_J"])
        assert checked.duration_s == pytest.approx(meta["duration_s"], rel=0.10)
    assert np.max(np.abs(errors)) < 0.10, errors
    assert abs(np.mean(errors)) < 0.05, errors


# --- the benchmark ---------------------------------------------------------------------------


def test_the_route_discrepancy_splits_relative_and_fixed_parts():
    from orange_plan.bench.flights import route_discrepancy

    predicted = np.array([1e5, 2e5, 4e5, 1e5, 2e5, 4e5])
    # errors +-(5 % of E and 3 kJ combined): half the flights above, half below
    spread = np.sqrt((0.05 * predicted) ** 2 + 3e3**2)
    recorded = predicted + np.array([1, 1, 1, -1, -1, -1]) * spread / np.sqrt(1.0)
    rel, fixed = route_discrepancy(recorded, predicted, np.zeros(6))
    # 2 max(e, 0)^2 averages to the squared spread when half the errors are positive
    assert rel == pytest.approx(0.05, rel=1e-6)
    assert fixed == pytest.approx(3e3, rel=1e-6)


def test_bench_flights_runs_on_three_flights():
    needs_flight(FLIGHTS[0])
    code, stdout, stderr = run_cli("bench", "flights", "--data", str(DATA.parent), "--limit", "3",
                                   "--json")
    assert code == 0, stderr
    out = json.loads(stdout)
    from test_json_docs import compare

    compare("bench flights", out)  # docs/json.md lists exactly these keys
    rows, summary = out["flights"], out["summary"]
    assert len(rows) == 3 and summary["folds"] == 3
    assert set(summary["median_abs_err_pct"]) == {"recording", "route", "per_metre",
                                                  "power_time"}
    assert all(np.isfinite(r["route_J"]) and r["route_sd_J"] > 0 for r in rows)
