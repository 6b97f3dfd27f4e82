"""What ``orange-plan range`` prints: the simplified and generalised ORangE ranges of a
scenario's Context and the energy breakdown (an assembly of ``physics.range`` pieces for
one command, so it lives above physics, beside ``context``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from orange_plan.physics.range import (
    EnergyBreakdown,
    RangeResult,
    breakdown,
    flat_state,
    generalised_range,
    simplified_range,
)


@dataclass(frozen=True)
class RangeReport:
    """What ``orange-plan range`` prints: both estimators and the energy breakdown."""

    scenario: str
    robot_kind: str
    crr: float
    omega: float
    ancillary_power_W: float
    simplified: RangeResult
    generalised: RangeResult
    energy: EnergyBreakdown
    time_limit_s: float | None = None

    def to_dict(self) -> dict:
        return {
            "scenario": self.scenario,
            "robot_kind": self.robot_kind,
            "d_max_m": self.simplified.d_max_m,
            "v_opt_mps": self.simplified.v_opt_mps,
            "energy_per_m_J": self.simplified.energy_per_m_J,
            "mission_time_s": self.simplified.mission_time_s,
            "time_limit_s": self.time_limit_s,
            "within_time_limit": self.simplified.within_time_limit,
            "reason": self.simplified.reason,
            "time_limited": (None if self.simplified.time_limited is None
                             else self.simplified.time_limited.to_dict()),
            "crr": self.crr,
            "omega": self.omega,
            "ancillary_power_W": self.ancillary_power_W,
            "energy": asdict(self.energy),
            "generalised": self.generalised.to_dict(),
        }


def range_report(ctx) -> RangeReport:
    """Simplified range on flat default ground, its energy breakdown, and the generalised
    offline range over the map (with wind, grades and surfaces); both within the scenario's
    mission time limit."""
    scenario, model = ctx.scenario, ctx.model
    crr = ctx.world.default_crr
    limit = scenario.mission.time_limit_s
    simple = simplified_range(scenario, model, crr, limit)
    return RangeReport(
        scenario=scenario.name,
        robot_kind=scenario.robot.kind,
        crr=crr,
        omega=scenario.omega,
        ancillary_power_W=float(model.ancillary_power_W(
            flat_state(simple.v_opt_mps, crr, scenario.ancillary.sensor_rate_Hz))),
        simplified=simple,
        generalised=generalised_range(scenario, model, ctx.world, time_limit_s=limit),
        energy=breakdown(scenario, model, simple, crr),
        time_limit_s=limit,
    )
