"""Figure of ``orange-plan bench flights``: each method's energy error per flight."""

from __future__ import annotations

from pathlib import Path

METHOD_STYLE = {"recording": ("from the recording", "tab:green", "o"),
                "route": ("from the planned route", "tab:blue", "s"),
                "per_metre": ("energy per metre x length", "tab:orange", "^"),
                "power_time": ("mean power x planned time", "tab:red", "v")}


def plot_check(rows: list[dict], path: Path) -> Path:
    """Error [%] of each method per flight (sorted by recorded energy); flights flown at
    transit speed are shaded and labelled, not dropped."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from orange_plan.atomic import atomic_path

    order = sorted(rows, key=lambda r: r["recorded_J"])
    x = range(len(order))
    fig, ax = plt.subplots(figsize=(11, 4.5))
    for method, (label, colour, marker) in METHOD_STYLE.items():
        ax.plot(x, [r[f"{method}_err_pct"] for r in order], marker, color=colour, ms=4,
                label=label)
    for i, r in enumerate(order):
        if r["speed_anomaly"]:
            ax.axvspan(i - 0.5, i + 0.5, color="0.85", zorder=0)
            ax.annotate("transit speed", (i, 0), rotation=90, fontsize=7, ha="center")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel("flight (by recorded energy)")
    ax.set_ylabel("predicted - recorded energy [%]")
    ax.set_ylim(-40, 60)
    ax.legend(fontsize=8, ncol=4)
    ax.set_title("DJI M100 survey flights, leave-one-route-out")
    fig.tight_layout()
    with atomic_path(Path(path), suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return Path(path)
