"""``identify.diagnose``: locate, name, model, on small simulated recordings whose truth is
known (the generated concealed-effect suite is tests/test_diagnose_concealed.py)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from planning_worlds import write_world
from scipy.optimize import lsq_linear
from scipy.signal import lfilter

from orange_plan.context import load_context
from orange_plan.identify.diagnose import build_design, diagnose, fit_design
from orange_plan.identify.diagnosis.fitting import _at_violated_bounds, _solve
from orange_plan.identify.diagnosis.settings import DEFAULT_SETTINGS
from orange_plan.identify.locate import quarters
from orange_plan.physics.model_builder import model_with_terms
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import simulate
from orange_plan.sim.truth import Truth
from orange_plan.telemetry.recording import recording_from_frame

RATE_HZ = 5.0
ZIGZAG_XY_M = np.array([[2, 2], [55, 2], [55, 10], [5, 10], [5, 18], [55, 18], [55, 26],
                        [5, 26], [5, 34], [55, 34], [30, 20], [2, 2]], float)


@pytest.fixture(scope="module")
def ctx(tmp_path_factory):
    """A 60 m x 40 m flat field; the scenario has no turning losses."""
    return load_context(write_world(tmp_path_factory.mktemp("diag"), width_m=60.0, height_m=40.0,
                                    rated_energy_Wh=500.0, name="field"))


def drive(ctx, model=None, truth=None, seed=0, laps=2, disturbance_sd_W=0.4):
    """A recording of ``laps`` zigzags under ``model`` (default the scenario's), with white
    noise and an AR(1) disturbance (correlation time 8 s) on the recorded power."""
    xy = np.vstack([ZIGZAG_XY_M] + [ZIGZAG_XY_M[1:]] * (laps - 1))
    route = Route(xy, np.full(len(xy), 1.0), "zigzag")
    sim_ctx = ctx if model is None else replace(ctx, model=model)
    frame = simulate(sim_ctx, route, truth or Truth(power_std_W=0.3), seed=seed,
                     sample_rate_Hz=RATE_HZ).frame.drop(columns=["payload_kg", "surface"])
    rng = np.random.default_rng(seed + 1000)
    phi = np.exp(-1.0 / (8.0 * RATE_HZ))
    ar = lfilter([1.0], [1.0, -phi], rng.normal(0, disturbance_sd_W * np.sqrt(1 - phi**2),
                                                len(frame)))
    frame["power_W"] = frame["power_W"] + ar
    return frame


def with_turning(ctx, turn_J_per_rad: float):
    return model_with_terms(ctx, [*ctx.model.term_ids, "turning"]).with_theta(
        {"turn_J_per_rad": turn_J_per_rad})


# --- naming and fitting ---------------------------------------------------------------------


def test_left_out_turning_is_found_fitted_and_explains_the_residual(ctx):
    frame = drive(ctx, with_turning(ctx, 12.0), seed=3)
    result = diagnose(recording_from_frame(frame), ctx)
    assert [f.term for f in result.findings] == ["turning"]
    found = result.findings[0]
    value, sd = found.params["turn_J_per_rad"], found.stderr["turn_J_per_rad"]
    assert abs(value - 12.0) <= 3 * sd + 0.02 * 12.0, (value, sd)
    assert found.explains_pct > 50
    assert result.improved.cv_rmse_W < 0.8 * result.baseline.cv_rmse_W
    assert "turn" in found.evidence and "held-out RMSE" in found.evidence


def test_a_diagnosis_runs_on_one_blas_thread_and_gives_the_others_back(ctx, monkeypatch):
    from threadpoolctl import ThreadpoolController, threadpool_limits

    from orange_plan.identify.diagnosis import pipeline

    seen = []
    select = pipeline.select

    def counting_select(d, pool):
        seen.append({i["num_threads"] for i in ThreadpoolController().info()
                     if i["user_api"] == "blas"})
        return select(d, pool)

    monkeypatch.setattr(pipeline, "select", counting_select)
    frame = drive(ctx, with_turning(ctx, 12.0), seed=3)
    with threadpool_limits(2, user_api="blas"):
        result = diagnose(recording_from_frame(frame), ctx)
        after = {i["num_threads"] for i in ThreadpoolController().info()
                 if i["user_api"] == "blas"}
    assert seen and all(s == {1} for s in seen if s)
    assert after <= {2} and [f.term for f in result.findings] == ["turning"]


def test_nothing_missing_is_said_explicitly_with_evidence(ctx):
    result = diagnose(recording_from_frame(drive(ctx, seed=4)), ctx)
    out = result.to_dict()
    assert out["verdict"] == "no missing physics found"
    assert out["missing_physics"] == []
    assert "best candidate" in out["evidence"] and "held-out RMSE" in out["evidence"]
    assert out["improved"]["rmse_W"] == out["baseline"]["rmse_W"]


def test_a_mis_set_coefficient_is_refitted_not_blamed_on_a_new_term(ctx):
    wrong = ctx.model.with_theta({"ancillary_W": 1.4 * ctx.model.coefficient("ancillary_W"),
                                  "rolling_kg": 0.7 * ctx.model.coefficient("rolling_kg")})
    result = diagnose(recording_from_frame(drive(ctx, wrong, seed=5)), ctx)
    assert result.findings == []
    assert result.design.base.coefficient("ancillary_W") == pytest.approx(
        wrong.coefficient("ancillary_W"), rel=0.05)


def test_a_column_that_carries_nothing_adds_no_term(ctx):
    """A temperature column unrelated to the power (a wrong sensor) gives no hvac term."""
    frame = drive(ctx, seed=6)
    rng = np.random.default_rng(6)
    frame["ambient_C"] = 15 + np.cumsum(rng.normal(0, 0.05, len(frame)))
    frame["battery_C"] = 10 + np.cumsum(rng.normal(0, 0.05, len(frame)))
    result = diagnose(recording_from_frame(frame), ctx)
    assert result.findings == []
    tried = {t.id for t in result.trials}
    assert {"hvac_ambient", "battery_temperature"} <= tried  # they were considered


# --- the baseline's prior ------------------------------------------------------------------


@pytest.mark.parametrize("disturbance_sd_W", [0.4, 4.0])
def test_a_coefficient_the_recording_cannot_see_keeps_its_stated_prior(ctx, disturbance_sd_W):
    """On a flat field the grade's column is zero: its coefficient is the prior's alone, with
    the stated standard error (``prior_scale`` times the a-priori one), however noisy the
    power. A prior weighed against squared residuals in W^2 as if the noise were 1 W came
    out sqrt(s^2 tau) times wider: 2.7 x at 0.4 W of disturbance, 30 x at 4 W."""
    d = build_design(recording_from_frame(drive(ctx, seed=7,
                                                disturbance_sd_W=disturbance_sd_W)), ctx)
    fit = fit_design(d, [])
    grade = d.base.names.index("grade_kg")
    assert not np.any(d.columns[:, grade])
    stated = d.settings.prior_scale * np.sqrt(ctx.model.cov[grade, grade])
    assert fit.sd[grade] == pytest.approx(stated, rel=1e-6)
    assert fit.theta[grade] == pytest.approx(ctx.model.coefficient("grade_kg"), rel=1e-6)


def test_the_prior_weight_is_the_noise_over_the_prior_variance(ctx):
    """A fit's ridge is one over the prior's variance times the noise the fit leaves (its
    residual variance times autocorrelation time): 7.3 W^2 / sd0^2 at 0.4 W of disturbance,
    900 W^2 / sd0^2 at 4 W, so the noisier recording leans on the same prior 120 x harder."""
    quiet, noisy = (build_design(recording_from_frame(drive(ctx, seed=7, disturbance_sd_W=s)),
                                 ctx) for s in (0.4, 4.0))
    ratios = []
    for d in (quiet, noisy):
        fit = fit_design(d, [])
        p = d.prior_weight.size
        noise = fit.rmse_W**2 * fit.tau
        near_prior = 1.0 / (1.0 + (fit.theta[:p] - d.prior_mean) ** 2 * d.prior_weight
                            / (d.settings.prior_dof + 1.0))
        np.testing.assert_allclose(fit.ridge[:p], d.prior_weight * noise * near_prior,
                                   rtol=0.02)
        assert d.noise_var == pytest.approx(noise, rel=0.02)
        ratios.append(noise)
    assert 30 < ratios[1] / ratios[0] < 300


def test_the_prior_weight_yields_as_a_student_t_by_hand(ctx):
    """``Design.ridge`` at coefficients: the normal prior's weight at the prior mean, and
    ``1 / (1 + z^2 / (dof + 1))`` of it ``z`` prior sd away: 1/3 at 2 sd with one degree of
    freedom, 1/51 at 10 sd."""
    d = build_design(recording_from_frame(drive(ctx, seed=7)), ctx)
    sd0 = 1.0 / np.sqrt(d.prior_weight)
    normal = d.ridge(d.prior_weight.size + 1, 3.0)
    assert normal[-1] == 0.0  # a candidate's column has no prior
    np.testing.assert_allclose(d.ridge(normal.size, 3.0, d.prior_mean), normal)
    for z, share in ((2.0, 1 / 3), (10.0, 1 / 51)):
        away = d.ridge(normal.size, 3.0, d.prior_mean + z * sd0)
        np.testing.assert_allclose(away[:-1], share * normal[:-1])
    with pytest.raises(ValueError):
        d.ridge(normal.size, 3.0, d.prior_mean[:1])


def test_a_prior_the_recording_contradicts_by_many_sd_yields(ctx):
    """The ancillary draw 10 prior sd above the scenario's, in 20 W of disturbance: the fit is
    the recording's (within one posterior sd), where a normal prior of the same sd pulled it
    more than halfway back (4 sd of 10)."""
    i = ctx.model.names.index("ancillary_W")
    sd0 = DEFAULT_SETTINGS.prior_scale * np.sqrt(ctx.model.cov[i, i])
    truth = ctx.model.with_theta({"ancillary_W": ctx.model.coefficient("ancillary_W") + 10 * sd0})
    rec = recording_from_frame(drive(ctx, truth, seed=8, disturbance_sd_W=20.0))
    fits = {dof: fit_design(build_design(rec, ctx, settings=replace(DEFAULT_SETTINGS,
                                                                    prior_dof=dof)), [])
            for dof in (DEFAULT_SETTINGS.prior_dof, 1e12)}
    t_fit, normal_fit = fits[DEFAULT_SETTINGS.prior_dof], fits[1e12]
    true_W = truth.coefficient("ancillary_W")
    assert abs(t_fit.theta[i] - true_W) < t_fit.sd[i]
    assert true_W - normal_fit.theta[i] > 3 * normal_fit.sd[i]


# --- locating ----------------------------------------------------------------------------------


def test_a_time_localised_excess_is_located_in_its_window(ctx):
    frame = drive(ctx, seed=7)
    t = frame["t_s"].to_numpy()
    step = (t >= 100.0) & (t < 180.0)
    frame.loc[step, "power_W"] += 6.0
    result = diagnose(recording_from_frame(frame), ctx)
    hit = [m for m in result.mismatches if m.t_start_s < 180 and m.t_end_s > 100
           and m.t_end_s - m.t_start_s < 200]
    assert hit, result.mismatches
    best = max(hit, key=lambda m: min(m.t_end_s, 180) - max(m.t_start_s, 100))
    assert best.t_start_s == pytest.approx(100, abs=10) and best.t_end_s == pytest.approx(180, abs=10)
    assert best.mean_residual_W > 3.0
    assert best.where


def test_quarters_split_a_feature_that_is_mostly_zero():
    yaw = np.r_[np.zeros(90), np.linspace(0.2, 1.0, 10)]
    upper, lower = quarters(yaw)
    assert upper.sum() == 10 and lower.sum() == 90
    upper, lower = quarters(np.arange(100.0))
    assert upper.sum() == 25 and lower.sum() == 25


# --- the bounded solve ---------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(1, 6))
def test_bounded_solve_from_normal_equations_matches_direct_least_squares(seed, k):
    """``_solve`` works on the k x k normal equations (to be fast on long recordings); it must
    give the bounded least-squares answer of the full n x k problem (scipy, independently)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(200, k)) * rng.uniform(0.01, 100, k)
    y = x @ rng.normal(size=k) + rng.normal(size=200)
    lower = np.where(rng.random(k) < 0.6, 0.0, -np.inf)
    upper = np.where(rng.random(k) < 0.2, 0.5, np.inf)
    upper = np.maximum(upper, lower + 0.1)
    ours = _solve(x.T @ x, x.T @ y, lower, upper)
    ref = lsq_linear(x, y, bounds=(lower, upper), method="bvls").x
    assert np.all(ours >= lower - 1e-9) and np.all(ours <= upper + 1e-9)
    cost = lambda th: float(np.sum((x @ th - y) ** 2))  # noqa: E731
    assert cost(ours) <= cost(ref) * (1 + 1e-6) + 1e-9


