"""Non-physical recording values are refused (recording rule 3b, ``telemetry.recording``): an infinite value
or one outside a column's generous physical range stops predict and calibrate with exit 2 and
one line naming the column, the value, the row and the range; a file that is accepted never
gives null energies."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from conftest import run_cli, write_scenario
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orange_plan.errors import RecordingError
from orange_plan.telemetry.recording import PHYSICAL_RANGES, recording_from_frame

N = 30
BAD_ROW = 3


def full_frame() -> pd.DataFrame:
    """A valid recording carrying every numeric recording column, values well inside range."""
    t = np.arange(N) * 0.2
    return pd.DataFrame({
        "t_s": t, "power_W": 40.0 + t, "voltage_V": 24.0, "current_A": (40.0 + t) / 24.0,
        "x_m": 0.5 * t, "y_m": 0.0, "z_m": 100.0, "v_mps": 0.5, "yaw_rate_radps": 0.0,
        "accel_mps2": 0.0, "soc": 0.9 - 0.001 * t, "ambient_C": 20.0, "battery_C": 25.0,
        "wind_mps": 3.0, "wind_from_deg": 270.0, "payload_kg": 2.0, "sensor_rate_Hz": 10.0,
    })


# one clearly non-physical value per column (each beyond the range docs/guide/recordings.md states)
BEYOND = {
    "power_W": 1e308, "voltage_V": 2500.0, "current_A": -2e4, "v_mps": 200.0,
    "accel_mps2": -2e4, "yaw_rate_radps": 150.0, "x_m": 2e8, "y_m": -2e8, "z_m": -2e4,
    "ambient_C": -100.0, "battery_C": 200.0, "soc": 1.5, "wind_mps": 200.0,
    "wind_from_deg": 1e5, "payload_kg": -2e6, "sensor_rate_Hz": 2e6,
}


def test_every_numeric_column_but_time_has_a_range():
    from orange_plan.telemetry.recording import NUMERIC_COLUMNS

    assert set(PHYSICAL_RANGES) == set(NUMERIC_COLUMNS) - {"t_s"} == set(BEYOND)
    assert recording_from_frame(full_frame()).issues == ()  # the base frame is clean


def bad_file(tmp_path, column, value):
    frame = full_frame()
    frame.loc[BAD_ROW, column] = value
    path = tmp_path / "bad.csv"
    frame.to_csv(path, index=False)
    return path


CASES = [(c, v) for c, v in BEYOND.items()] + [(c, math.inf) for c in ("power_W", "x_m", "soc")] \
    + [("v_mps", -math.inf)]


@pytest.mark.parametrize("command", ["predict", "calibrate"])
@pytest.mark.parametrize(("column", "value"), CASES)
def test_non_physical_value_exits_2_with_one_line(tmp_path, command, column, value):
    scenario = write_scenario(tmp_path)
    path = bad_file(tmp_path, column, value)
    code, stdout, stderr = run_cli(command, path, "--scenario", scenario, "--json")
    assert code == 2, stderr
    assert stdout == ""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1
    low, high, _ = PHYSICAL_RANGES[column]
    assert f"column '{column}' = {value:.6g} at row {BAD_ROW} (CSV line {BAD_ROW + 2})" in lines[0]
    assert f"outside its physical range [{low:.6g}, {high:.6g}]" in lines[0]


def test_a_percent_soc_gets_a_hint():
    frame = full_frame().assign(soc=lambda d: 100 * d.soc)
    with pytest.raises(RecordingError, match="a percentage must be divided by 100"):
        recording_from_frame(frame)


def test_derived_power_is_held_to_the_power_range():
    # 1.9 kV x 9 kA: both in range, their product 17 MW is not
    frame = full_frame().drop(columns="power_W")
    frame.loc[5, ["voltage_V", "current_A"]] = [1900.0, 9000.0]
    with pytest.raises(RecordingError, match=r"'power_W' \(voltage_V x current_A\) = 1.71e\+07 at row 5"):
        recording_from_frame(frame)


def test_missing_values_are_still_dropped_or_filled_not_refused():
    frame = full_frame()
    frame.loc[4, "power_W"] = np.nan
    frame.loc[6, "soc"] = np.nan
    rec = recording_from_frame(frame)
    kinds = {i.kind: i for i in rec.issues}
    assert (kinds["missing_value"].count, kinds["missing_value"].first_row) == (1, 4)
    assert kinds["optional_missing"].first_row == 6


EXTREME = st.sampled_from([0.0, 1e-300, -1e-300, 9.99e6, -9.99e6, 1e7, 1.0000001e7, 1e308,
                           -1e308, math.inf, -math.inf, math.nan, 2000.0, 150.0, 150.1])


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(power=EXTREME, speed=EXTREME, column=st.sampled_from(["power_W", "v_mps", "x_m"]),
       row=st.integers(0, N - 1))
def test_predict_never_prints_null_energies_for_a_file_it_accepts(tmp_path, power, speed,
                                                                  column, row):
    scenario = write_scenario(tmp_path)
    frame = full_frame()
    frame.loc[row, column] = power
    frame.loc[(row + 7) % N, "v_mps"] = speed
    path = tmp_path / "rec.csv"
    frame.to_csv(path, index=False)
    code, stdout, stderr = run_cli("predict", path, "--scenario", scenario, "--json")
    if code == 2:
        assert stdout == "" and len(stderr.strip().splitlines()) == 1
        return
    assert code == 0, stderr
    report = json.loads(stdout)
    for key in ("energy_recorded_J", "energy_predicted_J", "energy_predicted_sd_J",
                "energy_error_pct", "rmse_W", "duration_s"):
        assert isinstance(report[key], float) and math.isfinite(report[key]), (key, report[key])
