"""Everything a command needs about one scenario, loaded and validated once."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from orange_plan.model_builder import build_model
from orange_plan.physics.model import EnergyModel
from orange_plan.scenario import Scenario, load_scenario
from orange_plan.world.terrain import World


@dataclass(frozen=True)
class Context:
    """A scenario with its world and energy model."""

    scenario: Scenario
    world: World
    model: EnergyModel

    @property
    def sensor_rate_Hz(self) -> float:
        return self.scenario.ancillary.sensor_rate_Hz

    @property
    def duty_cycle(self) -> float:
        return self.scenario.mission.duty_cycle

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