def test_a_bound_the_free_optimum_crosses_is_tried_first_by_hand():
    """``_at_violated_bounds``: on the identity with ``z = (-1, 2)`` and both >= 0 the first
    coefficient is held at 0, the second is 2, and the gradient (1, 0) pushes the first
    outwards: the optimum. Correlated columns with ``z = (-1, -0.5)``: held at 0, the first
    pulls the second to -0.5, out of its bound, so the guess is refused and the bounded solve
    finds (0, 0)."""
    lo, hi = np.zeros(2), np.full(2, np.inf)
    np.testing.assert_allclose(_at_violated_bounds(np.eye(2), np.array([-1.0, 2.0]),
                                                   np.array([-1.0, 2.0]), lo, hi), [0.0, 2.0])
    g, z = np.array([[1.0, 0.9], [0.9, 1.0]]), np.array([-1.0, -0.5])
    assert _at_violated_bounds(g, z, np.linalg.solve(g, z), lo, hi) is None
    np.testing.assert_allclose(_solve(g, z, lo, hi), [0.0, 0.0], atol=1e-12)


@settings(max_examples=4, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000))
def test_a_recording_of_the_model_itself_never_gets_a_new_term(ctx, seed):
    """Invariant: with nothing left out, whatever the noise draw, nothing is named (a named
    term must be physics the recording holds, not a fluke of the noise)."""
    result = diagnose(recording_from_frame(drive(ctx, seed=seed, laps=1,
                                                 disturbance_sd_W=1.0)), ctx)
    assert result.findings == [], [f.to_dict() for f in result.findings]


