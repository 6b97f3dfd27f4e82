"""Operational range: simplified ORangE (Eq. 6) and generalised offline ORangE (Eq. 11)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from orange_plan.errors import InputError
from orange_plan.mission import check_time_limit
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.horizon import planning_elapsed_s
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.pathcost import heading_changes_rad, segments_energy, subdivide
from orange_plan.physics.state import MotionState


@dataclass(frozen=True)
class EnergyBreakdown:
    """Where the battery's energy goes over a full-range mission [J].

    ``available_J = ancillary_J + traversal_J``; the loss entries say how much of those
    (or, for eta_1, of the decayed capacity) each loss group takes.
    """

    rated_J: float
    capacity_J: float
    decay_J: float
    available_J: float
    ancillary_J: float
    traversal_J: float
    mechanical_work_J: float
    battery_loss_eta1_J: float
    motor_loss_eta2_J: float
    mechanical_loss_eta3_J: float
    ancillary_loss_eta4_J: float


@dataclass(frozen=True)
class RangeResult:
    """Operational range at the best speed.

    Attributes
    ----------
    d_max_m : maximum distance on one discharge [m]
    v_opt_mps : speed in [v_min, v_max] that maximises it [m/s]
    energy_per_m_J : battery energy per metre at v_opt [J/m]
    mission_time_s : mission time to cover d_max, stops included [s]
    method : "simplified (Eq. 6)" or "generalised offline (Eq. 11)"
    within_time_limit : the mission time keeps ``mission.time_limit_s`` (``check_time_limit``)
    reason : why not (None when within)
    time_limited : when not within, the range the time limit allows (the best speed for
        ``min(E_avail / e(v), T v D)``); else None
    """

    d_max_m: float
    v_opt_mps: float
    energy_per_m_J: float
    mission_time_s: float
    method: str
    within_time_limit: bool = True
    reason: str | None = None
    time_limited: RangeResult | None = None

    def to_dict(self) -> dict:
        return asdict(self)


def best_speed(cost_per_m, v_min_mps: float, v_max_mps: float, xatol: float = 1e-6) -> float:
    """Speed in [v_min, v_max] minimising a per-metre energy cost (or any unimodal function
    of speed) [m/s].

    Golden-section search down to ``xatol``, then the better of its result and the two ends
    (the cost is unimodal in v for the reference model; the ends catch a monotone cost).
    Pure Python on purpose: importing scipy.optimize for this costs half a second of start-up.
    """
    if v_min_mps == v_max_mps:
        return float(v_min_mps)
    inv_phi = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = float(v_min_mps), float(v_max_mps)
    c, d = b - inv_phi * (b - a), a + inv_phi * (b - a)
    fc, fd = cost_per_m(c), cost_per_m(d)
    while b - a > xatol:
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - inv_phi * (b - a)
            fc = cost_per_m(c)
        else:
            a, c, fc = c, d, fd
            d = a + inv_phi * (b - a)
            fd = cost_per_m(d)
    middle = c if fc <= fd else d
    return float(min([v_min_mps, v_max_mps, middle], key=cost_per_m))


def flat_state(speed_mps, crr: float, sensor_rate_Hz: float,
               elapsed_s: float = 0.0) -> MotionState:
    """Level, windless, straight motion on ground of rolling coefficient ``crr``, a drift
    charged at mission time ``elapsed_s`` [s] (planning's: ``Conditions.elapsed_s``)."""
    return MotionState(speed_mps=speed_mps, crr=crr, sensor_rate_Hz=sensor_rate_Hz,
                       channels={"elapsed_s": elapsed_s})


def flat_energy_per_m_J(model: EnergyModel, speed_mps, crr: float, sensor_rate_Hz: float,
                        duty_cycle: float, elapsed_s: float = 0.0):
    """Battery energy per metre on level, windless ground of rolling coefficient ``crr``
    (Eq. 6's denominator), a drift charged at ``elapsed_s`` [J/m]; ``speed_mps`` of any
    shape."""
    state = flat_state(speed_mps, crr, sensor_rate_Hz, elapsed_s)
    return model.segment_energy(state, 1.0, duty_cycle).total_J


def farthest_speed_mps(cost_per_m, energy_J: float, time_s: float, duty_cycle: float,
                       v_min_mps: float, v_max_mps: float) -> float:
    """Speed maximising the distance ``min(energy_J / e(v), time_s v D)`` on [v_min, v_max]
    (energy or time runs out first) [m/s]; ``cost_per_m`` is e(v) [J/m]."""
    return best_speed(lambda v: -min(energy_J / cost_per_m(v), time_s * v * duty_cycle),
                      v_min_mps, v_max_mps)


def within_time_limit(result: RangeResult, cost_per_m, scenario,
                      time_limit_s: float | None) -> RangeResult:
    """``result`` checked against ``time_limit_s`` (``mission.check_time_limit``); when its
    mission time exceeds the limit, with the reason and the range the limit allows.

    Notes
    -----
    Under a limit T the distance at speed v is ``min(E_avail / e(v), T v D)`` (energy or time
    runs out first); it is maximised over ``[v_min, v_max]``: a faster speed than the energy
    optimum, up to where both run out together, or v_max.
    """
    check = check_time_limit(result.mission_time_s, time_limit_s)
    if check.within:
        return result
    energy, duty = scenario.battery.usable_J, scenario.mission.duty_cycle

    v = farthest_speed_mps(cost_per_m, energy, time_limit_s, duty, scenario.robot.v_min_mps,
                           scenario.robot.v_max_mps)
    d = min(energy / cost_per_m(v), time_limit_s * v * duty)
    limited = RangeResult(d, v, cost_per_m(v), d / (v * duty), f"{result.method} within "
                          f"mission.time_limit_s")
    return replace(result, within_time_limit=False, reason=check.reason, time_limited=limited)


def simplified_range(scenario, model: EnergyModel, crr: float,
                     time_limit_s: float | None = None) -> RangeResult:
    """Simplified ORangE on flat ground (the paper's Eq. 6).

    ``d_max = E_avail / (P_anc / (v D) + (crr m g + c v^2) / Omega)`` at the speed ``v_opt``
    in ``[v_min, v_max]`` that maximises it; with ``time_limit_s`` [s], see
    ``within_time_limit``.
    """
    duty = scenario.mission.duty_cycle
    rate = scenario.ancillary.sensor_rate_Hz
    # a drift at its worst over the mission's horizon, as planning charges it
    elapsed = planning_elapsed_s(scenario, model, crr, Conditions.of(scenario))

    def cost_per_m(v):
        return float(flat_energy_per_m_J(model, v, crr, rate, duty, elapsed))

    v = best_speed(cost_per_m, scenario.robot.v_min_mps, scenario.robot.v_max_mps)
    cost = cost_per_m(v)
    if cost <= 0:
        raise InputError("the model gives no energy cost per metre; range is unbounded")
    d = scenario.battery.usable_J / cost
    result = RangeResult(d, v, cost, d / (v * duty), "simplified (Eq. 6)")
    return within_time_limit(result, cost_per_m, scenario, time_limit_s)


def breakdown(scenario, model: EnergyModel, result: RangeResult, crr: float) -> EnergyBreakdown:
    """Split the available energy of a full-range flat mission into its consumers and losses."""
    bat, losses = scenario.battery, scenario.losses
    duty, rate = scenario.mission.duty_cycle, scenario.ancillary.sensor_rate_Hz
    elapsed = planning_elapsed_s(scenario, model, crr, Conditions.of(scenario))
    state = flat_state(result.v_opt_mps, crr, rate, elapsed)
    seg = model.segment_energy(state, result.d_max_m, duty)
    ancillary_J, traversal_J = float(seg.ancillary_J), float(seg.traversal_J + seg.turning_J)
    # The model's hover coefficient (a [model] table or calibration may have replaced the
    # scenario's hover_W); hover power is battery side, so eta_4 takes nothing of it.
    hover_W = model.coefficient("hover_W") if model.has("hover") else 0.0
    hover_J = hover_W * float(seg.mission_time_s)
    return EnergyBreakdown(
        rated_J=bat.rated_energy_J,
        capacity_J=bat.capacity_J,
        decay_J=bat.rated_energy_J - bat.capacity_J,
        available_J=bat.usable_J,
        ancillary_J=ancillary_J,
        traversal_J=traversal_J,
        mechanical_work_J=traversal_J * losses.omega,
        battery_loss_eta1_J=bat.storage_loss_J,
        motor_loss_eta2_J=traversal_J * losses.motor,
        mechanical_loss_eta3_J=traversal_J * (1 - losses.motor) * losses.mechanical,
        ancillary_loss_eta4_J=(ancillary_J - hover_J) * losses.ancillary,
    )


def radial_probe_paths(world, n_headings: int = 16) -> list[np.ndarray]:
    """A priori mission sample: out-and-back straight rays from home in evenly spread headings.

    Each ray runs to the boundary or the first keep-out zone (whatever the map allows), so
    grades, surfaces and wind in every direction enter the estimate (Eq. 11's path integral).
    """
    from shapely.geometry import LineString, Point

    hx, hy = world.home_xy_m
    free = world.map.free_space
    reach = np.hypot(*np.subtract(world.map.boundary.bounds[2:], world.map.boundary.bounds[:2]))
    paths = []
    for ang in np.linspace(0, 2 * np.pi, n_headings, endpoint=False):
        ray = LineString([(hx, hy), (hx + reach * np.cos(ang), hy + reach * np.sin(ang))])
        part = ray.intersection(free)
        pieces = getattr(part, "geoms", [part])
        home = Point(hx, hy)
        first = next((g for g in pieces if g.geom_type == "LineString" and g.distance(home) < 1e-6),
                     None)
        if first is None or first.length < 1e-3:
            continue
        end = np.array(first.coords[-1])
        # Stop just short of the obstacle edge; the probe only samples terrain.
        end = np.array([hx, hy]) + (end - [hx, hy]) * max(0.0, 1 - 1e-6)
        paths.append(np.array([[hx, hy], end, [hx, hy]]))
    return paths


def generalised_range(scenario, model: EnergyModel, world, paths=None,
                      time_limit_s: float | None = None) -> RangeResult:
    """Generalised offline ORangE (Eq. 11): the path integral approximated a priori.

    The position-, speed- and wind-dependent forces are averaged over ``paths`` (default:
    ``radial_probe_paths``), giving an energy per metre ``e(v)``; ``d = E_avail / e(v)`` at
    the speed that maximises it.

    Parameters
    ----------
    paths : polylines (k, 2) in the map frame standing for the mission a priori
    time_limit_s : mission time limit [s] (None: none); see ``within_time_limit``
    """
    paths = radial_probe_paths(world) if paths is None else paths
    if not paths:
        raise InputError("no a priori path: home has no free straight line out")
    conditions = Conditions.of(scenario)  # a drift at its worst over the horizon, as planning
    conditions = conditions.with_elapsed(planning_elapsed_s(scenario, model, world.default_crr,
                                                            conditions))
    starts = np.concatenate([p[:-1] for p in paths])
    ends = np.concatenate([p[1:] for p in paths])
    steps = subdivide(world, starts, ends)  # terrain sampled once, re-costed per speed
    turns = np.concatenate([heading_changes_rad(p) for p in paths if len(p) > 2] or [[]])
    turning_J = float(np.sum(model.turning_energy_J(turns))) if turns.size else 0.0
    lengths = float(np.sum(np.hypot(*(ends - starts).T)))

    def cost_per_m(v):
        e = segments_energy(model, world, None, None, v, conditions, steps=steps)
        return (float(np.sum(e.ancillary_J + e.traversal_J)) + turning_J) / lengths

    v = best_speed(cost_per_m, scenario.robot.v_min_mps, scenario.robot.v_max_mps)
    cost = cost_per_m(v)
    if not cost > 0:  # nothing drawn per metre (no ancillary power, downhill with regen)
        raise InputError(f"the a-priori energy per metre is {cost:.3g} J/m (not positive): "
                         "the range is unbounded; check the ancillary power and regen")
    d = scenario.battery.usable_J / cost
    result = RangeResult(d, v, cost, d / (v * conditions.duty_cycle),
                         "generalised offline (Eq. 11)")
    return within_time_limit(result, cost_per_m, scenario, time_limit_s)
