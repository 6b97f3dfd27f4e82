"""Size limits (``orange_plan.limits``): a roadmap, a coverage lattice or a keep-out zone a
user asks for is checked before anything is allocated, and refused in one line (exit 2,
``InputError``) naming the setting and the limit; the command line and the Python API read
the same constants as the HTTP service (tests/test_service_limits.py)."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from conftest import REPO, base_features, feature, run_cli, write_map, write_scenario
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.errors import InputError, MapError
from orange_plan.limits import (
    MAX_COVERAGE_LATTICE_POINTS,
    MAX_ELEVATION_CELLS,
    MAX_ROADMAP_VERTICES,
)
from orange_plan.planning.coverage import check_sensor_radius, coverage_grid
from orange_plan.planning.reach import prepare_reach
from orange_plan.planning.tour import plan_tour
from orange_plan.world.geomap import keep_out_polygon, load_map

LAB = REPO / "scenarios" / "rusti_v1_box.toml"

TOO_MANY_VERTICES = st.integers(MAX_ROADMAP_VERTICES + 1, 10**12)
TOO_FEW_VERTICES = st.integers(-(10**12), 1)
# The lab (8 x 6 m) holds more than MAX_COVERAGE_LATTICE_POINTS viewpoints below
# r = sqrt(48 / (2.6 * 150e3)) = 11 mm, the yard (20 x 10 m) below 23 mm.
TINY_RADIUS_M = st.floats(5e-324, 0.01)


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("orange-plan: error: ") and "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def lab():
    return load_context(LAB)


# --- roadmap vertices: one limit for the CLI, the Python API and HTTP ----------------------
@pytest.mark.parametrize("vertices", [99_999_999, MAX_ROADMAP_VERTICES + 1, -5, 0, 1])
def test_cli_plan_refuses_vertices_beyond_the_limits(tmp_path, vertices):
    code, _, err = run_cli("plan", LAB, "-o", tmp_path / "p.geojson",
                           "--vertices", str(vertices))
    assert code == 2, err
    line = one_line(err)
    assert "--vertices" in line and f"{MAX_ROADMAP_VERTICES:,}" in line


def test_cli_reach_refuses_vertices_beyond_the_limit(tmp_path):
    goals = tmp_path / "goals.csv"
    goals.write_text("x_m,y_m\n4,3\n", encoding="utf-8")
    code, _, err = run_cli("reach", LAB, "--goals", goals, "--vertices", "99999999")
    assert code == 2 and f"{MAX_ROADMAP_VERTICES:,}" in one_line(err)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.one_of(TOO_MANY_VERTICES, TOO_FEW_VERTICES))
def test_python_api_refuses_vertices_beyond_the_limits(lab, n):
    for entry in (lambda: plan_tour(lab, n_vertices=n), lambda: prepare_reach(lab, n_vertices=n)):
        with pytest.raises(InputError, match=f"n_vertices.*{MAX_ROADMAP_VERTICES:,}"):
            entry()


def test_http_api_has_the_same_vertex_limit():
    pytest.importorskip("fastapi")
    from orange_plan.service.app import MissionCreate

    bound = next(m.le for m in MissionCreate.model_fields["n_vertices"].metadata
                 if hasattr(m, "le"))
    assert bound == MAX_ROADMAP_VERTICES


# --- the sensor radius against the map ----------------------------------------------------
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(r=TINY_RADIUS_M)
def test_a_radius_too_small_for_the_map_is_refused_before_any_allocation(lab, r):
    """Sized from the bounding box alone: 1e-9 m on the lab asked numpy for 22 GiB."""
    with pytest.raises(InputError, match=r"sensor_radius_m = .* too small for this map") as info:
        coverage_grid(lab.world, r)
    message = str(info.value)
    assert f"{MAX_COVERAGE_LATTICE_POINTS:,}" in message and "\n" not in message
    least = float(message.rsplit(">= ", 1)[1].split()[0])
    assert check_sensor_radius(lab.world, least) == least  # the radius it names is accepted


@pytest.mark.parametrize("r", [0.0, -1.0, math.nan, math.inf, "x", True])
def test_a_radius_that_is_no_length_is_refused(lab, r):
    with pytest.raises(InputError, match="sensor_radius_m"):
        check_sensor_radius(lab.world, r)


@pytest.mark.parametrize(("r", "why"), [
    (1e-9, f"{MAX_COVERAGE_LATTICE_POINTS:,}"), (0.001, f"{MAX_COVERAGE_LATTICE_POINTS:,}"),
    (0.02, f"{MAX_COVERAGE_LATTICE_POINTS:,}"), (1e200, "footprint"), (1e300, "footprint"),
    (math.nan, "finite"), (-1.0, "> 0")])
def test_cli_plan_refuses_a_sensor_radius_out_of_scale_at_once(tmp_path, r, why):
    """Tiny: over the lattice limit; huge: one footprint is larger than the free space
    (r**2 raised OverflowError, exit 1, for 1e200); not a length: the scenario's rule."""
    scenario = write_scenario(tmp_path, {"mission.sensor_radius_m": r})
    code, _, err = run_cli("plan", scenario, "-o", tmp_path / "p.geojson", "--vertices", "100")
    assert code == 2, err
    line = one_line(err)
    assert "sensor_radius_m" in line and why in line