# --- the command ---------------------------------------------------------------------------------


def run_cli(*args):
    from typer.testing import CliRunner

    from orange_plan.cli import _register_commands, app

    _register_commands()
    return CliRunner().invoke(app, [str(a) for a in args])


def test_cli_json_follows_spec_6_and_o_carries_the_term_into_predict(ctx, tmp_path):
    rec = tmp_path / "turns.csv"
    drive(ctx, with_turning(ctx, 12.0), seed=8).to_csv(rec, index=False)
    out_toml = tmp_path / "with_turning.toml"
    res = run_cli("diagnose", rec, "--scenario", ctx.scenario.path, "-o", out_toml,
                  "--png", tmp_path / "d.png", "--json")
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert set(report["baseline"]) >= {"terms", "rmse_W", "energy_error_pct"}
    assert set(report["improved"]) >= {"terms", "rmse_W", "holdout_rmse_W", "energy_error_pct"}
    for m in report["mismatches"]:
        assert set(m) == {"t_start_s", "t_end_s", "mean_residual_W", "where"}
    (found,) = report["missing_physics"]
    assert set(found) >= {"term", "explains_pct", "params", "evidence"}
    assert found["term"] == "turning" and "turning" in report["improved"]["terms"]
    assert (tmp_path / "d.png").stat().st_size > 10_000
    before = run_cli("predict", rec, "--scenario", ctx.scenario.path, "--json")
    after = run_cli("predict", rec, "--scenario", out_toml, "--json")
    rmse = [json.loads(r.stdout)["rmse_W"] for r in (before, after)]
    assert rmse[1] < 0.7 * rmse[0]


