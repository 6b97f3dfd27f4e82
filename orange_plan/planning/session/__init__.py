"""Mid-mission replanning: telemetry in, a decision out, and a new tour when the world or the
robot turns out different from the plan.

Problem statement (kept apart from how it is solved): during a mission the robot reports
samples (time, battery power, position, ...). After each batch the operator needs to know
whether the robot should

- ``return_home`` now: with what it has measured so far, the way home and its reserve no
  longer fit the energy left, or getting home is less likely than the reserve promises;
- ``replan``: the robot can still get home, but the plan it flies was made for another
  robot or another map (the energy it measures departs from the plan's model, a map update
  arrived, or the rest of the tour no longer keeps the homing constraint);
- ``continue`` otherwise;

and, on a replan, a new tour from the current position, energy, time and area already
sensed, made with the model the telemetry has taught (a head wind or a heavier load
shrinks it, a lighter one may extend it), in the world with every map update.

Decision rule (``MissionSession.decision``, the pure ``decision.decide``), in this order,
with ``E_avail`` the usable battery energy (the scenario's, or less when the telemetry's
state of charge shows a smaller battery: ``identify.soc``), ``E_used`` the measured battery energy so far (sum of ``P dt``;
a negative power is regeneration, refilling the battery at most to full: ``E_used >= 0``),
``E_home`` the energy of the best roadmap return from the current position evaluated with
the online model, ``R`` the scenario's reserve for that return and ``sd_home`` its predictive
standard deviation:

0. ``position_in_obstacle`` or ``off_map_position`` (flags) when the reported position is
   not in the map's free space (``World.is_free``, with the robot's size): the robot is not
   where the map says it can be, so no energy figure that depends on the position is given
   (and the batch's motion teaches the estimator nothing: ``intake.Intake.take``).
   A position far off the map (``world.positions.check_on_map``, the rule predict,
   calibrate and diagnose apply to recordings) is refused with the batch (InputError).
1. ``return_home`` when ``margin = E_avail - E_used - E_home - R < 0``, or the reserve is a
   confidence ``p`` and ``P(home) = Phi((E_avail - E_used - E_home) / sd_home) < p``.
2. ``replan`` when the map changed since the plan was made; or the energy per metre measured
   over the estimator's window departs from the plan model's prediction for the same motion
   by more than ``DEPARTURE_Z`` predictive standard deviations of the online estimator
   (``energy_per_m_sd_J``); or the rest of the tour, re-evaluated with the online model,
   has a vertex where ``E_used + E(here -> v) + E_home(v) + R(v) > E_avail - replan_margin_J``.
3. ``continue`` otherwise.

``remaining_range_m = max(0, E_avail - E_used - R) / e``, with ``e`` the online energy per
metre over the recent motion (the plan model's flat-ground figure before any motion).

How it is solved: ``identify.online.OnlineEstimator`` updates the model's coefficients and
covariance from every batch (recursive least squares with forgetting) and measures the energy
used; the return home is the cheapest roadmap way home (``planning.reach.way_home``) driven
from rest to rest and re-evaluated exactly (``planning.tour.drive``, the same evaluation as
the tour's returns) with the online coefficients, and its variance is ``g' Cov g`` (online
covariance) plus the estimator's spread of the energy per metre in quadrature; a replan is
``planning.tour.plan_tour`` from a ``StartState`` with the online model and the updated world.

Why the answer is safe: ``continue`` and ``replan`` are only said when the current position
has a return home whose exact energy with the model the data supports, plus the reserve,
fits what is left; a new tour is only returned by ``plan_tour``, which keeps the homing
constraint at every vertex with that model. Replay is deterministic: the same events (sample
batches, map updates, adopted plans) in the same order rebuild the same session
(``state_dict`` / ``from_state``; replans are stored, not recomputed).

Modules: ``intake`` (a batch checked and taken in: energy, estimator, trail, covered area),
``decision`` (the decision as a pure function of the figures), ``events`` (the event log a
session is rebuilt from) and ``facade`` (``MissionSession``, which joins them). A map
update raises the map's ``version``; what was computed for a map (the return-home roadmap,
the planner's setup, "the map changed since the plan") is keyed by that version.
"""

from orange_plan.planning.plan import plan_from_geojson
from orange_plan.planning.session.decision import ACTIONS, DEPARTURE_Z, FLAGS, Decision
from orange_plan.planning.session.events import STATE_VERSION
from orange_plan.planning.session.facade import MissionSession
from orange_plan.planning.session.intake import CONTEXT_ROWS

__all__ = ["ACTIONS", "CONTEXT_ROWS", "DEPARTURE_Z", "FLAGS", "STATE_VERSION", "Decision",
           "MissionSession", "plan_from_geojson"]