# --- keep-out zones: one rule set for map files and map updates ---------------------------
NAN = math.nan
SQUARE = [[12, 2], [14, 2], [14, 4], [12, 4], [12, 2]]
BAD_KEEP_OUT = {
    "a NaN coordinate": ([[[NAN, 2], [14, 2], [14, 4], [12, 4], [NAN, 2]]], "malformed|finite"),
    "an infinite coordinate": ([[[12, 2], [math.inf, 2], [14, 4], [12, 2]]], "finite"),
    "an unclosed ring": ([SQUARE[:-1]], "not closed"),
    "outside the boundary": ([[[x + 100, y] for x, y in SQUARE]], "outside the map's boundary"),
    "at 1e300 m": ([[[x * 1e300, y] for x, y in SQUARE]], "beyond 1e\\+07 m"),
    "a bow tie": ([[[12, 2], [14, 4], [14, 2], [12, 4], [12, 2]]], "invalid"),
    "two points": ([[[12, 2], [12, 2]]], "malformed|invalid|empty"),
}


@pytest.mark.parametrize("case", sorted(BAD_KEEP_OUT))
def test_map_files_refuse_bad_keep_out_zones(tmp_path, case):
    coords, why = BAD_KEEP_OUT[case]
    features = [*copy.deepcopy(base_features()), feature("obstacle", "Polygon", coords)]
    with pytest.raises(MapError, match=f"feature 4 \\(obstacle\\).*({why})"):
        load_map(write_map(tmp_path, features))
    code, _, err = run_cli("range", write_scenario(tmp_path))
    assert code == 2 and "feature 4 (obstacle)" in one_line(err)


@pytest.mark.parametrize("case", sorted(BAD_KEEP_OUT))
def test_map_updates_follow_the_map_file_rules(lab, case):
    """The same function refuses them in a map update (NaN answered a GEOSException)."""
    from orange_plan.planning.plan import Plan
    from orange_plan.planning.session import MissionSession

    coords, why = BAD_KEEP_OUT[case]
    coords = [[[x - 8, y] for x, y in ring] for ring in coords]  # the lab is 8 x 6 m
    home = np.array([lab.world.home_xy_m] * 2)
    zeros = np.zeros(2)
    plan = Plan(home, t_s=np.array([0.0, 1.0]), speed_mps=zeros, energy_used_J=zeros,
                energy_to_home_J=zeros, reserve_J=zeros, margin_J=np.ones(2),
                waypoints_xy_m=np.zeros((0, 2)), covered=None)
    session = MissionSession(lab, plan, n_vertices=100)
    for given_as in ({"type": "Polygon", "coordinates": coords}, coords):
        with pytest.raises(InputError, match=f"map update: obstacles\\[0\\].*({why})") as info:
            session.update_map(obstacles=[given_as], replan=False)
        assert "\n" not in str(info.value)
    assert session.ctx.world.map.obstacles == lab.world.map.obstacles


def test_one_keep_out_rule_set_accepts_a_good_zone(lab):
    zone = {"type": "Polygon", "coordinates": [[[5, 4], [6, 4], [6, 5], [5, 5], [5, 4]]]}
    assert keep_out_polygon(zone, "zone", lab.world.map.boundary).area == 1.0


# --- elevation rasters --------------------------------------------------------------------
def test_an_elevation_raster_too_large_is_refused_before_it_is_read(tmp_path):
    """Its header is enough: a 100,000 x 100,000 grid asked numpy for 37 GiB."""
    (tmp_path / "huge.asc").write_text("ncols 100000\nnrows 100000\nxllcorner -10\n"
                                       "yllcorner -10\ncellsize 1\nNODATA_value -9999\n0 0 0\n",
                                       encoding="utf-8")
    write_map(tmp_path, elevation="huge.asc")
    scenario = write_scenario(tmp_path)
    with pytest.raises(MapError, match=f"100000 x 100000 cells.*{MAX_ELEVATION_CELLS:,}"):
        load_map(tmp_path / "yard.geojson")
    code, _, err = run_cli("range", scenario)
    assert code == 2 and f"{MAX_ELEVATION_CELLS:,}" in one_line(err)


def test_a_ragged_ring_is_named_in_the_products_words():
    """A ring whose vertices are not all [x, y] is refused without numpy's shape text."""
    import shapely

    from orange_plan.errors import InputError
    from orange_plan.world.geomap import keep_out_polygon

    with pytest.raises(InputError) as err:
        keep_out_polygon([[0, 0], [1, 1, 2], [0, 1]], "map update: obstacles[0]",
                         shapely.box(0, 0, 10, 10))
    text = str(err.value)
    assert "every vertex two numbers" in text and "inhomogeneous" not in text