@pytest.mark.parametrize(("content", "message"), [
    ("t_s,v_mps\n0,1\n1,1\n", "power"),
    ("not a table at all", ""),
    ("t_s,power_W,v_mps\n" + "".join(f"{i},{1e308 if i == 3 else 5},1\n" for i in range(60)),
     "power_w"),
])
def test_cli_refuses_malformed_input_in_one_line(ctx, tmp_path, content, message):
    rec = tmp_path / "bad.csv"
    rec.write_text(content, encoding="utf-8")
    res = run_cli("diagnose", rec, "--scenario", ctx.scenario.path)
    assert res.exit_code == 2
    lines = [ln for ln in res.stderr.strip().splitlines() if ln]
    assert len(lines) == 1 and message in lines[0].lower()


def test_cli_refuses_a_missing_scenario_and_a_bad_output(ctx, tmp_path):
    rec = tmp_path / "r.csv"
    drive(ctx, seed=9, laps=1).to_csv(rec, index=False)
    res = run_cli("diagnose", rec, "--scenario", tmp_path / "nope.toml")
    assert res.exit_code == 2
    res = run_cli("diagnose", rec, "--scenario", ctx.scenario.path, "-o", tmp_path / "x.txt")
    assert res.exit_code == 2 and "-o" in res.stderr


