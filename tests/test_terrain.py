"""World: the map with the scenario's environment; vectorised terrain queries."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import base_features, feature, write_scenario

from orange_plan.context import load_context
from orange_plan.errors import InputError, ScenarioError
from orange_plan.scenario import load_scenario
from orange_plan.world.terrain import World


def world_from(tmp_path, **kw) -> World:
    return World.from_scenario(load_scenario(write_scenario(tmp_path, **kw)))


def test_world_from_scenario(tmp_path):
    w = world_from(tmp_path, set={"environment.wind_speed_mps": 3.0,
                                  "environment.wind_from_deg": 90.0})
    assert w.home_xy_m == (2.0, 5.0)
    assert w.default_crr == 0.05 and w.default_surface_name == "default"  # robot.crr


def test_the_wind_is_held_by_the_conditions_not_the_world(tmp_path):
    """One runtime holder of the wind: the context's conditions carry the scenario's wind
    and the world carries none (a second copy could disagree with a measured wind)."""
    path = write_scenario(tmp_path, set={"environment.wind_speed_mps": 3.0,
                                         "environment.wind_from_deg": 90.0})
    ctx = load_context(path)
    np.testing.assert_allclose(ctx.conditions.wind_xy_mps, (-3.0, 0.0), atol=1e-12)
    assert not hasattr(ctx.world, "wind_xy_mps")


def test_default_surface_wins_over_robot_crr(tmp_path):
    w = world_from(tmp_path, default_surface={"name": "asphalt", "crr": 0.015})
    assert (w.default_crr, w.default_surface_name) == (0.015, "asphalt")


def test_crr_and_surface_code_later_surface_wins(tmp_path):
    feats = [*base_features(),
             feature("surface", "Polygon", [[[15, 0], [20, 0], [20, 10], [15, 10], [15, 0]]],
                     name="tile", crr=0.02),
             feature("surface", "Polygon", [[[18, 0], [20, 0], [20, 2], [18, 0]]],
                     name="grass", crr=0.2)]
    w = world_from(tmp_path, map_features=feats)
    x = np.array([1.0, 12.0, 17.0, 19.5])
    y = np.array([1.0, 5.0, 5.0, 0.5])
    # default 0.05; grass 0.1; tile over grass 0.02; the second grass patch over tile 0.2
    np.testing.assert_allclose(w.crr_at(x, y), [0.05, 0.1, 0.02, 0.2])
    np.testing.assert_array_equal(w.surface_code_at(x, y), [-1, 0, 1, 0])
    assert w.map.surface_names == ("grass", "tile")
    assert w.crr_at(x[:, None], y).shape == (4, 4)
    assert w.elevation_at(x, y).shape == (4,) and not w.elevation_at(x, y).any()


def test_free_space_queries(tmp_path):
    w = world_from(tmp_path)
    np.testing.assert_array_equal(w.is_free([2.0, 5.0, 25.0], [5.0, 8.0, 5.0]),
                                  [True, False, False])  # home, in the box, outside
    np.testing.assert_array_equal(
        w.segments_free([[1.0, 8.0], [1.0, 1.0], [1.0, 1.0]], [[9.0, 8.0], [9.0, 1.0], [25.0, 1.0]]),
        [False, True, False])  # through the box, clear, leaving the boundary
    with pytest.raises(InputError, match=r"goal 1 at \(5, 8\) m is inside an obstacle or no-go zone"):
        w.check_points([[2.0, 5.0], [5.0, 8.0]], what="goal")


def test_scenario_home_override(tmp_path):
    w = world_from(tmp_path, set={"mission.home_xy_m": [15.0, 2.0]})
    assert w.home_xy_m == (15.0, 2.0)
    with pytest.raises(ScenarioError, match=r"home at \(5, 8\) m is inside an obstacle or no-go zone"):
        world_from(tmp_path, set={"mission.home_xy_m": [5.0, 8.0]})


def test_no_home_anywhere(tmp_path):
    with pytest.raises(ScenarioError, match=r"no home: set mission\.home_xy_m"):
        world_from(tmp_path, map_features=base_features()[:3])
