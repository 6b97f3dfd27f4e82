"""MotionState take/concat and channels; one recording -> state path for predict and calibrate."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
from conftest import write_scenario
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.identify.calibrate import recording_samples
from orange_plan.physics.state import CHANNELS, MotionState
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.replay import replay
from orange_plan.telemetry.state import recording_state

finite = st.floats(-1e3, 1e3, allow_nan=False)


@st.composite
def columns(draw):
    """Per-sample columns by name (fields and channels; some scalar) and their length."""
    n = draw(st.integers(1, 12))
    names = draw(st.sets(st.sampled_from(
        ["cos_t", "crr", "accel_mps2", "hvac_W", "elapsed_s", "heater_request_W"])))
    out = {"speed_mps": np.array(draw(st.lists(finite, min_size=n, max_size=n)))}
    for name in sorted(names):
        out[name] = (draw(finite) if draw(st.booleans())
                     else np.array(draw(st.lists(finite, min_size=n, max_size=n))))
    return out, n


@settings(max_examples=80, deadline=None)
@given(case=columns(), cuts=st.lists(st.integers(0, 12), max_size=3))
def test_take_then_concat_gives_back_every_column(case, cuts):
    values, n = case
    state = MotionState.from_values(values)
    bounds = [0, *sorted(min(c, n) for c in cuts), n]
    parts = [state.take(slice(a, b), n) for a, b in itertools.pairwise(bounds)]
    whole = MotionState.concat(parts, [b - a for a, b in itertools.pairwise(bounds)])
    for name, column in values.items():   # the reference: the numpy columns themselves
        got = whole.channel(name) if name in CHANNELS else getattr(whole, name)
        np.testing.assert_array_equal(got, np.broadcast_to(column, (n,)))
    mask = np.arange(n) % 2 == 0
    np.testing.assert_array_equal(state.take(mask, n).speed_mps, values["speed_mps"][mask])


def test_unknown_channel_is_named():
    with pytest.raises(TypeError, match="no field or channel 'cabin_W'"):
        MotionState(speed_mps=1.0).with_(cabin_W=3.0)


def test_a_declared_channel_is_read_from_its_column():
    frame = pd.DataFrame({"t_s": [0.0, 1.0, 2.0], "power_W": [10.0, 11.0, 12.0],
                          "v_mps": [1.0, 1.0, 1.0], "heater_request_W": [0.0, 50.0, np.nan]})
    state = recording_state(recording_from_frame(frame))
    assert set(CHANNELS) <= set(state.channels)
    np.testing.assert_allclose(state.channel("heater_request_W"), [0.0, 50.0, 0.0])  # gap: 0


def test_predict_and_calibrate_see_the_same_wheels_up_rows(tmp_path):
    """A wheels-up bench run: replay (predict) and calibration charge no traction there."""
    ctx = load_context(write_scenario(tmp_path))
    n = 40
    frame = pd.DataFrame({"t_s": np.arange(n, dtype=float), "power_W": np.full(n, 20.0),
                          "v_mps": np.full(n, 1.5), "accel_mps2": np.zeros(n),
                          "wheels_up": [1] * 20 + [0] * 20})
    rec = recording_from_frame(frame)
    predicted = replay(rec, ctx.model, ctx.world, ctx.conditions.sensor_rate_Hz).predicted_W
    fitted_state = recording_samples([rec], ctx).state
    np.testing.assert_allclose(predicted, ctx.model.power_W(fitted_state) * np.ones(n))
    idle = float(ctx.model.power_W(MotionState(speed_mps=0.0, crr=ctx.world.default_crr,
                                               sensor_rate_Hz=ctx.conditions.sensor_rate_Hz)))
    np.testing.assert_allclose(predicted[:20], idle)
    assert predicted[-1] > idle
