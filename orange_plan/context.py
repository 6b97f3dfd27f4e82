"""Everything a command needs about one scenario, loaded and validated once."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from orange_plan.errors import OrangeError
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.horizon import planning_elapsed_s
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.model_builder import build_model
from orange_plan.scenario import Scenario, load_scenario
from orange_plan.world.terrain import World


@dataclass(frozen=True)
class Context:
    """A scenario with its world, energy model and operating conditions."""

    scenario: Scenario
    world: World
    model: EnergyModel
    # The one source of duty cycle, sensor rate and wind for planning and simulation:
    # ``Conditions.of(scenario)`` unless given (a session's measured wind, an oracle's truth).
    conditions: Conditions | None = None

    def __post_init__(self):
        if self.conditions is None:
            object.__setattr__(self, "conditions", Conditions.of(self.scenario))
        else:
            self._check_conditions()
        # Recomputed on every build (``replace`` included): a drift's worst time belongs to
        # this model, not to the one the conditions were first made for.
        object.__setattr__(self, "conditions", self.conditions.with_elapsed(planning_elapsed_s(
            self.scenario, self.model, self.world.default_crr, self.conditions)))

    def _check_conditions(self) -> None:
        # Only the wind may be measured rather than set: a duty cycle or sensor rate that
        # differs from the scenario's is a stale copy (replace(ctx, scenario=...) keeps the
        # old conditions; use with_scenario).
        sc = self.scenario
        if (self.conditions.duty_cycle, self.conditions.sensor_rate_Hz) != (
                sc.mission.duty_cycle, sc.ancillary.sensor_rate_Hz):
            raise OrangeError(f"{sc.name}: conditions {self.conditions} disagree with the "
                              "scenario's duty cycle or sensor rate (use Context.with_scenario)")

    def with_scenario(self, scenario: Scenario) -> Context:
        """The same world and model under another scenario, its conditions rebuilt from it."""
        return replace(self, scenario=scenario, conditions=None)

    @property
    def cruise_speed_mps(self) -> float:
        """Default speed of planning and simulation: the simplified range's v_opt [m/s]."""
        from orange_plan.physics.range import simplified_range

        return simplified_range(self.scenario, self.model, self.world.default_crr).v_opt_mps


def load_context(scenario_path: str | Path) -> Context:
    """Load a scenario, its map (and raster) and build its EnergyModel.

    Raises
    ------
    InputError
        For any problem in the scenario, the map or the raster (one line, names the problem).
    """
    return context_of(load_scenario(scenario_path))


def context_of(scenario: Scenario) -> Context:
    """A validated scenario with its world (map, raster) and EnergyModel.

    Raises
    ------
    InputError
        For any problem in the map or the raster.
    """
    world = World.from_scenario(scenario)
    model = build_model(scenario, world.map.surface_names)
    return Context(scenario, world, model)
