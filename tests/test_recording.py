"""Recordings (docs/formats.md, docs/guide/recordings.md): reading, every validation rule, derived channels, motion state."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pandas as pd
import pytest
from conftest import write_scenario
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.errors import RecordingError
from orange_plan.telemetry.recording import (
    integrate_J,
    load_recording,
    recording_from_frame,
    split_blocks,
    write_recording,
)
from orange_plan.telemetry.state import recording_state


def straight(n=41, dt=0.1, speed=0.5, power=48.0) -> pd.DataFrame:
    """Driving east at constant speed, constant power."""
    t = np.arange(n) * dt
    return pd.DataFrame({"t_s": t, "power_W": power, "x_m": speed * t, "y_m": 0.0 * t})


def kinds(rec):
    return {i.kind: i for i in rec.issues}


# --- reading and writing ------------------------------------------------------------------


@pytest.mark.parametrize("name", ["rec.csv", "rec.parquet", "rec.csv.gz"])
def test_write_then_load_round_trip(tmp_path, name):
    rec = recording_from_frame(straight(), "mem")
    path = write_recording(rec, tmp_path / name)
    again = load_recording(path)
    pd.testing.assert_frame_equal(again.frame, rec.frame, check_dtype=False)
    assert [p.name for p in tmp_path.iterdir()] == [name]  # no temporary file left


def test_frame_has_the_always_columns_in_spec_order():
    rec = recording_from_frame(straight().assign(extra="kept"), "mem")
    cols = list(rec.frame.columns)
    assert cols[:2] == ["t_s", "power_W"]
    assert {"v_mps", "yaw_rate_radps", "accel_mps2", "x_m", "y_m", "extra"} <= set(cols)
    assert cols[-1] == "extra"


def test_energy_duration_distance_hand_values():
    rec = recording_from_frame(straight(n=11, dt=1.0, power=10.0), "mem")
    assert rec.duration_s == pytest.approx(10.0)
    assert rec.energy_J == pytest.approx(100.0)
    assert rec.distance_m == pytest.approx(5.0)


def test_trapezoid_of_a_ramp():
    df = pd.DataFrame({"t_s": [0.0, 1.0, 3.0], "power_W": [0.0, 10.0, 30.0], "v_mps": 1.0})
    assert recording_from_frame(df).energy_J == pytest.approx(0.5 * 10 + 0.5 * (10 + 30) * 2)


# --- refused input ---------------------------------------------------------------------------


@pytest.mark.parametrize("drop, needle", [
    (["t_s"], "'t_s'"),
    (["power_W"], "'power_W'"),
    (["x_m"], "'v_mps'"),
])
def test_missing_required_column_is_named(drop, needle):
    with pytest.raises(RecordingError, match=needle):
        recording_from_frame(straight().drop(columns=drop))


def test_voltage_without_current_names_current():
    df = straight().drop(columns="power_W").assign(voltage_V=24.0)
    with pytest.raises(RecordingError, match="current_A"):
        recording_from_frame(df)


def test_text_in_a_number_names_column_and_row(tmp_path):
    path = tmp_path / "r.csv"
    df = straight().astype({"power_W": object})
    df.loc[3, "power_W"] = "high"
    df.to_csv(path, index=False)
    with pytest.raises(RecordingError, match=r"'power_W' holds text 'high' at row 3 \(CSV line 5\)"):
        load_recording(path)


@pytest.mark.parametrize("content, needle", [
    ("", "empty"),
    ("t_s,power_W,v_mps\n", "no data rows"),
    ("t_s,power_W,v_mps\n0,1,1\n", "only one row"),
])
def test_empty_header_only_and_one_row_are_refused(tmp_path, content, needle):
    path = tmp_path / "r.csv"
    path.write_text(content)
    with pytest.raises(RecordingError, match=needle):
        load_recording(path)


@pytest.mark.parametrize("t, needle", [
    ([1.7e18, 1.7e18 + 1e8, 1.7e18 + 2e8], "epoch milli- or nanoseconds"),
    ([0.0, 1.0, 2e7], "spans"),
    ([0.0, math.inf, 2.0], "infinite"),
])
def test_bad_timestamps_are_refused_with_a_hint(t, needle):
    df = pd.DataFrame({"t_s": t, "power_W": 1.0, "v_mps": 1.0})
    with pytest.raises(RecordingError, match=f"{needle}.*seconds since the start"):
        recording_from_frame(df)


def test_epoch_seconds_are_rebased_and_reported():
    df = straight().assign(t_s=lambda d: d.t_s + 1.7e9)
    rec = recording_from_frame(df)
    assert rec.t_s[0] == 0.0
    assert kinds(rec)["rebased"].count == len(df)


def test_unknown_extension_and_missing_file(tmp_path):
    with pytest.raises(RecordingError, match="unknown recording extension"):
        write_recording(straight(), tmp_path / "r.txt")
    with pytest.raises(RecordingError, match="recording file not found"):
        load_recording(tmp_path / "nope.csv")


def test_nothing_usable_left_is_refused():
    df = straight(n=3).assign(power_W=[1.0, np.nan, np.nan])
    with pytest.raises(RecordingError, match="fewer than 2 usable rows"):
        recording_from_frame(df)


# --- cleaning rules, each reported --------------------------------------------------------------


def test_nan_in_needed_column_drops_rows_and_reports():
    df = straight()
    df.loc[[4, 9], "power_W"] = np.nan
    df.loc[12, "x_m"] = np.nan  # (an infinite value is refused instead: test_recording_ranges)
    rec = recording_from_frame(df)
    issue = kinds(rec)["missing_value"]
    assert (issue.count, issue.first_row) == (3, 4)
    assert len(rec.frame) == len(df) - 3


def test_backwards_and_duplicate_stamps_are_dropped_and_reported():
    df = straight(n=10, dt=1.0)
    df.loc[5, "t_s"] = 2.5          # goes back
    df.loc[7, "t_s"] = 6.0          # repeats row 6
    rec = recording_from_frame(df)
    k = kinds(rec)
    assert (k["backwards"].count, k["backwards"].first_row) == (1, 5)
    assert (k["duplicate"].count, k["duplicate"].first_row) == (1, 7)
    assert np.all(np.diff(rec.t_s) > 0)
    assert len(rec.frame) == 8


def test_gap_is_reported_and_not_bridged():
    t = np.r_[np.arange(0, 5.0, 1.0), np.arange(100.0, 105.0, 1.0)]
    df = pd.DataFrame({"t_s": t, "power_W": 10.0, "v_mps": 1.0})
    rec = recording_from_frame(df)
    gap = kinds(rec)["gap"]
    assert (gap.count, gap.first_row) == (1, 5)
    assert rec.energy_J == pytest.approx(80.0)      # 2 x 4 s at 10 W, the 96 s gap skipped
    assert rec.duration_s == pytest.approx(104.0)
    assert list(rec.interval_ok).count(False) == 1


def test_optional_column_holes_are_interpolated_and_reported():
    df = straight(n=5, dt=1.0).assign(soc=[1.0, np.nan, 0.8, np.nan, np.nan])
    rec = recording_from_frame(df)
    assert rec.frame["soc"].tolist() == pytest.approx([1.0, 0.9, 0.8, 0.8, 0.8])
    assert kinds(rec)["optional_missing"].count == 3


def test_negative_speed_becomes_ground_speed():
    df = pd.DataFrame({"t_s": [0, 1, 2.0], "power_W": 1.0, "v_mps": [0.5, -0.5, 0.5]})
    rec = recording_from_frame(df)
    assert rec.frame["v_mps"].tolist() == [0.5, 0.5, 0.5]
    assert kinds(rec)["reverse"].count == 1


# --- derived channels ---------------------------------------------------------------------------


def test_power_from_voltage_and_current():
    df = straight().drop(columns="power_W").assign(voltage_V=24.0, current_A=2.5)
    rec = recording_from_frame(df)
    assert np.allclose(rec.frame["power_W"], 60.0)
    assert any("voltage_V x current_A" in i.rule for i in rec.issues)


def test_speed_and_acceleration_from_straight_positions_are_exact():
    rec = recording_from_frame(straight(speed=0.7))
    assert np.allclose(rec.frame["v_mps"], 0.7)
    assert np.allclose(rec.frame["accel_mps2"], 0.0, atol=1e-9)
    assert np.allclose(rec.frame["yaw_rate_radps"], 0.0, atol=1e-9)


def test_yaw_rate_from_a_circle():
    t = np.arange(0, 60, 0.1)
    radius, omega = 5.0, 0.2
    df = pd.DataFrame({"t_s": t, "power_W": 1.0, "x_m": radius * np.cos(omega * t),
                       "y_m": radius * np.sin(omega * t)})
    rec = recording_from_frame(df)
    inner = slice(10, -10)
    assert np.allclose(rec.frame["yaw_rate_radps"][inner], omega, rtol=0.01)
    assert np.allclose(rec.frame["v_mps"][inner], radius * omega, rtol=0.01)


def test_no_positions_and_no_yaw_rate_gives_zero_and_says_so():
    df = pd.DataFrame({"t_s": [0, 1, 2.0], "power_W": 1.0, "v_mps": [0.0, 1.0, 2.0]})
    rec = recording_from_frame(df)
    assert rec.frame["yaw_rate_radps"].tolist() == [0.0, 0.0, 0.0]
    assert any("yaw rate set to 0" in i.rule for i in rec.issues)
    assert np.allclose(rec.frame["accel_mps2"], 1.0)


# --- blocks -------------------------------------------------------------------------------------


def test_split_blocks_are_contiguous_and_cover_the_run():
    rec = recording_from_frame(straight(n=101, dt=0.1))
    blocks = split_blocks(rec, 4)
    assert sum(len(b.frame) for b in blocks) == 101
    for a, b in itertools.pairwise(blocks):
        assert a.t_s[-1] < b.t_s[0]
    assert blocks[2].source.endswith("[block 3/4]")
    with pytest.raises(RecordingError, match="n_blocks"):
        split_blocks(rec, 0)
    with pytest.raises(RecordingError, match="fewer blocks"):
        split_blocks(rec, 100)


def test_integrate_any_channel():
    rec = recording_from_frame(straight(n=11, dt=1.0))
    assert integrate_J(rec, np.full(11, 2.0)) == pytest.approx(20.0)


# --- motion state ---------------------------------------------------------------------------------


def test_recording_state_grade_direction_and_defaults():
    t = np.arange(0, 200, 0.5)
    df = pd.DataFrame({"t_s": t, "power_W": 1.0, "x_m": 0.0 * t, "y_m": 1.0 * t,
                       "z_m": 0.05 * t})
    state = recording_state(recording_from_frame(df))
    slope = 0.05
    assert np.allclose(state.sin_t, slope, atol=1e-3)  # sin_t v = dz/dt
    assert np.allclose(state.cos_t ** 2 + state.sin_t ** 2, 1.0)
    assert np.allclose(state.dir_y, 1.0) and np.allclose(state.dir_x, 0.0, atol=1e-9)
    assert np.all(state.crr == 0.0) and np.all(state.surface_code == -1)
    state.validate()


def test_recording_state_flat_without_elevation():
    state = recording_state(recording_from_frame(straight()), sensor_rate_Hz=7.0)
    assert np.all(state.sin_t == 0.0) and np.all(state.cos_t == 1.0)
    assert np.all(state.sensor_rate_Hz == 7.0)


def test_wind_columns_are_meteorological():
    df = straight(n=5).assign(wind_mps=4.0, wind_from_deg=90.0)  # from the east: blows west
    state = recording_state(recording_from_frame(df))
    assert np.allclose(state.wind_x_mps, -4.0) and np.allclose(state.wind_y_mps, 0.0, atol=1e-12)


def test_world_gives_crr_and_surface_at_positions(tmp_path):
    ctx = load_context(write_scenario(tmp_path))  # yard: grass (crr 0.1) where x > 10
    t = np.arange(0, 17, 0.5)
    df = pd.DataFrame({"t_s": t, "power_W": 1.0, "x_m": 1.0 + t, "y_m": 5.0})
    state = recording_state(recording_from_frame(df), ctx.world)
    on_grass = df["x_m"].to_numpy() > 10
    assert np.allclose(state.crr[on_grass], 0.1) and np.allclose(state.crr[~on_grass], 0.05)
    assert set(state.surface_code[on_grass]) == {0} and set(state.surface_code[~on_grass]) == {-1}


def test_surface_column_maps_through_the_world(tmp_path):
    ctx = load_context(write_scenario(tmp_path))
    df = pd.DataFrame({"t_s": [0, 1, 2.0], "power_W": 1.0, "v_mps": 1.0,
                       "surface": ["grass", "Grass", "ice"], "sensor_rate_Hz": 3.0})
    state = recording_state(recording_from_frame(df), ctx.world, sensor_rate_Hz=9.0)
    assert state.crr.tolist() == [0.1, 0.1, 0.05]
    assert state.surface_code.tolist() == [0, 0, -1]
    assert state.sensor_rate_Hz.tolist() == [3.0, 3.0, 3.0]
    assert np.allclose(state.wind_x_mps, 0.0)  # no wind columns, no conditions: calm


def test_a_recording_without_wind_columns_takes_the_conditions_wind(tmp_path):
    """A session's measured wind (``conditions.with_wind``) reaches the samples of a
    recording that carries no wind: the conditions are the one holder of the wind."""
    ctx = load_context(write_scenario(tmp_path, set={"environment.wind_speed_mps": 3.0,
                                                     "environment.wind_from_deg": 90.0}))
    df = pd.DataFrame({"t_s": [0, 1, 2.0], "power_W": 1.0, "v_mps": 1.0})
    measured = ctx.conditions.with_wind((1.5, -0.5))
    state = recording_state(recording_from_frame(df), ctx.world, conditions=measured)
    assert np.allclose(state.wind_x_mps, 1.5) and np.allclose(state.wind_y_mps, -0.5)
    with_columns = df.assign(wind_mps=2.0, wind_from_deg=0.0)  # from the north: blows south
    state = recording_state(recording_from_frame(with_columns), ctx.world, conditions=measured)
    assert np.allclose(state.wind_x_mps, 0.0, atol=1e-12) and np.allclose(state.wind_y_mps, -2.0)


# --- invariants -----------------------------------------------------------------------------------

@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 50), st.floats(0.0, 500.0), st.floats(0.0, 2.0)),
                min_size=2, max_size=40))
def test_cleaning_invariants(rows):
    """Whatever the order of stamps: time strictly increases, every dropped row is counted,
    energy of non-negative power is non-negative and at most max power x duration."""
    df = pd.DataFrame(rows, columns=["t_s", "power_W", "v_mps"]).astype(float)
    try:
        rec = recording_from_frame(df)
    except RecordingError as exc:
        assert "fewer than 2 usable rows" in str(exc)
        return
    assert np.all(np.diff(rec.t_s) > 0)
    dropped = sum(i.count for i in rec.issues if i.kind in ("backwards", "duplicate"))
    assert len(rec.frame) + dropped == len(df)
    assert 0.0 <= rec.energy_J <= df["power_W"].max() * rec.duration_s + 1e-9
    assert rec.distance_m >= 0.0


def test_recording_state_hvac_and_elapsed_time():
    frame = pd.DataFrame({"t_s": [10.0, 11.0, 12.0], "power_W": 1.0, "v_mps": 2.0,
                          "hvac_W": [500.0, np.nan, 700.0]})
    state = recording_state(recording_from_frame(frame))
    np.testing.assert_allclose(state.channel("elapsed_s"), [0.0, 1.0, 2.0])  # since the start
    np.testing.assert_allclose(state.channel("hvac_W"), [500.0, 0.0, 700.0])  # missing counts 0
    no_hvac = recording_state(recording_from_frame(frame.drop(columns="hvac_W")))
    np.testing.assert_allclose(no_hvac.channel("hvac_W"), 0.0)


def test_other_columns_keep_their_dtype_and_rows_through_cleaning():
    """The rules work on arrays and build the table once: columns the rules do not read
    (text, flags, nullable numbers) come out with their dtype, filtered like every row."""
    df = pd.DataFrame({
        "t_s": [0.0, 1.0, 1.0, 2.0, 3.0],  # a duplicate stamp: row 2 dropped
        "power_W": [5.0, 6.0, 7.0, np.nan, 8.0],  # a missing power: row 3 dropped
        "v_mps": [0.5, 0.5, 0.5, 0.5, 0.5],
        "surface": ["grass", "tile", "x", "y", "tile"],
        "wheels_up": [False, True, False, False, True],
        "hvac_W": pd.array([1, None, 3, 4, 5], dtype="Int64"),
    })
    df.attrs["import_notes"] = ["a note"]
    rec = recording_from_frame(df)
    f = rec.frame
    assert f["surface"].tolist() == ["grass", "tile", "tile"]
    assert f["wheels_up"].dtype == bool and f["wheels_up"].tolist() == [False, True, True]
    assert str(f["hvac_W"].dtype) == "Int64" and f["hvac_W"].isna().tolist() == [False, True,
                                                                                 False]
    assert f.attrs["import_notes"] == ["a note"]
    assert f["t_s"].dtype == float and list(f.columns[:3]) == ["t_s", "power_W", "v_mps"]


def test_a_column_named_twice_is_refused():
    df = pd.DataFrame([[0.0, 1.0, 0.5, 2.0], [1.0, 1.0, 0.5, 2.0]],
                      columns=["t_s", "power_W", "v_mps", " power_W"])
    with pytest.raises(RecordingError, match="column 'power_W' appears twice"):
        recording_from_frame(df)


def test_a_climb_on_the_spot_converts_to_a_recording_that_loads(tmp_path):
    """A drone climbing at 3 m/s (its 3-D speed in ``v_mps``) while its position drifts by
    millimetres has no heading: the derived yaw rate is held by the horizontal speed, so the
    written recording passes its own loader's range check (|yaw rate| <= 100 rad/s)."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 30.0, 0.02)
    drift = np.cumsum(rng.normal(0.0, 1e-3, (2, t.size)), axis=1)
    frame = pd.DataFrame({"t_s": t, "power_W": 400.0, "x_m": 2.0 + drift[0],
                          "y_m": 1.0 + drift[1], "z_m": 3.0 * t, "v_mps": 3.0})
    path = tmp_path / "climb.csv"
    write_recording(recording_from_frame(frame, "climb"), path)
    yaw = load_recording(path).frame["yaw_rate_radps"].to_numpy()
    assert np.all(np.abs(yaw) < 1.0)


def test_the_wadl_track_and_a_recording_share_one_yaw_rate_derivation():
    """The WADL importer's track yaw rate is the generic derivation without smoothing: a
    square flown at 2 m/s turns by pi/2 at each corner and holds its heading on the spot."""
    from orange_plan.telemetry.derive import position_yaw_rate_radps

    t = np.arange(0.0, 41.0)
    x = np.interp(t, [0, 5, 15, 25, 35, 40], [0, 0, 20, 20, 0, 0])
    y = np.interp(t, [0, 5, 15, 25, 35, 40], [0, 0, 0, 20, 20, 20])
    yaw = position_yaw_rate_radps(x, y, t, still_mps=0.5, window=1)
    assert np.trapezoid(yaw, t) == pytest.approx(np.pi, abs=1e-9)  # two left turns
    assert np.all(yaw[:5] == 0.0) and np.all(yaw[36:] == 0.0)
