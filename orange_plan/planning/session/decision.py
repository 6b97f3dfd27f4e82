"""The homing decision of a mission session: a pure function of the session's figures.

``decide`` reads a ``HomingState`` (what the telemetry, the return home and the plan's
checks say now) and returns a ``Decision``; it does no I/O, changes nothing and computes no
path: everything it weighs is in the state, so a decision can be checked by hand from it.
The rule is in ``planning.session``'s docstring.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

FLAGS = ("position_in_obstacle", "off_map_position")
"""Actions that say the robot is not where the map says it can be: no energy figure that
depends on the position is given, nothing is advised but to check the localisation."""
ACTIONS = ("continue", "replan", "return_home", *FLAGS)
DEPARTURE_Z = 3.0
"""Predictive standard deviations of the energy per metre beyond which the measured rate is
said to depart from the plan's model (three: a false alarm about once in 370 windows)."""


@dataclass(frozen=True)
class Decision:
    """What the robot should do now, and the figures it rests on.

    Attributes
    ----------
    action : "continue", "replan", "return_home", or a flag that the reported position is
        not where the map allows the robot to be: "position_in_obstacle" (inside an obstacle
        or no-go zone, within the robot's size) or "off_map_position" (outside the boundary,
        yet too near it to be refused as another frame)
    reason : one sentence a person can check against the figures
    position_xy_m : last reported position [m]
    energy_used_J : measured battery energy so far [J] (never below 0: regeneration refills
        the battery at most to full)
    time_s : mission time of the last sample [s]
    energy_to_home_J : energy of the return home from the position, online model [J]
        (NaN under a flag: the position is not one a return can start from)
    reserve_J : reserve kept for that return (the scenario's rule) [J] (NaN under a flag)
    homing_margin_J : energy_available - energy_used - energy_to_home - reserve [J]
        (NaN under a flag)
    return_probability : probability that the energy left covers the return [-]
        (NaN under a flag)
    remaining_range_m : (energy left - reserve) / online energy per metre [m]
        (NaN under a flag)
    covered_m2 : area sensed so far (sensor footprint along the trail) [m^2]
    energy_available_J : usable battery energy the decision counts on [J]: the scenario's,
        or less when the telemetry's ``soc`` shows a smaller battery (``capacity_from_soc``)
    """

    action: str
    reason: str
    position_xy_m: tuple[float, float]
    energy_used_J: float
    time_s: float
    energy_to_home_J: float
    reserve_J: float
    homing_margin_J: float
    return_probability: float
    remaining_range_m: float
    covered_m2: float
    energy_available_J: float = math.nan

    def to_dict(self) -> dict:
        d = asdict(self)
        d["position_xy_m"] = list(self.position_xy_m)
        return d


@dataclass(frozen=True)
class Home:
    """The return home from the current position.

    Attributes
    ----------
    energy_J : its energy with the online model [J] (inf: no way home found)
    reserve_J : the reserve the scenario's rule keeps for it [J]
    sd_J : predictive standard deviation of ``energy_J`` [J]
    """

    energy_J: float
    reserve_J: float
    sd_J: float


@dataclass(frozen=True)
class HomingState:
    """Everything a decision weighs.

    Attributes
    ----------
    position_xy_m, time_s, energy_used_J, energy_available_J, covered_m2 : as ``Decision``
    position_where : "free" (in the map's free space), "in_obstacle" or "off_map"
    reserve : the scenario's reserve rule (``planning.reserve.reserve_from``)
    home : the return home from the position; None when the position is not free
    energy_per_m_J : online energy per metre of the recent motion [J/m]
    map_changed : the map changed since the plan was made
    departure : (measured, plan-model predicted, predictive sd) energy per metre over the
        estimator's window [J/m], or None while it cannot say
    tour_margin_J : smallest homing margin over the rest of the tour, online model [J]
    replan_margin_J : the margin the rest of the tour must keep [J]
    lookahead_J : what the robot needs, beyond the way home and its reserve now, before
        the next decision can reach it (the most any point of the next stretch needs: the
        stretch so far, the way home from there and the reserve for both; at the route's
        end the last batch's energy) [J]: the return is decided while the margin still
        covers it
    """

    position_xy_m: tuple[float, float]
    time_s: float
    energy_used_J: float
    energy_available_J: float
    covered_m2: float
    position_where: str
    reserve: object
    home: Home | None
    energy_per_m_J: float
    map_changed: bool
    departure: tuple[float, float, float] | None
    tour_margin_J: float
    replan_margin_J: float
    lookahead_J: float = 0.0


