"""The latency section of a report: success and NWT against latency, and each controller's budget.

A controller's **latency budget** in a cell is the largest latency at which it still walks with
success >= 0.8 (and at every smaller latency too: one lucky cell after a failing one does not
extend it); "none" when it does not even at the smallest latency tried.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.common.figures import save_figure
from benchmark.common.tables import to_markdown, wilson
from benchmark.experiments.experiment import axes_of

BUDGET_SUCCESS = 0.8


def latency_curves(group: pd.DataFrame) -> pd.DataFrame:
    """One row per controller, robot, terrain and latency: success with its Wilson interval, NWT mean and 95% CI."""
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


def budget_of(curve: pd.DataFrame) -> float | None:
    """One controller's budget in one cell, from its curve sorted by latency (None: not even the smallest)."""
    budget = None
    for latency, success in zip(curve["latency_s"], curve["success"]):
        if success < BUDGET_SUCCESS:
            break
        budget = float(latency)
    return budget


def budgets(curves: pd.DataFrame) -> pd.DataFrame:
    """The latency budget per controller (rows) and cell (columns)."""
    out = {}
    for (controller, robot, terrain), g in curves.groupby(["controller", "robot", "terrain"], sort=False):
        budget = budget_of(g)
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
    return save_figure(fig, path, dpi=110)


def latency_section(group: pd.DataFrame, out: Path, name: str) -> tuple[list[str], list[Path]]:
    """Markdown lines and figures for a store with a latency axis (empty when it has none)."""
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


LATENCY_STORE = Path("reports") / "data" / "latency.parquet"


def seed_policy_budget(robot: str, terrain: str, store: Path = LATENCY_STORE) -> float | None:
    """The seed policy's latency budget in a cell, from the committed latency experiment (None: unknown or none)."""
    if not store.is_file():
        return None
    frame = pd.read_parquet(store)
    frame = frame[(frame["controller"] == "seed_policy") & (frame["robot"] == robot) & (frame["terrain"] == terrain)]
    return None if frame.empty else budget_of(latency_curves(frame))


def realtime_section(group: pd.DataFrame) -> list[str]:
    """For trials on the realtime clock with measured latency: when each fell, its latency and real-time
    factor, and how much faster the model must answer to fit the seed policy's latency budget."""
    if "latency" not in group or "clock" not in group:
        return []
    live = group[(group["clock"] == "realtime") & (group["latency"].astype(str) == "measured")]
    if live.empty:
        return []
    rows = []
    for _, t in live.iterrows():
        fall = t.get("fall_time")
        held = t.get("mean_held_steps")
        latencies = np.asarray(t["query_latencies_s"], dtype=float)
        rows.append({"robot": t["robot"], "terrain": t["terrain"], "seed": int(t["seed"]), "queries": len(latencies),
                     "mean latency (s)": round(float(latencies.mean()), 2) if len(latencies) else None,
                     "p95 (s)": round(float(np.percentile(latencies, 95)), 2) if len(latencies) else None,
                     "real-time factor": round(float(t["control_dt"] / latencies.mean()), 3) if len(latencies) else None,
                     "steps per target": round(float(held), 1) if held is not None and held == held else None,
                     "fell after (s)": "-" if fall is None or fall != fall else round(float(fall - t["eval_start"]), 1),
                     "NWT": round(float(t["nwt"]), 3), "success": bool(t["success"]),
                     "load (1 min)": round(float(t["load_1m"]), 2) if t.get("load_1m") is not None else None})
    table = pd.DataFrame(rows)
    lines = ["## On the real clock (measured latency)", "",
             "Each query's own wall time is its latency: the robot holds its last targets until the answer arrives. "
             "The real-time factor is the control period (0.1 s) over the mean latency (1 would keep up); "
             "'fell after' counts from the model's takeover. Load is the machine's 1-minute load average as the "
             "trial ended (2 cores here: above ~2, other work shared them and latencies are inflated).", "",
             to_markdown(table.dropna(axis=1, how="all")), ""]
    for (robot, terrain), g in table.groupby(["robot", "terrain"], sort=False):
        budget, mean = seed_policy_budget(robot, terrain), float(g["mean latency (s)"].mean())
        falls = [x for x in g["fell after (s)"] if x != "-"]
        fell = (f"{len(falls)} of {len(g)} trials fell, after {min(falls):g}-{max(falls):g} s" if falls
                else f"none of {len(g)} trials fell")
        fell += f", mean NWT {g['NWT'].mean():.2f}" + (" (it stopped walking, holding its targets)"
                                                        if g["NWT"].max() == 0 else "")
        if budget:
            need = f"the seed policy's latency budget here is {budget:g} s, so the model must answer {mean / budget:.0f}x faster"
        elif budget == 0:
            need = ("the seed policy's latency budget here is 0 s: even one held control period (0.1 s) stops it "
                    f"walking, so no measured latency fits; keeping up at all needs answers {mean / 0.1:.0f}x faster")
        else:
            need = "the seed policy has no latency budget here in the committed latency experiment"
        lines += [f"- {robot}/{terrain}: {fell}; mean latency {mean:.2f} s; {need}.", ""]
    return lines
