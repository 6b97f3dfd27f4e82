"""Path energy (docs/guide/range.md, Eq. 7): ramps over a DEM, surfaces crossed, turning at interior vertices."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import feature, write_asc, write_map
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.errors import InputError
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.pathcost import (
    heading_changes_rad,
    max_step_m,
    path_energy,
    segments_energy,
    segments_energy_jacobian,
    subdivide,
)
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import TERMS, surface_rolling_term
from orange_plan.world.geomap import load_map
from orange_plan.world.terrain import World

G = 9.81
MASS_KG, OMEGA = 10.0, 0.8  # lumped rolling_kg = grade_kg = 10 / 0.8 = 12.5


def reference_model(turn_J_per_rad: float = 0.0) -> EnergyModel:
    terms = [TERMS["ancillary"], TERMS["rolling"], TERMS["grade"]]
    theta = {"ancillary_W": 10.0, "rolling_kg": MASS_KG / OMEGA, "grade_kg": MASS_KG / OMEGA}
    if turn_J_per_rad:
        terms.append(TERMS["turning"])
        theta["turn_J_per_rad"] = turn_J_per_rad
    return EnergyModel(terms, theta, omega=OMEGA)


def world_of(map_path, default_crr=0.05, home=(1.0, 1.5)) -> World:
    return World(load_map(map_path), default_crr, "default", home)


def ramp_world(tmp_path, corner: bool) -> World:
    """12 m x 3 m strip, 1 m cells; centres at x = 0.5 .. 11.5 with z = 0.1 x_centre."""
    z_row = [0.1 * (j + 0.5) for j in range(12)]
    origin = 0.0 if corner else 0.5  # xllcorner 0 and xllcenter 0.5 describe the same grid
    write_asc(tmp_path / "ramp.asc", [z_row] * 3, 1.0, origin, origin, corner=corner)
    boundary = feature("boundary", "Polygon", [[[0, 0], [12, 0], [12, 3], [0, 3], [0, 0]]])
    return world_of(write_map(tmp_path, [boundary], elevation="ramp.asc"))


@pytest.mark.parametrize("corner", [True, False], ids=["xllcorner", "xllcenter"])
def test_straight_segment_over_ramp_dem(tmp_path, corner):
    world = ramp_world(tmp_path, corner)
    assert max_step_m(world) == 0.5  # min(0.5 m, half a 1 m cell)
    steps = subdivide(world, [[0.0, 1.5]], [[12.0, 1.5]])
    # 24 sub-steps of 0.5 m; x in [0, 0.5] and [11.5, 12] are outer half cells (flat),
    # the 22 steps between rise 0.1 * 0.5 = 0.05 m each (bilinear = linear here)
    assert steps.length_m.size == 24
    np.testing.assert_allclose(steps.horiz_m, 0.5)
    np.testing.assert_allclose(steps.dz_m, [0.0] + [0.05] * 22 + [0.0], atol=1e-6)  # float32 grid

    e = segments_energy(reference_model(), world, [[0.0, 1.5]], [[12.0, 1.5]], 1.0, Conditions(1.0))
    # traversal = (crr m g d + m g dz) / Omega = (0.05*10*9.81*12 + 10*9.81*1.1) / 0.8
    #           = (58.86 + 107.91) / 0.8 = 208.4625 J
    assert float(e.traversal_J[0]) == pytest.approx(208.4625)
    # L = 2 * 0.5 + 22 * hypot(0.5, 0.05) = 1 + 22 * 0.5024938 = 12.054863 m; 10 W, v = 1, D = 1
    assert float(e.moving_time_s[0]) == pytest.approx(12.054863, rel=1e-6)
    assert float(e.ancillary_J[0]) == pytest.approx(120.54863, rel=1e-6)

    # Downhill: the ramp steps have F = 12.5 g (0.05 cos - 0.0995) < 0 and give nothing back
    # (max(0, .) per sub-step); only the two flat 0.5 m steps cost 12.5 * 9.81 * 0.05 * 1 m.
    back = segments_energy(reference_model(), world, [[12.0, 1.5]], [[0.0, 1.5]], 1.0,
                           Conditions(1.0))
    assert float(back.traversal_J[0]) == pytest.approx(12.5 * 9.81 * 0.05 * 1.0)


def test_substep_shortened_to_half_a_cell(tmp_path):
    write_asc(tmp_path / "fine.asc", [[0.0] * 30] * 30, 0.4, 0.0, 0.0)
    boundary = feature("boundary", "Polygon", [[[0, 0], [12, 0], [12, 12], [0, 12], [0, 0]]])
    world = world_of(write_map(tmp_path, [boundary], elevation="fine.asc"))
    assert max_step_m(world) == pytest.approx(0.2)
    steps = subdivide(world, [[0.0, 1.0]], [[3.0, 1.0]])
    assert steps.length_m.size == 15 and steps.length_m.max() <= 0.2 + 1e-12


def test_segment_crossing_a_surface(tmp_path):
    world = world_of(write_map(tmp_path), home=(2.0, 5.0))  # grass crr 0.1 for x > 10
    steps = subdivide(world, [[2.0, 2.0], [2.0, 2.0]], [[18.0, 2.0], [9.3, 2.0]])
    assert steps.length_m.max() <= 0.5
    # first segment: 32 sub-steps of 0.5 m, 16 of them (midpoints x > 10) on grass
    first = steps.segment == 0
    assert first.sum() == 32
    assert (steps.crr[first] == 0.1).sum() == 16 and (steps.crr[first] == 0.05).sum() == 16
    assert set(steps.surface_code[first]) == {-1, 0}
    # second: 7.3 m in ceil(7.3 / 0.5) = 15 steps of 0.4867 m, none on grass
    assert (steps.segment == 1).sum() == 15 and (steps.crr[steps.segment == 1] == 0.05).all()

    e = segments_energy(reference_model(), world, [[2.0, 2.0]], [[18.0, 2.0]], 0.5, Conditions(0.8))
    # traversal = 12.5 * 9.81 * (0.05 * 8 + 0.1 * 8) = 147.15 J
    assert float(e.traversal_J[0]) == pytest.approx(147.15)
    # ancillary: 10 W * 16 m / (0.5 m/s * 0.8) = 400 J
    assert float(e.ancillary_J[0]) == pytest.approx(400.0)


def test_turning_charged_at_interior_vertices(tmp_path):
    world = world_of(write_map(tmp_path), home=(2.0, 2.0))
    path = [[2.0, 2.0], [8.0, 2.0], [8.0, 6.0], [2.0, 6.0]]  # two left quarter turns
    pe = path_energy(reference_model(turn_J_per_rad=3.0), world, path, 1.0, Conditions(1.0))
    # 3 J/rad * pi/2 at each interior vertex, charged to the segment leaving it
    np.testing.assert_allclose(pe.segments.turning_J, [0.0, 1.5 * math.pi, 1.5 * math.pi])
    # flat default ground, 16 m: rolling 12.5*9.81*0.05*16 = 98.1 J, ancillary 10 W * 16 s
    assert pe.total_J == pytest.approx(98.1 + 160.0 + 3 * math.pi)
    assert pe.duration_s == pytest.approx(16.0)
    assert pe.cumulative_J.shape == (4,) and pe.cumulative_J[0] == 0.0
    assert np.all(np.diff(pe.cumulative_J) > 0)
    # without a turning term the same path costs 3 pi less
    plain = path_energy(reference_model(), world, path, 1.0, Conditions(1.0))
    assert plain.total_J == pytest.approx(
        pe.total_J - 3 * math.pi)


def test_heading_changes_wrap_around():
    # east then north: pi/2; a U-turn: pi; headings 170 deg -> -170 deg: 20 deg, not 340
    assert heading_changes_rad([[0, 0], [1, 0], [1, 1]]) == pytest.approx([math.pi / 2])
    assert heading_changes_rad([[0, 0], [1, 0], [0, 0]]) == pytest.approx([math.pi])
    a, b = math.radians(170), math.radians(-170)
    p = [[0, 0], [math.cos(a), math.sin(a)], [math.cos(a) + math.cos(b), math.sin(a) + math.sin(b)]]
    assert heading_changes_rad(p) == pytest.approx([math.radians(20)])


def test_heading_changes_ignore_a_repeated_vertex():
    # a repeated vertex is not a turn to heading 0: north, (stay), west = one pi/2 turn
    got = heading_changes_rad([[0, 0], [0, 1], [0, 1], [-1, 1]])
    assert got.shape == (2,) and got == pytest.approx([0.0, math.pi / 2])
    lead = heading_changes_rad([[2, 2], [2, 2], [2, 3], [1, 3]])  # leading repeat
    assert lead == pytest.approx([0.0, math.pi / 2])


def test_segments_energy_jacobian_matches_energy(tmp_path):
    world = ramp_world(tmp_path, corner=True)
    model = reference_model()
    a, b = [[0.5, 0.5], [11.0, 2.5]], [[11.0, 2.5], [3.0, 1.0]]
    steps = subdivide(world, a, b)
    jac = segments_energy_jacobian(model, world, steps, [0.8, 1.2], Conditions(0.9))
    e = segments_energy(model, world, a, b, [0.8, 1.2], Conditions(0.9))
    assert jac.shape == (2, 3)
    np.testing.assert_allclose(jac @ model.theta, e.ancillary_J + e.traversal_J)


def test_pathcost_bad_inputs(tmp_path):
    world = world_of(write_map(tmp_path), home=(2.0, 5.0))
    with pytest.raises(InputError, match=r"must both have shape \(n, 2\)"):
        subdivide(world, [[0.0, 0.0, 0.0]], [[1.0, 1.0, 1.0]])
    with pytest.raises(InputError, match="speed_mps must be > 0"):
        segments_energy(reference_model(), world, [[1.0, 1.0]], [[2.0, 1.0]], 0.0, Conditions(1.0))
    with pytest.raises(InputError, match="at least two"):
        path_energy(reference_model(), world, [[1.0, 1.0]], 1.0, Conditions(1.0))


# --- properties -------------------------------------------------------------------------



def no_regen_model() -> EnergyModel:
    terms = [TERMS["ancillary"], TERMS["sensor_rate"], TERMS["rolling"],
             surface_rolling_term(("grass",)), TERMS["aero_drag"], TERMS["grade"],
             TERMS["inertia"], TERMS["turning"]]
    theta = {"ancillary_W": 5.0, "sensor_W_per_Hz": 0.1, "rolling_kg": 12.5,
             "rolling_kg_grass": 15.0, "drag_kg_per_m": 0.4, "grade_kg": 12.5,
             "inertia_kg": 12.5, "turn_J_per_rad": 2.0}
    return EnergyModel(terms, theta, omega=OMEGA)


states = st.builds(
    dict,
    speed_mps=st.floats(1e-3, 30.0),
    angle=st.floats(-1.5, 1.5),
    heading=st.floats(-4.0, 4.0),
    wind_x_mps=st.floats(-20.0, 20.0),
    wind_y_mps=st.floats(-20.0, 20.0),
    crr=st.floats(0.0, 1.0),
    accel_mps2=st.floats(-5.0, 5.0),
    sensor_rate_Hz=st.floats(0.0, 60.0),
    surface_code=st.integers(-1, 0),
)


def to_state(d) -> MotionState:
    d = dict(d)
    angle, heading = d.pop("angle"), d.pop("heading")
    return MotionState(cos_t=math.cos(angle), sin_t=math.sin(angle), dir_x=math.cos(heading),
                       dir_y=math.sin(heading), **d).validate()


@settings(max_examples=60, deadline=None)
@given(s=states, length=st.floats(0.0, 100.0), duty=st.floats(0.01, 1.0),
       turn=st.floats(0.0, math.pi))
def test_energy_never_negative_without_regen(s, length, duty, turn):
    model = no_regen_model()
    state = to_state(s)
    e = model.segment_energy(state, length, duty, turn)
    assert float(e.traversal_J) >= 0 and float(e.ancillary_J) >= 0 and float(e.turning_J) >= 0
    assert float(e.total_J) >= 0
    assert float(model.power_W(state)) >= 0


@settings(max_examples=60, deadline=None)
@given(s=states, length=st.floats(0.01, 100.0), split=st.floats(0.0, 1.0),
       duty=st.floats(0.01, 1.0))
def test_segment_energy_additive_when_split(s, length, split, duty):
    model = no_regen_model()
    state = to_state(s)
    whole = float(model.segment_energy(state, length, duty).total_J)
    parts = sum(float(model.segment_energy(state, part, duty).total_J)
                for part in (length * split, length * (1 - split)))
    assert parts == pytest.approx(whole, rel=1e-9, abs=1e-9)


@pytest.fixture(scope="module")
def flat_windy_world(tmp_path_factory):
    folder = tmp_path_factory.mktemp("flat")
    boundary = feature("boundary", "Polygon", [[[0, 0], [50, 0], [50, 50], [0, 50], [0, 0]]])
    return world_of(write_map(folder, [boundary]), home=(1.0, 1.0))


WINDY = Conditions(0.7, 0.0, (2.0, -1.0))  # the additivity test's duty cycle and wind


@settings(max_examples=30, deadline=None)
@given(ax=st.floats(0, 50), ay=st.floats(0, 50), bx=st.floats(0, 50), by=st.floats(0, 50),
       split=st.floats(0.0, 1.0), speed=st.floats(0.1, 5.0))
def test_path_segment_energy_additive_when_split(flat_windy_world, ax, ay, bx, by, split, speed):
    model = no_regen_model()
    a, b = np.array([ax, ay]), np.array([bx, by])
    mid = a + split * (b - a)
    whole = segments_energy(model, flat_windy_world, [a], [b], speed, WINDY)
    halves = segments_energy(model, flat_windy_world, [a, mid], [mid, b], speed, WINDY)
    assert halves.traversal_J.sum() == pytest.approx(whole.traversal_J[0], rel=1e-9, abs=1e-9)
    assert halves.ancillary_J.sum() == pytest.approx(whole.ancillary_J[0], rel=1e-9, abs=1e-9)
