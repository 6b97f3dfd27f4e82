"""bench.mission (``orange-plan bench mission``): a quick run on a tiny world completes with
every column, and the energy accounting strands a robot far heavier than its model (structure
and bookkeeping, never the measured figures of docs/benchmarks/mission.md)."""

from __future__ import annotations

import json

import pytest
from conftest import run_cli

from orange_plan.bench.mission import (
    METHODS,
    MissionSpec,
    mission_specs,
    run_one_mission,
    stranding_upper_bound,
    summarise,
)

pytestmark = pytest.mark.timeout(240)

TINY = {"width_m": 80.0, "height_m": 60.0, "n_vertices": 400}

ROW_KEYS = ("family", "method", "missions", "errors", "strandings", "stranding_upper95",
            "energy_left_at_home_kJ", "coverage_m2", "coverage_over_oracle",
            "coverage_over_oracle_median", "replans", "returned_early", "seconds")
FLIGHT_KEYS = ("coverage_m2", "energy_left_J", "stranded", "duration_s", "replans",
               "returned_early", "seconds")


def test_quick_run_completes_with_every_column(tmp_path):
    out, png = tmp_path / "mission.json", tmp_path / "mission.png"
    code, stdout, stderr = run_cli("bench", "mission", "--quick", "--json", "--out", out,
                                   "--png", png)
    assert code == 0, stderr
    result = json.loads(stdout)
    from test_json_docs import compare

    compare("bench mission", result)  # docs/json.md lists exactly these keys
    assert result["complete"] and result["missions"] == 3 == len(result["flights"])
    assert json.loads(out.read_text())["missions"] == 3
    assert png.stat().st_size > 10_000
    assert [r["method"] for r in result["rows"]] == list(METHODS)
    for row in result["rows"] + result["by_family"] + result["by_kind"]:
        assert set(ROW_KEYS) <= set(row)
    for row in result["rows"]:
        assert row["missions"] == 3 and row["errors"] == 0
        assert row["coverage_m2"] > 0
    oracle = next(r for r in result["rows"] if r["method"] == "oracle")
    assert oracle["coverage_over_oracle"] == pytest.approx(1.0)
    assert result["session_over_oracle"] is not None
    families = [f["family"] for f in result["flights"]]
    assert families == ["within", "beyond", "within"]
    for flight in result["flights"]:
        for method in METHODS:
            assert set(FLIGHT_KEYS) <= set(flight[method])


def test_far_heavier_truth_strands_the_open_loop_not_the_live_check():
    """+80 kg on the 25 kg robot: the first tour flown open loop runs out of energy before
    home; the session, told not to replan, still gets home: its live check on the measured
    energy turns it home in time; the oracle (true model) gets home too."""
    spec = MissionSpec(0, heavier_kg=80.0, replanning=False, **TINY)
    result = run_one_mission(spec, 3)
    assert "+ 80 kg" in result["truth"]
    assert result["open_loop"]["stranded"] and result["open_loop"]["energy_left_J"] < 0
    assert not result["session"]["stranded"] and result["session"]["energy_left_J"] >= 0
    assert result["session"]["returned_early"]
    for method in ("open_loop", "session"):
        assert result[method]["replans"] == 0
    assert not result["oracle"]["stranded"]
    assert result["oracle"]["energy_left_J"] > 0
    row = {r["method"]: r for r in summarise([result])}
    assert row["open_loop"]["strandings"] == 1
    assert row["open_loop"]["energy_left_at_home_kJ"] is None  # none got home


def test_one_mission_is_pure():
    spec = MissionSpec(0, family="beyond", kind="mass", methods=("open_loop", "oracle"), **TINY)
    a, b = run_one_mission(spec, 5), run_one_mission(spec, 5)
    for method in spec.methods:
        a[method].pop("seconds"), b[method].pop("seconds")
        assert a[method] == b[method]
    assert a["truth"] == b["truth"] and a["truth"].startswith("calibration draw, payload")


