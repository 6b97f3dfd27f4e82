"""Planning charges a drift at its worst over the mission's horizon (``physics.horizon``):
a rising line or a step within the horizon is charged, a cold-start decay at its start."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.horizon import mission_horizon_s, planning_elapsed_s, worst_elapsed_s
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.model_builder import model_with_terms
from orange_plan.physics.pathcost import path_energy
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import G_MPS2, TERMS, drift_term

LIMIT_S = 2000.0
PATH_XY_M = np.array([[2.0, 2.0], [30.0, 2.0], [30.0, 20.0]])


@pytest.fixture(scope="module")
def limited(tmp_path_factory):
    """A flat world whose mission may last at most LIMIT_S."""
    return load_context(write_world(tmp_path_factory.mktemp("drift"), time_limit_s=LIMIT_S))


def _with_drift(ctx, term, drift_W):
    base = model_with_terms(ctx, [*ctx.model.term_ids])
    return replace(ctx, model=base.with_terms([*base.terms, term], {"drift_W": drift_W}))


def _charged_drift_W(ctx, drifted) -> float:
    """The drift power a planned path is charged: its ancillary energy over its mission time,
    with and without the drift."""
    with_drift = path_energy(drifted.model, drifted.world, PATH_XY_M, 1.0, drifted.conditions)
    without = path_energy(ctx.model, ctx.world, PATH_XY_M, 1.0, ctx.conditions)
    extra_J = with_drift.cumulative_J[-1] - without.cumulative_J[-1]
    return float(extra_J / without.cumulative_time_s[-1])


@pytest.mark.parametrize(("term", "drift_W", "expected_W"), [
    (drift_term("linear", 1000.0), 5.0, 5.0 * LIMIT_S / 1000.0),     # rising: at the end, 10 W
    (drift_term("linear", 1000.0), -5.0, 0.0),                       # falling: at the start
    (drift_term("decay", 600.0), 8.0, 8.0),                          # cold start: at t = 0
    (drift_term("decay", 600.0), -8.0, -8.0 * math.exp(-LIMIT_S / 600.0)),  # levels off: at T
    (drift_term("step", 1.0, 1500.0), 6.0, 6.0),                     # switched on in time
    (drift_term("step", 1.0, 2500.0), 6.0, 0.0),                     # after the horizon
    (drift_term("step", 1.0, 1500.0), -6.0, 0.0),                    # switched off: before
])
def test_planning_charges_a_drift_at_its_worst_over_the_horizon(limited, term, drift_W,
                                                                expected_W):
    drifted = _with_drift(limited, term, drift_W)
    assert _charged_drift_W(limited, drifted) == pytest.approx(expected_W, abs=1e-9)


def test_a_rising_line_sits_at_the_time_limit_and_a_decay_at_the_start(limited):
    rising = _with_drift(limited, drift_term("linear", 1000.0), 5.0)
    decay = _with_drift(limited, drift_term("decay", 600.0), 8.0)
    assert rising.conditions.elapsed_s == LIMIT_S
    assert decay.conditions.elapsed_s == 0.0
    assert limited.conditions.elapsed_s == 0.0  # no drift: nothing to place


def test_the_worst_time_follows_the_model_not_stale_conditions(limited):
    """``replace(ctx, model=...)`` keeps the old conditions' wind but places the new drift."""
    rising = _with_drift(limited, drift_term("linear", 1000.0), 5.0)
    falling = replace(rising, model=rising.model.with_theta({"drift_W": -5.0}))
    assert (rising.conditions.elapsed_s, falling.conditions.elapsed_s) == (LIMIT_S, 0.0)


