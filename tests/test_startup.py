"""Start-up. Structural checks (no timings): the CLI and its command
modules import no heavy library, and ``range`` needs neither scipy nor CasADi."""

from __future__ import annotations

import json
import subprocess
import sys

from conftest import REPO

HEAVY = ("scipy", "casadi", "ompl", "matplotlib", "pandas", "pyarrow", "rasterio", "pyulog",
         "rosbags", "shapely", "numba", "pymavlink")


def loaded_after(code: str) -> set[str]:
    """Top-level packages among HEAVY imported by ``code`` in a fresh interpreter."""
    probe = (f"import sys\n{code}\nimport json\n"
             f"print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}))))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          cwd=REPO, timeout=120, check=True)
    return set(json.loads(proc.stdout.splitlines()[-1]))


def test_cli_and_every_command_module_import_no_heavy_library():
    assert loaded_after("import orange_plan.cli as c\nc._register_commands()") == set()


def test_range_needs_neither_scipy_nor_casadi():
    code = ("from orange_plan.context import load_context\n"
            "from orange_plan.range_report import range_report\n"
            "range_report(load_context('scenarios/rusti_v2_grass_2200mAh_v0952.toml'))")
    assert loaded_after(code) <= {"shapely"}


def test_reach_does_not_import_scipy_stats():
    probe = ("import sys\nimport orange_plan.planning.reach\n"
             "assert 'scipy.stats' not in sys.modules, 'scipy.stats imported'")
    subprocess.run([sys.executable, "-c", probe], cwd=REPO, timeout=120, check=True)


def test_roadmap_weights_and_point_queries_do_not_depend_on_the_chunk_size(tmp_path,
                                                                           monkeypatch):
    """Memory: edges and field points are processed in chunks; the answers must not change."""
    import numpy as np
    from planning_worlds import write_world

    from orange_plan.context import load_context
    from orange_plan.planning import reach as reach_mod
    from orange_plan.planning import roadmap as roadmap_mod

    ctx = load_context(write_world(tmp_path, obstacles=[(10, 5, 14, 25)],
                                   hill=(28, 20, 4.0, 5.0), reserve={"confidence": 0.95}))
    whole = reach_mod.prepare_reach(ctx, n_vertices=200)
    pts = np.column_stack([np.linspace(1, 30, 50), np.linspace(1, 30, 50)])
    field = reach_mod.query_points(whole, pts)
    monkeypatch.setattr(roadmap_mod, "WEIGH_CHUNK", 97)
    monkeypatch.setattr(reach_mod, "QUERY_CHUNK", 7)
    chunked = reach_mod.prepare_reach(ctx, n_vertices=200)
    assert np.array_equal(whole.roadmap.energy_J, chunked.roadmap.energy_J)
    field_chunked = reach_mod.query_points(chunked, pts)
    assert np.array_equal(field.margin_J, field_chunked.margin_J, equal_nan=True)
