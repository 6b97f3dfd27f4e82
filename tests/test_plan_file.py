"""The one reader of plan files (planning.plan.plan_from_geojson / read_tour): what
``Plan.to_geojson`` writes reads back the same, and what the session, the simulator and the
service load generator are handed is checked the same way."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import box

from orange_plan.errors import InputError
from orange_plan.planning.plan import Plan, plan_from_geojson, read_tour


def _plan() -> Plan:
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 5.0], [0.0, 0.0]])
    n = len(xy)
    return Plan(xy, np.arange(n, dtype=float), np.full(n, 1.5), np.linspace(0, 30, n),
                np.full(n, 5.0), np.full(n, 2.0), np.full(n, 10.0), np.array([[10.0, 0.0]]),
                box(0, 0, 10, 5), {"coverage_m2": 50.0},
                np.array([[10.0, 5.0], [20.0, 5.0], [0.0, 0.0]]))


def test_a_written_plan_reads_back_the_same():
    plan = _plan()
    back = plan_from_geojson(plan.to_geojson())
    for key in ("xy_m", "t_s", "speed_mps", "energy_used_J", "energy_to_home_J", "reserve_J",
                "margin_J", "waypoints_xy_m", "continuation_xy_m"):
        assert np.allclose(getattr(back, key), getattr(plan, key)), key
    assert back.covered.equals(plan.covered) and back.summary == plan.summary


def test_the_tour_alone_reads_three_d_coordinates_and_absent_arrays_as_none():
    data = _plan().to_geojson()
    tour = data["features"][0]
    tour["geometry"]["coordinates"] = [[*c, 7.0] for c in tour["geometry"]["coordinates"]]
    del tour["properties"]["t_s"]
    xy, arrays = read_tour(data)
    assert xy.shape == (4, 2) and arrays["t_s"] is None
    assert np.allclose(arrays["speed_mps"], 1.5)
    assert np.allclose(plan_from_geojson(data).t_s, 0.0)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d.update(features=[]), "f.geojson: no feature with kind = 'tour'"),
    (lambda d: d["features"][0]["geometry"].update(type="Point"), "must be a LineString"),
    (lambda d: d["features"][0]["geometry"].update(coordinates=[["a", 1]]), "must be numbers"),
    (lambda d: d["features"][0]["properties"].update(margin_J=[1.0]),
     "tour margin_J has 1 values for 4 vertices"),
    (lambda d: d["features"][0]["properties"].update(speed_mps=["fast"] * 4),
     "tour speed_mps must be numbers"),
])
def test_a_bad_plan_file_is_refused_naming_the_file(edit, message):
    data = _plan().to_geojson()
    edit(data)
    with pytest.raises(InputError, match=message):
        plan_from_geojson(data, "f.geojson")
