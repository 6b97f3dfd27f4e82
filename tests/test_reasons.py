"""Refusals give the real reason, in the words of the interface that was used: the CLI names
its options, the HTTP service its fields, the Python API its arguments; no numpy or pydantic
text reaches a person."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import run_cli, write_map, write_scenario

from orange_plan.errors import InputError

pytestmark = pytest.mark.timeout(120)


def test_a_too_short_time_limit_is_named_not_the_battery(tmp_path):
    scenario = write_scenario(tmp_path, set={"mission.time_limit_s": 0.0001})
    code, _, err = run_cli("plan", scenario, "-o", tmp_path / "p.geojson", "--vertices", "300")
    assert code == 2 and "time limit is too short" in err and "battery" not in err, err
    assert "0.0001 s" in err


def test_range_shows_a_small_time_limit_as_given(tmp_path):
    scenario = write_scenario(tmp_path, set={"mission.time_limit_s": 0.0001})
    code, out, _ = run_cli("range", scenario)
    assert code == 0 and "mission.time_limit_s = 0.0001 s" in " ".join(out.split())


def test_a_huge_sensor_radius_is_named_not_a_boxed_in_home(tmp_path):
    scenario = write_scenario(tmp_path, set={"mission.sensor_radius_m": 1e9})
    code, _, err = run_cli("plan", scenario, "-o", tmp_path / "p.geojson", "--vertices", "300")
    assert code == 2 and "mission.sensor_radius_m = 1e+09 m" in err and "boxed in" not in err


@pytest.mark.parametrize("where", ["map", "elevation"])
def test_a_folder_named_as_a_file_is_called_a_folder(tmp_path, where):
    if where == "map":
        scenario = write_scenario(tmp_path, set={"map": "."})
    else:
        write_map(tmp_path, elevation=".")
        scenario = write_scenario(tmp_path)
    code, _, err = run_cli("range", scenario)
    assert code == 2 and "is a folder" in err and "not found" not in err, err
    assert str(tmp_path) in err  # where it looked


@pytest.mark.parametrize("option", ["--data", "--scenarios"])
def test_a_file_given_as_a_folder_is_called_a_file(tmp_path, option):
    afile = tmp_path / "afile.txt"
    afile.write_text("x", encoding="utf-8")
    args = (["report", "paper", "-o", tmp_path / "r", "--data", afile] if option == "--data"
            else ["serve", "--scenarios", afile])
    code, _, err = run_cli(*args)
    assert code == 2 and "is a file; give a folder" in err, err


def test_each_interface_names_the_start_its_own_way(tmp_path):
    from orange_plan.context import load_context
    from orange_plan.planning.reach import prepare_reach

    scenario = write_scenario(tmp_path)
    with pytest.raises(InputError) as python_api:
        prepare_reach(load_context(scenario), (500.0, 500.0), n_vertices=100)
    assert str(python_api.value).startswith("start_xy (500, 500) m is outside")
    with pytest.raises(InputError) as energy:
        prepare_reach(load_context(scenario), None, 1e12, n_vertices=100)
    assert str(energy.value).startswith("energy_used_J = 1e+12 must be in")
    code, _, err = run_cli("reach", scenario, "--from", "500,500", "--vertices", "100")
    assert code == 2 and "--from (500, 500) m is outside" in err


def test_the_service_names_its_own_fields_not_cli_options(tmp_path):
    pytest.importorskip("httpx")
    from fastapi.testclient import TestClient

    from orange_plan.errors import NamedInputError
    from orange_plan.service.app import create_app

    app = create_app(tmp_path / "m.sqlite", warm_up=False, token_from_env=False)

    @app.get("/probe/{argument}")
    def probe(argument: str):
        raise NamedInputError(argument, "{name} is refused")

    client = TestClient(app)
    for argument in ("start_xy", "energy_used_J", "time_used_s"):
        detail = client.get(f"/probe/{argument}").json()["detail"]
        assert "--" not in detail and argument not in detail, detail
    assert "telemetry" in client.get("/probe/start_xy").json()["detail"]


def test_the_service_says_validation_problems_in_its_own_words(tmp_path):
    pytest.importorskip("httpx")
    from fastapi.testclient import TestClient

    from orange_plan.service.app import create_app

    client = TestClient(create_app(tmp_path / "m.sqlite", warm_up=False,
                                   token_from_env=False))
    r = client.post("/missions", json={"scenario": "rusti_v1_box", "n_vertices": 300})
    mission = r.json()["mission_id"]
    ring = [[3, 3], [4, 3], [4, 4], [3, 4]]
    detail = client.post(f"/missions/{mission}/map", json={"obstacles": [ring]}).json()["detail"]
    assert detail.startswith("obstacles[0]: expected a GeoJSON Polygon"), detail
    detail = client.post("/missions", json={"scenario": "x", "n_vertices": "many"}).json()[
        "detail"]
    assert detail == 'n_vertices: expected an integer, got "many"'
    detail = client.post("/missions", json={"scenario": "x", "n_vertices": 1}).json()["detail"]
    assert detail == "n_vertices: must be >= 50"
    detail = client.post(f"/missions/{mission}/telemetry", json={"samples": []}).json()["detail"]
    assert detail == "samples: needs at least 1 item"


def test_numpy_scalars_are_shown_as_plain_numbers(tmp_path):
    from orange_plan.context import load_context
    from orange_plan.errors import plain_message
    from orange_plan.planning.coverage import coverage_grid

    world = load_context(write_scenario(tmp_path)).world
    with pytest.raises(InputError) as caught:
        coverage_grid(world, np.float64("nan"))
    assert str(caught.value).startswith("sensor_radius_m = nan must be")
    assert plain_message(f"x = {np.int64(3)!r},\n y = {np.float64(2.5)!r}") == "x = 3, y = 2.5"