def test_without_a_time_limit_the_horizon_is_the_battery_at_the_slowest_speed():
    """Hand-computed: 3 W of ancillary and a 10 kg rolling mass on crr 0.02 at 0.5 m/s, moving
    80 % of the time, from 36 kJ: P = 3 + 0.8 * 10 * 9.81 * 0.02 * 0.5 W."""
    model = EnergyModel([TERMS["ancillary"], TERMS["rolling"], drift_term("linear", 100.0)],
                        {"ancillary_W": 3.0, "rolling_kg": 10.0, "drift_W": 1.0})
    scenario = SimpleNamespace(name="s", mission=SimpleNamespace(time_limit_s=None),
                               robot=SimpleNamespace(v_min_mps=0.5),
                               battery=SimpleNamespace(usable_J=36_000.0))
    conditions = Conditions(0.8)
    power = 3.0 + 0.8 * 10.0 * G_MPS2 * 0.02 * 0.5
    horizon = mission_horizon_s(scenario, model, 0.02, conditions)
    assert horizon == pytest.approx(36_000.0 / power, rel=1e-12)
    assert planning_elapsed_s(scenario, model, 0.02, conditions) == pytest.approx(horizon)


def test_a_planned_state_with_a_drift_is_one_value_per_step_numpy_and_casadi():
    import casadi as ca

    model = EnergyModel([TERMS["ancillary"], drift_term("linear", 100.0)],
                        {"ancillary_W": 3.0, "drift_W": 2.0})
    channels = Conditions(1.0, elapsed_s=300.0).channels
    power = model.power_W(MotionState(speed_mps=np.ones(4), channels=channels))
    assert np.asarray(power).shape == (4,) and np.allclose(power, 3.0 + 2.0 * 3.0)
    v = ca.SX.sym("v")
    symbolic = model.power_W(MotionState(speed_mps=v, channels=channels))
    assert float(ca.Function("p", [v], [symbolic])(1.0)) == pytest.approx(9.0)


def test_the_simulated_truth_follows_the_clock(limited):
    """The simulator is the truth, not planning: its drift rises with the recording's time."""
    from orange_plan.sim.route import Route
    from orange_plan.sim.simulator import simulate

    route = Route(PATH_XY_M, np.full(len(PATH_XY_M), 1.0), "test")
    base = simulate(limited, route).frame
    rising = simulate(_with_drift(limited, drift_term("linear", 1000.0), 5.0), route).frame
    extra = (rising["power_W"] - base["power_W"]).to_numpy()
    assert extra == pytest.approx(5.0 * base["t_s"].to_numpy() / 1000.0, abs=1e-9)


def test_bad_horizons_and_times_are_one_line_input_errors():
    model = EnergyModel([drift_term("linear", 100.0)], {"drift_W": 1.0})
    with pytest.raises(InputError, match="horizon"):
        worst_elapsed_s(model, math.nan, 1.0, 0.02, Conditions(1.0))
    with pytest.raises(InputError, match="elapsed_s"):
        Conditions(1.0, elapsed_s=-1.0)
    scenario = SimpleNamespace(name="s", mission=SimpleNamespace(time_limit_s=None),
                               robot=SimpleNamespace(v_min_mps=0.5),
                               battery=SimpleNamespace(usable_J=1.0))
    with pytest.raises(InputError, match="time_limit_s"):
        mission_horizon_s(scenario, model, 0.02, Conditions(1.0))


def test_the_simplified_range_charges_a_rising_drift_at_the_horizon(limited):
    """Eq. 6's energy per metre with a rising line: the drift's value at the time limit
    (10 W) over the metre's mission time, 1 / (v D) s."""
    from orange_plan.physics.range import simplified_range

    crr = limited.world.default_crr
    rising = _with_drift(limited, drift_term("linear", 1000.0), 5.0)
    base = simplified_range(limited.scenario, limited.model, crr)
    v = base.v_opt_mps
    drifted = simplified_range(rising.scenario, rising.model, crr)
    from orange_plan.physics.range import flat_energy_per_m_J

    duty = limited.scenario.mission.duty_cycle
    extra = (flat_energy_per_m_J(rising.model, v, crr, 0.0, duty, rising.conditions.elapsed_s)
             - flat_energy_per_m_J(limited.model, v, crr, 0.0, duty))
    assert float(extra) == pytest.approx(10.0 / (v * duty))
    assert drifted.energy_per_m_J > base.energy_per_m_J