# --- real recordings -------------------------------------------------------------------------

REPO = __import__("pathlib").Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"


@pytest.mark.skipif(not (DATA / "borealtc").is_dir(),
                    reason="real data not present in ../shared/data (BorealTC)")
def test_real_husky_run_turning_scrub_is_found_with_the_a_priori_scenario():
    """On the real recordings: husky_a200 carries turning_torque with no
    a-priori value (0: left out); on a converted asphalt run diagnosis names the turning
    scrub and the held-out RMSE falls by a third or more."""
    from orange_plan.telemetry.importers import read_log

    rec = recording_from_frame(read_log(DATA / "borealtc" / "ASPHALT" / "pro_01.csv")[0])
    ctx = load_context(REPO / "scenarios" / "husky_a200.toml")
    result = diagnose(rec, ctx)
    assert "turning" in [f.term for f in result.findings]
    assert result.improved.cv_rmse_W < 0.67 * result.baseline.cv_rmse_W


@pytest.fixture(scope="module")
def payload_pickup():
    """A payload picked up at 40 s on the lab floor (600 s at 10 Hz): (frame, diagnosis)."""
    from conftest import REPO

    ctx = load_context(REPO / "scenarios" / "rusti_v1_box.toml")
    loop = np.array([[1, 1], [7, 1], [7, 4.4], [1, 4.4], [1, 1]], float)
    route = Route(loop, np.full(len(loop), 0.3), "loop")
    truth = Truth(power_std_W=0.2, payload_kg=2.0, payload_from_s=40.0)
    frame = simulate(ctx, route, truth, seed=0, sample_rate_Hz=10.0, to_depletion=True,
                     max_duration_s=600.0).frame
    return frame, diagnose(recording_from_frame(frame), ctx)


def test_one_condition_found_in_time_and_by_condition_is_one_true_row(payload_pickup):
    """The window before the pickup and the payload condition are the same finding: one
    row, worded so that it holds for the samples it names (exactly 0 kg is "<= 0 kg")."""
    frame, result = payload_pickup
    rows = [m.where for m in result.mismatches]
    assert len(rows) == len(set(rows)), rows
    payload = frame["payload_kg"].to_numpy()
    for m in result.mismatches:
        if "payload" in m.where:
            op, bound = m.where.split("payload ")[1].split()[:2]
            inside = (frame["t_s"] >= m.t_start_s) & (frame["t_s"] < m.t_end_s)
            holds = payload[inside] >= float(bound) if op == ">=" else \
                payload[inside] <= float(bound)
            assert op in (">=", "<=") and holds.mean() >= 0.75, (m, holds.mean())
    assert any("payload" in w for w in rows), rows


@pytest.mark.parametrize("windows", ["found", "many"])
def test_figure_shades_every_listed_window_in_seconds(payload_pickup, windows):
    """One bar per row of the table, long or short, and one time unit on every time axis."""
    import matplotlib.pyplot as plt

    from orange_plan.identify.locate import Mismatch
    from orange_plan.viz.diagnose_plot import diagnosis_figure

    _frame, result = payload_pickup
    if windows == "many":  # overlapping, run-wide and late windows, as a table may list
        result = replace(result, mismatches=[
            Mismatch(0.0, 40.0, -0.2, "while payload <= 0 kg"),
            Mismatch(0.0, 590.0, 0.05, "while speed >= 0.3 m/s"),
            Mismatch(100.0, 400.0, 0.1, "while |yaw rate| >= 0.1 rad/s"),
            Mismatch(560.0, 599.0, 0.3, "from t = 560 s to 599 s, a change in time")])
    fig = diagnosis_figure(result)
    try:
        bars = fig.findobj(lambda a: a.get_gid() == "located-window")
        assert len(bars) == len(result.mismatches) > 0
        spans = np.array(sorted((b.get_x(), b.get_x() + b.get_width()) for b in bars))
        listed = np.array(sorted((m.t_start_s, m.t_end_s) for m in result.mismatches))
        assert spans.shape == listed.shape and np.allclose(spans, listed)
        labels = [ax.get_xlabel() for ax in fig.axes if ax.get_xlabel()]
        assert not any("[min]" in label for label in labels), labels
        assert sum("time" in label and "[s]" in label for label in labels) >= 1
    finally:
        plt.close(fig)