def test_specs_alternate_families_and_deal_maps():
    specs = mission_specs(10, n_maps=3)
    assert [s.family for s in specs[:4]] == ["within", "beyond", "within", "beyond"]
    assert [s.kind for s in specs[1::2]] == ["wind", "mass", "ageing", "terrain", "wind"]
    assert [s.map_seed for s in specs[:4]] == [0, 1, 2, 0]


def test_stranding_upper_bound():
    assert stranding_upper_bound(0, 500) == pytest.approx(1 - 0.05 ** (1 / 500))
    assert stranding_upper_bound(0, 500) < 0.01
    assert stranding_upper_bound(3, 3) == 1.0
    assert stranding_upper_bound(0, 0) is None


def test_bad_arguments_are_one_line_errors():
    code, _, stderr = run_cli("bench", "mission", "--missions", "0")
    assert code == 2 and "--missions = 0 must be >= 1" in stderr
    code, _, stderr = run_cli("bench", "mission", "--quick", "--png", "x.jpg")
    assert code == 2 and "must end in .png" in stderr


def figure_result(strandings: dict) -> dict:
    """A study's result as mission_plot reads it: 20 missions, the open loop and the oracle
    at the same place, ``strandings`` per method."""
    coverage = {"session": 0.84, "open_loop": 1.0, "lawnmower": 1.48, "oracle": 1.0}

    def row(family, method, shift=0.0):
        return {"family": family, "method": method, "missions": 20,
                "strandings": strandings[method], "coverage_over_oracle": coverage[method] + shift}

    return {"missions": 20, "complete": True, "spec": {"confidence": 0.99},
            "rows": [row("all", m) for m in coverage],
            "by_family": [row(f, m, s) for f, s in (("within", 0.1), ("beyond", -0.05))
                          for m in coverage]}


@pytest.mark.parametrize("strandings", [
    {"session": 0, "open_loop": 0, "lawnmower": 20, "oracle": 0},   # 100 % stranded
    {"session": 0, "open_loop": 0, "lawnmower": 0, "oracle": 0},    # none
    {"session": 1, "open_loop": 3, "lawnmower": 9, "oracle": 3},
])
def test_mission_figure_labels_apart_and_axis_to_the_data(strandings):
    import matplotlib.pyplot as plt

    from orange_plan.bench.mission import mission_plot

    fig = mission_plot(figure_result(strandings))
    try:
        ax = fig.axes[0]
        renderer = fig.canvas.get_renderer()
        labels = fig.findobj(lambda a: a.get_gid() == "method-label")
        named = " ".join(t.get_text() for t in labels)
        assert all(m in named for m in ("(a)", "(b)", "(c)", "(d)")), named
        boxes = [t.get_window_extent(renderer) for t in labels]
        assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
        top = 100.0 * max(strandings.values()) / 20
        lo, hi = ax.get_xlim()
        assert hi <= max(top, 5.0) * 1.1 + 1.0 and hi <= 107.0, (lo, hi)
        assert all(b.x0 >= ax.bbox.x0 - 1 and b.x1 <= ax.bbox.x1 + 1 for b in boxes)
    finally:
        plt.close(fig)


def test_map_kits_kept_are_bounded_least_recently_used_first(monkeypatch):
    from orange_plan.bench import mission

    monkeypatch.setattr(mission, "_KITS", mission.OrderedDict())
    made = []

    def kit(key):
        return mission._remember(key, lambda: made.append(key) or key, kept=2)

    for key in ("a", "b", "a", "c", "a", "b"):
        kit(key)
    assert made == ["a", "b", "c", "b"]  # "b" was the least recently used when "c" came
    assert list(mission._KITS) == ["a", "b"]


def test_the_generated_worlds_folder_goes_with_its_process():
    import subprocess
    import sys
    from pathlib import Path

    probe = "from orange_plan.bench.mission import _folder\nprint(_folder())"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True, timeout=120)
    folder = Path(out.stdout.strip())
    assert folder.name.startswith("orange-bench-mission-") and not folder.exists()