def decide(state: HomingState) -> Decision:
    """The decision for ``state`` (``planning.session``: decision rule)."""
    used, avail, home = state.energy_used_J, state.energy_available_J, state.home
    common = dict(position_xy_m=state.position_xy_m, energy_used_J=used, time_s=state.time_s,
                  covered_m2=state.covered_m2, energy_available_J=avail)
    if home is None:
        return _flagged(state, common)
    ahead = state.lookahead_J
    margin = avail - used - home.energy_J - home.reserve_J
    res_rule = state.reserve
    prob = float(res_rule.return_probability(avail - used - home.energy_J, home.sd_J))
    left = max(avail - used - home.reserve_J, 0.0)
    per_m = state.energy_per_m_J
    figures = dict(
        common, energy_to_home_J=home.energy_J, reserve_J=home.reserve_J,
        homing_margin_J=margin, return_probability=prob,
        remaining_range_m=left / per_m if per_m > 0 else math.inf)
    if not math.isfinite(home.energy_J):
        return Decision("return_home", "no way home was found from the current position; "
                        "head home by the last known way", **figures)
    if margin - ahead < 0:  # the next decision comes a batch later: turn before it is late
        return Decision("return_home", f"the homing margin is {margin:,.0f} J, less than the "
                        f"{ahead:,.0f} J drawn until the next decision: "
                        f"{used:,.0f} J used + {ahead:,.0f} J until the next decision + "
                        f"{home.energy_J:,.0f} J to home + {home.reserve_J:,.0f} J reserve "
                        f"exceed {avail:,.0f} J available", **figures)
    if res_rule.falls_short(prob):
        return Decision("return_home", f"the probability of getting home is {prob:.4f}, "
                        f"below the reserve's confidence {res_rule.value:g}", **figures)
    reason = _replan_reason(state)
    if reason is not None:
        return Decision("replan", reason, **figures)
    return Decision("continue", f"home is {home.energy_J:,.0f} J away with "
                    f"{margin:,.0f} J to spare after the {home.reserve_J:,.0f} J reserve, "
                    "and the plan still fits the measured energy", **figures)


def _flagged(state: HomingState, common: dict) -> Decision:
    """The robot reports a position the map does not allow: no energy figure from it."""
    x, y = state.position_xy_m
    if state.position_where == "off_map":
        action, where = "off_map_position", "outside the map's boundary"
    else:
        action, where = ("position_in_obstacle", "inside an obstacle or no-go zone (within "
                         "the robot's size)")
    unknown = dict(energy_to_home_J=math.nan, reserve_J=math.nan, homing_margin_J=math.nan,
                   return_probability=math.nan, remaining_range_m=math.nan)
    return Decision(action, f"the reported position ({x:g}, {y:g}) m lies {where}: the robot "
                    "is not where the map says it can be; check its localisation and the map "
                    "before trusting any energy to home", **common, **unknown)


def _replan_reason(state: HomingState) -> str | None:
    if state.map_changed:
        return "the map changed since the plan was made"
    if state.departure is not None:
        measured, predicted, sd = state.departure
        if abs(measured - predicted) > DEPARTURE_Z * sd:
            return (f"the measured energy per metre {measured:.2f} J/m departs from the "
                    f"plan's {predicted:.2f} J/m by more than {DEPARTURE_Z:g} x "
                    f"{sd:.2f} J/m (the online predictive spread)")
    worst = state.tour_margin_J
    if worst < state.replan_margin_J:
        return (f"the rest of the tour, re-evaluated with the online model, leaves a "
                f"homing margin of {worst:,.0f} J < {state.replan_margin_J:,.0f} J")
    return None
