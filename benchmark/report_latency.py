"""The latency section of a report: success and NWT against latency, and each controller's budget.

A controller's **latency budget** in a cell is the largest latency at which it still walks with
success >= 0.8 (and at every smaller latency too: one lucky cell after a failing one does not
extend it); "none" when it does not even at the smallest latency tried.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

BUDGET_SUCCESS = 0.8


def latency_curves(group: pd.DataFrame) -> pd.DataFrame:
    """One row per controller, robot, terrain and latency: success with its Wilson interval, NWT mean and 95% CI."""
    from benchmark.report import wilson  # report imports this module

    frame = group.assign(latency_s=group["latency"].astype(float))
    rows = []
    for (controller, robot, terrain, latency), g in frame.groupby(["controller", "robot", "terrain", "latency_s"],
                                                                   sort=False):
        n, k = len(g), int(g["success"].sum())
        low, high = wilson(k, n)
        nwt = g["nwt"].to_numpy(float)
        half = 1.96 * nwt.std(ddof=1) / np.sqrt(n) if n > 1 else 0.0
        rows.append({"controller": controller, "robot": robot, "terrain": terrain, "latency_s": latency, "trials": n,
                     "success": k / n, "success_low": low, "success_high": high, "nwt": float(nwt.mean()),
                     "nwt_half_ci": float(half)})
    return pd.DataFrame(rows).sort_values(["controller", "robot", "terrain", "latency_s"]).reset_index(drop=True)


def budgets(curves: pd.DataFrame) -> pd.DataFrame:
    """The latency budget per controller (rows) and cell (columns)."""
    out = {}
    for (controller, robot, terrain), g in curves.groupby(["controller", "robot", "terrain"], sort=False):
        budget = None
        for latency, success in zip(g["latency_s"], g["success"]):
            if success < BUDGET_SUCCESS:
                break
            budget = latency
        out.setdefault(controller, {})[f"{robot}/{terrain}"] = (
            f"{budget:g} s" if budget is not None else f"none (< {BUDGET_SUCCESS:g} at {g['latency_s'].min():g} s)")
    return pd.DataFrame(out).T.rename_axis("controller").reset_index()


def latency_figure(curves: pd.DataFrame, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = list(dict.fromkeys(zip(curves["robot"], curves["terrain"])))
    fig, axes = plt.subplots(2, len(cells), figsize=(3.2 * len(cells), 5.6), sharex=True, sharey=True, squeeze=False)
    for col, (robot, terrain) in enumerate(cells):
        part = curves[(curves["robot"] == robot) & (curves["terrain"] == terrain)]
        for controller, g in part.groupby("controller", sort=False):
            x = g["latency_s"].to_numpy()
            line, = axes[0, col].plot(x, g["success"], marker="o", ms=3, label=controller)
            axes[0, col].fill_between(x, g["success_low"], g["success_high"], color=line.get_color(), alpha=0.15)
            axes[1, col].errorbar(x, g["nwt"], yerr=g["nwt_half_ci"], marker="o", ms=3, capsize=2,
                                  color=line.get_color())
        axes[0, col].axhline(BUDGET_SUCCESS, color="grey", lw=0.8, ls=":")
        axes[0, col].set_title(f"{robot} / {terrain}", fontsize=9)
        axes[1, col].set_xlabel("latency (s)")
        axes[1, col].set_xscale("symlog", linthresh=0.05)
    axes[0, 0].set_ylabel("success (Wilson 95%)")
    axes[1, 0].set_ylabel("NWT (mean, 95% CI)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Realtime clock: the robot holds its targets while a query is in flight", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def latency_section(group: pd.DataFrame, out: Path, name: str) -> tuple[list[str], list[Path]]:
    """Markdown lines and figures for a store with a latency axis (empty when it has none)."""
    from benchmark.report import axes_of, to_markdown

    if "latency" not in axes_of(group):
        return [], []
    curves = latency_curves(group)
    figure = latency_figure(curves, out / "figures" / f"{name}_curves.png")
    lines = ["## Latency budget", "",
             f"The largest latency at which a controller still walks with success >= {BUDGET_SUCCESS:g} (at every "
             "smaller latency too), per cell:", "", to_markdown(budgets(curves)), "",
             "Latencies act in whole control periods: an answer takes effect at the first 10 Hz step at or after "
             "it arrives, so 0.05 s and 0.1 s both hold each target for one period and give the same trials.", "",
             f"![latency curves](figures/{figure.name})", ""]
    return lines, [figure]
