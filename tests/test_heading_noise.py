"""The direction of travel read from noisy positions: the positions' own noise estimated from
their second differences, and the heading taken over a path that noise cannot swing."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.telemetry.derive import position_noise_m, window_samples
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.state import HEADING_NOISE_PATHS, _heading_window, recording_state


def test_the_noise_of_a_hand_made_track_is_its_second_differences_spread():
    """x alternates +-e about a straight line: its 18 second differences are +-4 e; y is
    exact: its 18 are 0. Pooled, the median is 0 and the median absolute deviation the
    median of 18 x 4 e and 18 x 0, i.e. 2 e; the noise is 1.4826 x 2 e / sqrt(6)."""
    e = 0.1
    x = np.arange(20.0) + e * (-1.0) ** np.arange(20)
    y = np.zeros(20)
    assert position_noise_m(x, y) == pytest.approx(1.4826 * 2 * e / math.sqrt(6.0))


@settings(max_examples=20, deadline=None)
@given(sd=st.floats(0.01, 1.0), seed=st.integers(0, 1000), speed=st.floats(0.3, 8.0))
def test_the_estimate_recovers_white_noise_on_a_curving_track(sd, seed, speed):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 300.0, 0.1)
    heading = 0.05 * t  # a steady turn: its acceleration is far below the noise
    x = np.cumsum(speed * np.cos(heading)) * 0.1 + rng.normal(0, sd, t.size)
    y = np.cumsum(speed * np.sin(heading)) * 0.1 + rng.normal(0, sd, t.size)
    assert position_noise_m(x, y) == pytest.approx(sd, rel=0.1)


def test_a_smooth_track_has_no_noise_and_keeps_the_usual_window():
    t = np.arange(0.0, 60.0, 0.1)
    x, y = 0.8 * t, np.zeros_like(t)
    assert position_noise_m(x, y) == pytest.approx(0.0, abs=1e-12)
    assert _heading_window(t, np.full(t.size, 0.8), 0.0) == 1


def test_too_few_samples_or_no_finite_values_give_no_noise():
    assert position_noise_m([0.0, 1.0], [0.0, 0.0]) == 0.0
    assert position_noise_m([], []) == 0.0
    assert position_noise_m([np.nan] * 5, [np.nan] * 5) == 0.0


def test_the_window_covers_the_path_the_noise_asks_for():
    t = np.arange(0.0, 100.0, 0.1)
    # 0.4 m of noise x 8 = 3.2 m of path at 1 m/s and 10 Hz: 32 samples, made odd
    assert _heading_window(t, np.full(t.size, 1.0), HEADING_NOISE_PATHS * 0.4) == 33
    assert _heading_window(t, np.zeros(t.size), 3.2) == 1  # at rest: no window
    assert _heading_window(t[:20], np.full(20, 0.01 + 1.0), 100.0) == 5  # a quarter at most


def test_a_slow_boats_heading_is_taken_over_a_path_its_noise_cannot_swing():
    """A boat at 1 m/s logging positions with 0.4 m of noise at 10 Hz: differenced over half
    a second of path its heading swung by tens of degrees; over a path of
    ``HEADING_NOISE_PATHS`` times the noise it is within a few degrees."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 600.0, 0.1)
    frame = pd.DataFrame({"t_s": t, "power_W": 1.0, "v_mps": 1.0,
                          "x_m": t + rng.normal(0, 0.4, t.size),
                          "y_m": rng.normal(0, 0.4, t.size)})
    state = recording_state(recording_from_frame(frame))
    error_deg = np.degrees(np.arctan2(np.asarray(state.dir_y), np.asarray(state.dir_x)))
    assert float(np.sqrt(np.mean(error_deg**2))) < 10.0
    assert float(np.mean(np.asarray(state.dir_x))) > 0.98


def test_a_ground_robots_few_centimetres_of_noise_keep_its_turns_sharp():
    """5 cm of noise at 0.8 m/s asks for 0.4 m of path: no more than the usual half-second
    window, so the heading through a right-angle turn is what it was."""
    t = np.arange(0.0, 0.1 * 400, 0.1)
    assert _heading_window(t, np.full(t.size, 0.8), HEADING_NOISE_PATHS * 0.05) \
        <= window_samples(t)
