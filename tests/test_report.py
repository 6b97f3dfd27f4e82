"""orange-plan report paper: the reduced report (--trials 2) is complete and its numbers are
within their stated ranges; the shared pieces against hand-computed references."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.report import ar_drone, rusti_v1, rusti_v2, wear
from orange_plan.report.real_data import range_accuracy_pct
from orange_plan.report.trials import (
    Variation,
    course,
    course_range_m,
    draw_truth,
    run_to_depletion,
    with_belief,
    with_duty_cycle,
)
from orange_plan.sim.ranges import accuracy_pct

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
BOX = REPO / "scenarios" / "rusti_v1_box.toml"
NO_VARIATION = Variation(coefficient_rel_sd=0.0, capacity_factor=1.0, capacity_rel_sd=0.0,
                         power_std_W=0.0)


def eq6_box_m(duty: float) -> float:
    """The paper's Eq. 6 by hand from scenarios/rusti_v1_box.toml and maps/lab_box.geojson
    (lab floor crr 0.02; v_opt = v_max = 0.35 m/s: drag is negligible)."""
    e_avail = 3600 * 16.65 * math.exp(-(0.0005 * 60 + 0.0001 * 180)) * (1 - 0.03)
    omega = (1 - 0.20) * (1 - 0.10)
    p_anc = (1.0 + 0.02 * 20.0 + 3.5 + 0.8) / (1 - 0.10)
    v = 0.35
    per_m = p_anc / (v * duty) + (0.02 * 2.8 * 9.81 + 0.01 * v**2) / omega
    return e_avail / per_m


@pytest.mark.timeout(120)
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(duty=st.floats(0.3, 1.0), seed=st.integers(0, 10_000))
def test_runs_to_depletion_match_eq6_when_the_truth_is_the_model(duty, seed):
    # Without truth-only effects the box course's estimate is Eq. 6 (flat, no turning term)
    # and the simulated robot, driven until its battery is spent, covers that distance up to
    # its corner slow-downs and the last unfinished duty-cycle stop.
    ctx = with_duty_cycle(load_context(BOX), duty)
    route = course(ctx, rusti_v1.COURSES["flat (box)"][1])
    assert course_range_m(ctx, route) == pytest.approx(eq6_box_m(duty), rel=0.005)
    truth = draw_truth(ctx, NO_VARIATION, np.random.default_rng(seed))
    sim = run_to_depletion(ctx, route, truth, seed)
    assert sim.depleted
    assert sim.distance_m == pytest.approx(eq6_box_m(duty), rel=0.03)


@given(factor=st.floats(0.3, 1.5), cycles=st.floats(0.0, 500.0))
@settings(max_examples=30, deadline=None)
def test_belief_energy_follows_eq3(factor, cycles):
    ctx = load_context(BOX)
    belief = with_belief(ctx, energy_factor=factor, extra_cycles=cycles)
    by_hand = (3600 * 16.65 * math.exp(-(0.0005 * (60 + cycles) + 0.0001 * 180)) * (1 - 0.03)
               * factor)
    assert belief.scenario.battery.usable_J == pytest.approx(by_hand, rel=1e-12)
    assert belief.model is ctx.model


@given(n=st.integers(0, 1000), k1=st.floats(0.0, 0.002))
def test_wear_capacity_is_the_true_fade_over_the_believed_one(n, k1):
    # truth / belief after n cycles: exp(-k1_true n) / exp(-k1 n)
    reference = math.exp(-wear.DRIFT.k1_true_per_cycle * n) / math.exp(-k1 * n)
    assert wear.DRIFT.capacity_factor(n, k1) == pytest.approx(reference, rel=1e-12)
    assert wear.DRIFT.bias(n)["rolling_kg"] >= 1.0


@given(energy_J=st.floats(1.0, 1e7), recorded_per_m=st.floats(0.1, 1e3),
       predicted_per_m=st.floats(0.1, 1e3))
def test_real_data_range_accuracy_is_the_range_ratio(energy_J, recorded_per_m, predicted_per_m):
    # the same energy spent at the predicted vs the recorded energy per metre
    d_true, d_est = energy_J / recorded_per_m, energy_J / predicted_per_m
    error_pct = 100 * (predicted_per_m / recorded_per_m - 1)
    assert range_accuracy_pct(error_pct) == pytest.approx(accuracy_pct(d_est, d_true),
                                                          rel=1e-9, abs=1e-9)


def test_truth_draw_applies_bias_and_stays_positive():
    ctx = load_context(BOX)
    variation = Variation(bias={"rolling_kg": 1.35}, coefficient_rel_sd=0.0)
    truth = draw_truth(ctx, variation, np.random.default_rng(0), {"rolling_kg": 2.0})
    assert truth["coefficients"]["rolling_kg"] == pytest.approx(
        2.7 * ctx.model.coefficient("rolling_kg"))
    assert truth["coefficients"]["ancillary_W"] == pytest.approx(
        ctx.model.coefficient("ancillary_W"))
    wild = draw_truth(ctx, Variation(coefficient_rel_sd=5.0), np.random.default_rng(1))
    assert all(v >= 0 for v in wild["coefficients"].values())


def small_data(folder: Path) -> Path:
    """Two Husky runs on each of two surfaces and the two shortest BMW trips."""
    for surface in ("ASPHALT", "FLOORING"):
        (folder / "borealtc" / surface).mkdir(parents=True)
        for run in ("00", "01"):
            for kind in ("pro", "imu"):
                src = DATA / "borealtc" / surface / f"{kind}_{run}.csv"
                (folder / "borealtc" / surface / src.name).symlink_to(src)
    (folder / "tum_bmw_i3").mkdir()
    trips = sorted((DATA / "tum_bmw_i3").glob("Trip*.csv.gz"), key=lambda p: p.stat().st_size)
    for trip in trips[:2]:
        (folder / "tum_bmw_i3" / trip.name).symlink_to(trip)
    return folder


def table_rows(markdown: str, caption_start: str) -> list[list[str]]:
    """The body rows of the table whose caption starts with ``caption_start``."""
    block = markdown.split(f"**{caption_start}", 1)[1].split("\n\n")[1]
    return [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()[2:]]


@pytest.mark.timeout(300)
@pytest.mark.skipif(not (DATA / "borealtc").is_dir(), reason="real data not in ../shared/data")
def test_reduced_report_is_complete_and_in_range(tmp_path):
    out = tmp_path / "report"
    code, stdout, stderr = run_cli("report", "paper", "-o", out, "--trials", "2",
                                   "--data", small_data(tmp_path / "data"))
    assert code == 0, stderr
    assert "66-91 %" in stdout and "82.97 / 93.87 %" in stdout
    md = (out / "report.md").read_text()
    summary = json.loads((out / "report.json").read_text())
    from test_json_docs import compare

    compare("report paper", summary | {"out": str(out)})  # what --json prints
    for name in summary["files"]:
        assert (out / name).stat().st_size > 1000, name
        if name.endswith(".png"):
            assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
            assert f"]({name})" in md
    for number in range(1, 7):
        assert re.search(rf"^## {number}\. ", md, re.M), f"section {number} missing"
    assert not re.search(r"\bnan\b", md, re.I)
    assert "no row is faked" in md and "bench diagnose" in md

    v1 = table_rows(md, "Rusti V1.0: range")
    assert len(v1) == len(rusti_v1.COURSES) * len(rusti_v1.DUTY_CYCLES)
    v2 = table_rows(md, "Rusti V2.0: range")
    assert {(r[0], r[1][:2], r[2][:2]) for r in v2} == {
        (s, b, v) for s in rusti_v2.SURFACES for b in rusti_v2.PACKS for v in rusti_v2.SPEEDS}
    drone = table_rows(md, "AR Drone 2.0: range")
    assert [r[0] for r in drone] == list(ar_drone.MODELS)
    assert drone[0][3] == "82.97" and drone[0][6] == "93.87"
    assert [r[0] for r in table_rows(md, "Husky A200")] == ["ASPHALT", "FLOORING", "all"]
    assert len(table_rows(md, "BMW i3")) == 3
    assert [int(r[0]) for r in table_rows(md, "Wear and tear")] == wear.missions()[1:]

    sec = summary["sections"]
    for cell in sec["rusti_v1"]["cells"] + sec["rusti_v2"]["cells"]:
        assert cell["d_true_m"] > 0
        assert 0 <= cell["error_prior_pct"] <= 100 and 0 <= cell["error_calibrated_pct"] <= 100
    for cell in sec["ar_drone"]["cells"]:
        for key in ("offline", "online", "online_mean"):
            assert cell[f"accuracy_{key}_pct"] <= 100 and cell[f"accuracy_{key}_sd_pct"] >= 0
    for row in sec["wear"]["missions"]:
        assert all(row[k] >= 0 for k in wear.ESTIMATES)
    # the stated a-priori accuracy band is the table's
    band = re.search(r"Ours, a priori: accuracy ([\d.]+)-([\d.]+) %", md)
    accuracies = [100 - c["error_prior_pct"] for c in sec["rusti_v1"]["cells"]]
    assert float(band[1]) == pytest.approx(min(accuracies), abs=0.05)
    assert float(band[2]) == pytest.approx(max(accuracies), abs=0.05)


@pytest.mark.parametrize("args, message", [
    (["--trials", "1"], "--trials = 1 must be >= 2"),
    (["--data", "/nonexistent-folder"], "--data /nonexistent-folder: folder not found"),
])
def test_bad_arguments_exit_2_with_one_line(tmp_path, args, message):
    code, _, stderr = run_cli("report", "paper", "-o", tmp_path / "r", *args)
    assert code == 2
    assert message in stderr and stderr.count("\n") == 1


def test_output_that_is_a_file_is_refused(tmp_path):
    target = tmp_path / "report.md"
    target.write_text("not a folder")
    code, _, stderr = run_cli("report", "paper", "-o", target)
    assert code == 2 and "exists and is not a folder" in stderr


def test_report_is_a_layer_above_sim_identify_and_planning():
    # the report reuses the simulator, the estimators and the planner; none may depend on it
    package = REPO / "orange_plan"
    for layer in ("sim", "identify", "planning", "physics", "telemetry", "world"):
        for module in (package / layer).rglob("*.py"):
            text = module.read_text(encoding="utf-8")
            assert "orange_plan.report" not in text, module.relative_to(REPO)


def test_help_names_the_options_and_cites_no_spec():
    code, stdout, _ = run_cli("report", "paper", "--help")
    assert code == 0
    for option in ("--out", "--trials", "--seed", "--data", "--json"):
        assert option in stdout
    assert not re.search(r"SPEC|DESIGN\.md|§", stdout)
