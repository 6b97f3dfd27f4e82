"""Experiment 2: Rusti V2.0 outdoors, generalised ORangE error per surface x battery x speed.

The paper's grid: grass, asphalt and tile; b1 = 1500 mAh and b2 = 2200 mAh packs; v1 = 0.544
and v2 = 0.952 m/s (its figure, not in the source; no number in the text). The twelve shipped
scenarios ``rusti_v2_<surface>_<pack>mAh_v<speed>`` are driven on the a-priori probe course
of ``bench online`` (``sim.ranges.lap_route``: out-and-back rays from home, one lap at
most 10 % of the range) until the battery is spent.

Estimates: the generalised offline ORangE (Eq. 11, path integral on the course) a priori and
calibrated on ``CALIBRATION_RUNS`` drives per surface with b1 at v1 (coefficients fitted on
their recordings; their measured usable energy / the b1 scenario's, taken as both packs'
state of health).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from orange_plan.atomic import save_figure
from orange_plan.context import load_context
from orange_plan.report import rusti_v1
from orange_plan.report.markdown import Section, Table
from orange_plan.report.trials import (
    CALIBRATION_RUNS,
    Variation,
    advance,
    calibrate_on,
    calibration_runs,
    cells_by,
    course_range_m,
    draw_truth,
    error_pct,
    run_to_depletion,
    with_belief,
)
from orange_plan.sim.ranges import lap_route

SURFACES = ("grass", "asphalt", "tile")
PACKS = {"b1": "1500mAh", "b2": "2200mAh"}
SPEEDS = {"v1": "v0544", "v2": "v0952"}
SPEED_MPS = {"v1": 0.544, "v2": 0.952}

VARIATION = Variation(bias={"ancillary_W": 1.05, "turn_J_per_rad": 1.5},
                      coefficient_rel_sd=0.05, capacity_factor=0.92, capacity_rel_sd=0.04,
                      power_std_W=0.5, roughness_crr_std=0.005)
"""Outdoors against the datasheet: skid-steer scrub 50 % higher, electronics +5 %, packs at
92 % of nominal; rolling per surface in ``SURFACE_ROLLING``."""

SURFACE_ROLLING = {"grass": 1.33, "asphalt": 1.10, "tile": 0.95}
"""True / assumed rolling resistance per surface: wet, longer grass rolls a third harder."""


def scenario_name(surface: str, pack: str, speed: str) -> str:
    return f"rusti_v2_{surface}_{PACKS[pack]}_{SPEEDS[speed]}"


def count(trials: int) -> int:
    """Progress items: one per run to depletion (calibration drives included)."""
    return len(SURFACES) * (CALIBRATION_RUNS + len(PACKS) * len(SPEEDS) * trials)


def run(scenario_dir: Path, trials: int, seed: int, tick=None) -> list[dict]:
    """Every surface x pack x speed x trial: true range and both estimates (rows)."""
    rows = []
    for k, surface in enumerate(SURFACES):
        rng = np.random.default_rng([seed, 2, k])
        surface_bias = {"rolling_kg": SURFACE_ROLLING[surface]}
        cal_ctx = load_context(Path(scenario_dir) / f"{scenario_name(surface, 'b1', 'v1')}.toml")
        cal_route = lap_route(cal_ctx)
        fitted, energy_factor = calibrate_on(
            cal_ctx, calibration_runs(cal_ctx, cal_route, VARIATION, rng, surface_bias),
            f"{surface} calibration drive")
        advance(tick, CALIBRATION_RUNS)
        for pack in PACKS:
            for speed in SPEEDS:
                ctx = load_context(Path(scenario_dir) / f"{scenario_name(surface, pack, speed)}.toml")
                route = lap_route(ctx)
                prior_m = course_range_m(ctx, route)
                calibrated_m = course_range_m(with_belief(ctx, fitted, energy_factor), route)
                for trial in range(trials):
                    sim = run_to_depletion(ctx, route, draw_truth(ctx, VARIATION, rng, surface_bias),
                                           int(rng.integers(2**31)))
                    rows.append({"surface": surface, "pack": pack, "speed": speed,
                                 "trial": trial, "d_true_m": sim.distance_m,
                                 "error_prior_pct": error_pct(prior_m, sim.distance_m),
                                 "error_calibrated_pct": error_pct(calibrated_m,
                                                                   sim.distance_m)})
                    advance(tick)
    return rows


def cells(rows: list[dict]) -> list[dict]:
    """Per surface x pack x speed: mean true range and error statistics."""
    return cells_by(rows, {"surface": SURFACES, "pack": PACKS, "speed": SPEEDS},
                    rusti_v1.MEASURES)


def section(rows: list[dict], figure: str, trials: int) -> Section:
    """The report section: text, the 12-cell table, the figure."""
    summary = cells(rows)
    table = Table(
        f"Rusti V2.0: range estimation error per surface x battery x speed, mean ± sd over "
        f"{trials} trials (paper: figure only, no number in the text)",
        ["surface", "battery", "speed", "true range m", "generalised ORangE a priori: error %",
         "calibrated: error %"],
        [[c["surface"], f"{c['pack']} ({PACKS[c['pack']]})",
          f"{c['speed']} ({SPEED_MPS[c['speed']]:g} m/s)",
          f"{c['d_true_m'].mean:,.0f}", c["prior"].text(), c["calibrated"].text()]
         for c in summary])
    text = [
        "The paper drove Rusti V2.0 on grass, asphalt and tile with two packs (b1 = 1500 "
        "mAh, b2 = 2200 mAh) at two speeds (v1 = 0.544, v2 = 0.952 m/s) and shows the "
        "generalised ORangE's error in a figure without numbers. Here the twelve shipped "
        "scenarios run to depletion on the probe course of `bench online`.",
        f"Truth: {VARIATION.describe()}; rolling_kg x "
        + ", ".join(f"{s} {f:g}" for s, f in SURFACE_ROLLING.items()) + ".",
        f"Calibrated: coefficients fitted on {CALIBRATION_RUNS} drives to depletion per "
        "surface with b1 at v1 (fresh truth draws), their mean measured usable energy taken "
        "as both packs' state of health.",
    ]
    data = {"cells": [{"surface": c["surface"], "pack": c["pack"], "speed": c["speed"],
                       "d_true_m": c["d_true_m"].mean,
                       "error_prior_pct": c["prior"].mean,
                       "error_calibrated_pct": c["calibrated"].mean} for c in summary]}
    return Section("2. Rusti V2.0 outdoors: surface x battery x speed", text, [table], figure,
                   data)


def plot(rows: list[dict], path: Path) -> Path:
    """Grouped bars per surface: the four b/v cells, a priori and calibrated (mean ± sd)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = cells(rows)
    fig, axes = plt.subplots(1, len(SURFACES), figsize=(12, 4), sharey=True)
    x = np.arange(len(PACKS) * len(SPEEDS))
    for ax, surface in zip(axes, SURFACES):
        mine = [c for c in summary if c["surface"] == surface]
        for offset, key, colour, name in ((-0.2, "prior", "tab:red", "a priori"),
                                          (0.2, "calibrated", "tab:blue", "calibrated")):
            ax.bar(x + offset, [c[key].mean for c in mine], 0.4,
                   yerr=np.nan_to_num([c[key].sd for c in mine]), color=colour, capsize=3,
                   label=name)
        ax.set_xticks(x, [f"{c['pack']}{c['speed']}" for c in mine])
        ax.set_title(f"Rusti V2.0 on {surface}", fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("range estimation error [%]")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
