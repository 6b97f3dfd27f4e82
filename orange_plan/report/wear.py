"""Experiment 6, the paper's future work: wear and tear over many missions.

The paper's conclusion: the ORangE parameters are calibrated a priori, but as robots wear
they drift, and monitoring them is labour-intensive. Here a Rusti V2.0 on asphalt flies one
mission per battery cycle while its truth drifts with the mission count n (``DRIFT``):

* capacity fades with cycles faster than its datasheet says (true k1 vs the scenario's),
* rolling resistance grows (tyre and bearing wear, dirt),
* the ancillary draw grows (ageing regulators, a warmer, harder-working computer).

Every ``STEP``-th mission is simulated to depletion on the probe course. Three range
estimates are made for it:

* a-priori calibration: coefficients and usable energy calibrated on mission 0, then only the
  datasheet's capacity fade per cycle (Eq. 3) applied: the practice the paper describes;
* re-estimated between missions: the coefficients the online estimator ended the previous
  simulated mission with, and the usable energy that mission measured (it ran to depletion),
  faded by the datasheet rate over the missions since;
* online: the ``OnlineEstimator`` during the mission (from the re-estimated belief) at 20 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from orange_plan.atomic import save_figure
from orange_plan.context import load_context
from orange_plan.report.markdown import Section, Table
from orange_plan.report.trials import (
    LOGGER_HZ,
    Variation,
    advance,
    calibrate_on,
    cells_by,
    course_range_m,
    draw_truth,
    error_pct,
    online_ranges_m,
    run_to_depletion,
    with_belief,
)
from orange_plan.sim.ranges import lap_route

SCENARIO = "rusti_v2_asphalt_1500mAh_v0952"
MISSIONS = 300
STEP = 25
ONLINE_AT = 0.2
"""Fraction of a mission at which the in-mission online estimate is read."""


@dataclass(frozen=True)
class Drift:
    """How the truth wears with the mission count n (one mission per battery cycle).

    Attributes
    ----------
    k1_true_per_cycle : true capacity fade per cycle (the scenario's k1 is what is believed)
    rolling_growth_per_mission : rolling_kg x (1 + this n) [1/mission]
    ancillary_growth_per_mission : ancillary_W x (1 + this n) [1/mission]
    """

    k1_true_per_cycle: float = 0.0012
    rolling_growth_per_mission: float = 0.001
    ancillary_growth_per_mission: float = 0.0005

    def bias(self, n: int) -> dict[str, float]:
        """Coefficient multipliers after n missions."""
        return {"rolling_kg": 1.0 + self.rolling_growth_per_mission * n,
                "ancillary_W": 1.0 + self.ancillary_growth_per_mission * n}

    def capacity_factor(self, n: int, k1_believed: float) -> float:
        """True usable energy / the datasheet-faded belief after n cycles (Eq. 3) [-]."""
        return math.exp(-(self.k1_true_per_cycle - k1_believed) * n)


DRIFT = Drift()
VARIATION = Variation(coefficient_rel_sd=0.03, capacity_factor=1.0, capacity_rel_sd=0.02,
                      power_std_W=0.5, roughness_crr_std=0.002)
"""Mission-to-mission spread on top of the drift (no fixed bias: mission 0 is calibrated)."""

ESTIMATES = ("a-priori calibration", "re-estimated between missions", "online @20 %")
ESTIMATE_KEYS = ("stale", "reestimated", "online")


def missions() -> list[int]:
    """The simulated missions: 0, STEP, ..., MISSIONS."""
    return list(range(0, MISSIONS + 1, STEP))


def count(trials: int) -> int:
    """Progress items: one per simulated mission."""
    return trials * len(missions())


def run(scenario_dir: Path, trials: int, seed: int, tick=None) -> list[dict]:
    """Each trial is one robot flown through ``missions()``; one row per simulated mission."""
    base = load_context(Path(scenario_dir) / f"{SCENARIO}.toml")
    route = lap_route(base)
    k1 = base.scenario.battery.k1_per_cycle
    rows = []
    for trial in range(trials):
        rng = np.random.default_rng([seed, 6, trial])
        calibrated = learned = None  # (model, usable energy / the datasheet's at that cycle)
        for n in missions():
            ctx = with_belief(base, extra_cycles=n)  # the battery as the datasheet ages it
            truth = draw_truth(ctx, VARIATION, rng, DRIFT.bias(n))
            truth["battery"]["capacity_factor"] *= DRIFT.capacity_factor(n, k1)
            sim = run_to_depletion(ctx, route, truth, int(rng.integers(2**31)), LOGGER_HZ)
            if calibrated is None:  # mission 0: the a-priori calibration
                calibrated = learned = calibrate_on(ctx, [sim], "mission 0")
            current = with_belief(base, *learned, n)
            (online_m, _), est = online_ranges_m(current, sim, (ONLINE_AT, 1.0), batch_s=10.0)
            if n > 0:
                estimates = (course_range_m(with_belief(base, *calibrated, n), route),
                             course_range_m(current, route), online_m)
                rows.append({"trial": trial, "mission": n, "d_true_m": sim.distance_m,
                             "k1_believed_per_cycle": k1,
                             "capacity_true_pct": 100 * sim.energy_available_J
                             / base.scenario.battery.usable_J,
                             **{name: error_pct(d, sim.distance_m)
                                for name, d in zip(ESTIMATES, estimates)},
                             **{f"d_{key}_m": d for key, d in zip(ESTIMATE_KEYS, estimates)}})
            # between missions: what the whole mission just flown taught the estimator
            learned = (current.model.with_theta(dict(zip(current.model.names, est.theta_))),
                       est.energy_used_J / ctx.scenario.battery.usable_J)
            advance(tick)
    return rows


def cells(rows: list[dict]) -> list[dict]:
    """Per mission: true range and error statistics over trials."""
    return cells_by(rows, {"mission": missions()[1:]},
                    {"d_true_m": "d_true_m", "capacity_true_pct": "capacity_true_pct",
                     **{name: name for name in ESTIMATES}})


def section(rows: list[dict], figure: str, trials: int) -> Section:
    """The report section: drift, the per-mission table, the figure."""
    summary = cells(rows)
    bias = DRIFT.bias(MISSIONS)
    table = Table(
        f"Wear and tear: range estimation error % per mission, mean ± sd over {trials} "
        "robots (paper: future work, no number)",
        ["mission", "true usable energy, % of mission 0's datasheet value", "rolling x", "ancillary x",
         "true range m", *ESTIMATES],
        [[str(c["mission"]), f"{c['capacity_true_pct'].mean:.0f}",
          f"{DRIFT.bias(c['mission'])['rolling_kg']:.2f}",
          f"{DRIFT.bias(c['mission'])['ancillary_W']:.2f}", f"{c['d_true_m'].mean:,.0f}",
          *(c[name].text() for name in ESTIMATES)] for c in summary])
    last = summary[-1]
    text = [
        "The paper's conclusion names the open problem: ORangE's parameters are calibrated "
        "a priori, robots wear, and monitoring the parameters is labour-intensive. Here "
        f"`{SCENARIO}` flies one mission per battery cycle for {MISSIONS} missions while its "
        f"truth drifts: capacity fades at k1 = {DRIFT.k1_true_per_cycle:g} per cycle (the "
        "datasheet's, which the estimates apply, says "
        f"{rows[0]['k1_believed_per_cycle']:g}), rolling resistance x{bias['rolling_kg']:.2f} and the ancillary "
        f"draw x{bias['ancillary_W']:.2f} by mission {MISSIONS} (linear in n). Every "
        f"{STEP}th mission is simulated to depletion on the probe course; "
        f"mission-to-mission spread: {VARIATION.describe()}.",
        "Estimates: the a-priori calibration (fitted on mission 0, then only the "
        "datasheet's fade per cycle); re-estimated between missions (the online estimator's "
        "coefficients at the end of the previous simulated mission and the usable energy "
        "that mission measured, faded by the datasheet rate since); the online estimate "
        f"during the mission at {100 * ONLINE_AT:.0f} %.",
        f"By mission {last['mission']}: a-priori calibration off by "
        f"{last[ESTIMATES[0]].mean:.1f} %, re-estimated {last[ESTIMATES[1]].mean:.1f} %, "
        f"online {last[ESTIMATES[2]].mean:.1f} %.",
    ]
    data = {"missions": [{"mission": c["mission"], "d_true_m": c["d_true_m"].mean,
                          **{name: c[name].mean for name in ESTIMATES}} for c in summary]}
    return Section("6. Future work: wear and tear over many missions", text, [table], figure,
                   data)


def plot(rows: list[dict], path: Path) -> Path:
    """Range against mission number (true and the three estimates) and the errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = cells(rows)
    n = np.array([c["mission"] for c in summary])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    top.plot(n, [c["d_true_m"].mean for c in summary], "k-o", label="true range (depletion)")
    colours = ("tab:red", "tab:green", "tab:blue")
    for name, key, colour in zip(ESTIMATES, ESTIMATE_KEYS, colours):
        top.plot(n, [np.mean([r[f"d_{key}_m"] for r in rows if r["mission"] == m]) for m in n],
                 "--o", color=colour, ms=4, label=name)
        mean = np.array([c[name].mean for c in summary])
        sd = np.nan_to_num(np.array([c[name].sd for c in summary]))
        bottom.plot(n, mean, "-o", color=colour, ms=4, label=name)
        bottom.fill_between(n, mean - sd, mean + sd, color=colour, alpha=0.15)
    top.set_ylabel("operational range [m]")
    top.set_title(f"Wear and tear: {SCENARIO}, one mission per battery cycle", fontsize=10)
    top.legend(fontsize=8)
    bottom.set_ylabel("range estimation error [%]")
    bottom.set_xlabel("mission (battery cycle since calibration)")
    bottom.set_ylim(bottom=0)
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)
