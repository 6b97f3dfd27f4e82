"""A sweep's summary (one row per scenario and grid point, over its seeds) and its figure."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from orange_plan.atomic import save_figure
from orange_plan.sim.flight import stranding_upper_bound


def summary_rows(rows: pd.DataFrame, grid_keys) -> list[dict]:
    """Per scenario and grid point: runs, errors, planner refusals, strandings (and the 95 %
    upper bound of the stranding probability), median coverage, energy left at home and run
    time."""
    keys = ["scenario", *grid_keys]
    out = []
    for group, sub in rows.groupby(keys, sort=False, dropna=False):
        group = group if isinstance(group, tuple) else (group,)
        ok = sub[sub["error"].isna()]
        stranded = ok["stranded"].astype(bool)
        home = ok.loc[~stranded, "energy_left_J"]
        out.append({**dict(zip(keys, group)), "runs": len(sub), "errors": len(sub) - len(ok),
                    "stayed_home": int((~ok["planned"].astype(bool)).sum()),
                    "strandings": int(stranded.sum()),
                    "stranding_upper95": stranding_upper_bound(int(stranded.sum()), len(ok)),
                    "coverage_m2": _median(ok["coverage_m2"]),
                    "energy_left_at_home_kJ": _median(home / 1e3),
                    "run_s": _median(sub["run_s"])})
    return out


def cell(value, spec: str) -> str:
    """A number for a table cell, formatted by ``spec``; ``-`` for a missing or non-finite one."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, spec)


def _median(values) -> float | None:
    values = pd.to_numeric(values, errors="coerce").dropna()
    return float(values.median()) if len(values) else None


def _show(value) -> str:
    """A grid value for a table cell: an inline table's JSON without braces and quotes."""
    text = str(value)
    return text.strip("{}").replace('"', "") if text.startswith("{") else text


def summary_table(summary: list[dict], grid_keys, title: str):
    """The terminal table (rich): the scenario column only when there are several."""
    from rich import box
    from rich.table import Table

    scenarios = {r["scenario"] for r in summary}
    keys = [*(["scenario"] if len(scenarios) > 1 else []), *grid_keys]
    if len(scenarios) == 1:
        title += f" of {next(iter(scenarios))}"
    t = Table(title=title, header_style="bold", box=box.SIMPLE_HEAD, caption="err: runs "
              "that failed; home: runs that stayed home (no tour fitted), each shown when not "
              "0; p95: 95 % upper bound of the stranding probability; left: median energy "
              "left at home of the runs that got home; medians over seeds")
    for col in keys:  # as wide as their values (up to 18), then they wrap; the figures not
        width = max(len(_show(r[col])) for r in summary)
        t.add_column(col.split(".")[-1], overflow="fold", min_width=min(width, 18),
                     max_width=max(min(width, 18), 8))
    counts = [(c, k) for c, k in (("err", "errors"), ("home", "stayed_home"))
              if any(r[k] for r in summary)]  # columns of zeros only are left out
    for col in (*(c for c, _ in counts), "runs", "strand", "p95", "cov m2", "left kJ", "run s"):
        t.add_column(col, justify="right", no_wrap=True, min_width=len(col))
    for r in summary:
        t.add_row(*(_show(r[k]) for k in keys), *(str(r[k]) for _, k in counts),
                  str(r["runs"]), str(r["strandings"]),
                  cell(r["stranding_upper95"], ".1%"), cell(r["coverage_m2"], ",.0f"),
                  cell(r["energy_left_at_home_kJ"], ".2f"), cell(r["run_s"], ".2f"))
    return t


def x_key(summary: list[dict], grid_keys) -> str | None:
    """The first grid key whose values are all numbers: the figure's x axis."""
    for key in grid_keys:
        if all(isinstance(r[key], (int, float)) and not isinstance(r[key], bool)
               for r in summary):
            return key
    return None


def sweep_figure(summary: list[dict], grid_keys, title: str, path) -> Path:
    """PNG: median coverage (top) and share of runs stranded (bottom) against the first
    numeric grid key (else against the grid points in order); one line per scenario and
    combination of the other grid keys."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = x_key(summary, grid_keys)
    others = [k for k in ("scenario", *grid_keys) if k != x]
    lines: dict[tuple, list[dict]] = {}
    for r in summary:
        lines.setdefault(tuple(r[k] for k in others), []).append(r)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 6.0), sharex=True)
    for label, group in lines.items():
        xs = [r[x] for r in group] if x else list(range(len(group)))
        name = ", ".join(_show(v) if k == "scenario" else f"{k.split('.')[-1]}: {_show(v)}"
                         for k, v in zip(others, label))
        cov = [math.nan if r["coverage_m2"] is None else r["coverage_m2"] for r in group]
        share = [100.0 * r["strandings"] / max(1, r["runs"] - r["errors"]) for r in group]
        top.plot(xs, cov, marker="o", label=name)
        bottom.plot(xs, share, marker="s", label=name)
    top.set_ylabel("median coverage [m²]")
    bottom.set_ylabel("runs stranded [%]")
    bottom.set_ylim(-3, 103)
    bottom.set_xlabel(x or "grid point")
    if x is None:
        bottom.set_xticks(range(max(len(g) for g in lines.values())))
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    top.legend(fontsize=7, loc="best")
    top.set_title(title)
    fig.tight_layout()
    return save_figure(fig, path)
