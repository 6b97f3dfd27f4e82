"""Meteorological wind <-> vector (docs/guide/range.md), shared by scenario, truth, recordings, simulator."""

from __future__ import annotations

import numpy as np
import pytest

from orange_plan.physics.wind import wind_speed_and_from, wind_vector_mps


def test_wind_from_the_north_blows_south_and_from_the_west_blows_east():
    assert wind_vector_mps(5.0, 0.0) == pytest.approx((0.0, -5.0))
    assert wind_vector_mps(2.0, 270.0) == pytest.approx((2.0, 0.0))


def test_wind_round_trip_on_arrays():
    speed, frm = np.array([0.5, 3.0, 7.0]), np.array([10.0, 200.0, 359.0])
    back_speed, back_from = wind_speed_and_from(*wind_vector_mps(speed, frm))
    np.testing.assert_allclose(back_speed, speed)
    np.testing.assert_allclose(back_from, frm)
