"""Map changes are keyed by ``Map.version`` (0 as loaded, +1 per update), not by which
object holds the map: an equal map rebuilt (a restored context) keeps the planner's
roadmap, an update makes a planner and a session build theirs again."""

from __future__ import annotations

from dataclasses import replace

from conftest import REPO

from orange_plan.context import load_context
from orange_plan.planning.plan import StartState
from orange_plan.planning.session import MissionSession
from orange_plan.planning.tour import TourPlanner

SCENARIO = REPO / "scenarios" / "rusti_v1_box.toml"
BOX = [[6.2, 0.4], [6.8, 0.4], [6.8, 1.0], [6.2, 1.0], [6.2, 0.4]]


def test_planner_keys_its_setup_by_the_map_version():
    ctx = load_context(SCENARIO)
    planner = TourPlanner(ctx, n_vertices=200, bitstar_legs=0)
    planner.plan()
    setup = planner.setup
    same = replace(ctx.world, map=replace(ctx.world.map))  # another object, same version
    planner.plan(StartState(), world=same)
    assert planner.setup is setup
    newer = replace(ctx.world, map=replace(ctx.world.map, version=ctx.world.map.version + 1))
    planner.plan(StartState(), world=newer)
    assert planner.setup is not setup


def test_each_map_update_raises_the_version_and_asks_for_a_replan():
    ctx = load_context(SCENARIO)
    session = MissionSession(ctx, n_vertices=200, seed=0)
    assert session.map_version == 0 and ctx.world.map.version == 0
    session.decision()
    roadmap = session._home_reach
    d = session.update_map(obstacles=[BOX], replan=False)
    assert session.map_version == 1 and session.ctx.world.map.version == 1
    assert d.action == "replan" and "map changed" in d.reason
    assert session._home_reach is not roadmap and session._home_reach[0] == 1
    session.replan()
    assert "map changed" not in session.decision().reason
    session.update_map(no_go=[[[6.2, 5.0], [6.8, 5.0], [6.8, 5.5], [6.2, 5.0]]], replan=False)
    assert session.map_version == 2
    again = MissionSession.from_state(ctx, session.state_dict())
    assert again.map_version == 2
