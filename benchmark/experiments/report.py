"""Comparison tables and figures from a results store.

    bench report results/normalization                 # reports/normalization.md + figures
    bench report results/cross_engine --format html

One table per experiment in the paper's shape: a row per cell of the grid with the trial
count, normalized walking time (NWT), success rate, speed and drift, and for LLM cells the
input/output tokens (the model's and GPT-4's), parse failures and latency. When engines are
an axis, a second table puts them side by side. Figures (PNG, in OUT/figures): bars of NWT
and success per cell, and the front-left leg's joint trajectories of the seed policy against
the LLM (or across engines when there is no LLM).
"""

from __future__ import annotations

import hashlib
import json
import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.common.figures import save_figure
from benchmark.common.fingerprint import describe
from benchmark.common.tables import ended_at_stop, fell_before_takeover, live_latency_mean, to_markdown, wilson
from benchmark.experiments.experiment import Experiment, ExperimentError, axes_of, load_experiment
from benchmark.experiments.report_latency import latency_section, realtime_section
from benchmark.experiments.report_ablation import ablation_section
from benchmark.experiments.report_matrix import matrix_section
from benchmark.experiments.report_prompting import (diagnostics_section, probe_section, split_probe_rows, step_times,
                                                     study_section)
from robots import load_robot

FORMATS = ("md", "html", "csv")
METRICS = {  # column in the store -> (heading, aggregation, digits)
    "nwt": ("NWT", "mean", 3),
    "success": ("success rate", "mean", 2),
    "upright_fraction": ("upright", "mean", 2),
    "mean_vx": ("vx (m/s)", "mean", 2),
    "distance_m": ("distance (m)", "mean", 2),
    "abs_drift_m": ("|drift| (m)", "mean", 2),
    "abs_heading_change_rad": ("|heading change| (rad)", "mean", 2),
    "knn_agreement": ("kNN agreement", "mean", 2),
    "repeated_targets": ("repeated targets", "mean", 2),
    "input_tokens": ("input tokens", "mean", 0),
    "output_tokens": ("output tokens", "mean", 0),
    "gpt4_input_tokens": ("GPT-4 input tokens", "mean", 0),
    "gpt4_output_tokens": ("GPT-4 output tokens", "mean", 0),
    "parse_failures": ("parse failures", "sum", 0),
    "queries": ("queries", "sum", 0),
    "latency_mean_s": ("latency (s)", "live", 2),
}
AGGREGATIONS = {"mean": "mean", "sum": lambda x: x.sum(min_count=1)}  # a sum over no values is "-", not 0
# "live": seconds a query weighted by each trial's live queries (cached replies carry no latency)
LEG = "FL"  # the leg the trajectory figure shows, as in the paper


def axis_text(value) -> str:
    """An axis value as tables, figures and the `[paper]` table write it: "-" where the cell's policy does
    not use the setting, numbers as written (a column with gaps holds history 10 as 10.0)."""
    if pd.isna(value):
        return "-"
    return f"{value:g}" if isinstance(value, float) else str(value)


def _with_axis_text(frame: pd.DataFrame, axes: list[str]) -> pd.DataFrame:
    """Axis values as text (groupby drops NaN keys, so "-" keeps the cells that ignore a setting)."""
    return frame.assign(**{a: frame[a].map(axis_text) for a in axes})


INTERVALS = ("success",)  # rates shown with a Wilson 95% interval; other means with +- one std
SPREAD = ("nwt", "mean_vx", "distance_m")


def _with_spread(values: pd.Series, key: str, digits: int) -> str:
    values = values.dropna().astype(float)
    if values.empty:
        return "-"
    mean = values.mean()
    if key in INTERVALS:
        low, high = wilson(int(values.sum()), len(values))
        return f"{mean:.{digits}f} [{low:.2f}, {high:.2f}]"
    return f"{mean:.{digits}f} ± {values.std(ddof=1) if len(values) > 1 else 0.0:.{digits}f}"


def repeated_targets(row: pd.Series) -> float:
    """For an LLM trial, the fraction of its evaluated control steps whose joint targets equal the
    previous step's: 1.0 for a model stuck on one reply (as `hold` is by design), near 0 for a gait.
    It tells a frozen model from a copying one where `knn_agreement` cannot: in a frozen state the
    nearest example's answer is often the frozen action itself. NaN for other policies."""
    if row.get("policy") != "llm" or not isinstance(row.get("traj_joint_target"), (list, np.ndarray)):
        return float("nan")
    targets = np.array([np.asarray(step, dtype=float) for step in row["traj_joint_target"]])
    phase = targets[step_times(row, len(targets)) > float(row["eval_start"]) + 1e-9]
    if len(phase) < 2:
        return float("nan")
    return float(np.all(np.diff(phase, axis=0) == 0.0, axis=1).mean())


def summary_table(frame: pd.DataFrame, spread: bool = True) -> pd.DataFrame:
    """One row per cell: trial count and the mean (or sum) of every metric present; with `spread`,
    rates carry their 95% Wilson interval and NWT, speed and distance their standard deviation.
    Trials that fell before the takeover are left out of `trials` and every metric, and counted in a
    column of their own (present when any did)."""
    early = fell_before_takeover(frame)
    frame = frame.assign(abs_drift_m=frame["lateral_drift_m"].abs(), counted=~early, early=early)
    if "traj_joint_target" in frame:
        frame = frame.assign(repeated_targets=frame.apply(repeated_targets, axis=1))
    if "heading_change_rad" in frame:
        frame = frame.assign(abs_heading_change_rad=frame["heading_change_rad"].abs())
    axes = axes_of(frame)
    present = {k: v for k, v in METRICS.items() if k in frame and frame[k].notna().any()}
    if early.any():  # blank what they measured: means and sums skip NaN
        frame = frame.astype({k: float for k in present if frame[k].dtype == bool})
        frame.loc[early, list(present)] = np.nan
    grouped = _with_axis_text(frame, axes).groupby(axes, sort=False)
    table = grouped.agg(trials=("counted", "sum"), **({"fell_before_takeover": ("early", "sum")} if early.any() else {}),
                        **{k: (k, AGGREGATIONS[agg]) for k, (_, agg, _) in present.items() if agg != "live"})
    if "latency_mean_s" in present:
        weights = [c for c in ("latency_mean_s", "queries", "cache_hits") if c in frame]
        table["latency_mean_s"] = grouped[weights].apply(live_latency_mean)
    for key, (_, _, digits) in present.items():
        table[key] = table[key].round(digits)
    if spread:
        for key in [k for k in (*INTERVALS, *SPREAD) if k in present]:
            digits = present[key][2]
            table[key] = grouped[key].apply(lambda v, k=key, d=digits: _with_spread(v, k, d))
    table = table.rename(columns={k: heading for k, (heading, _, _) in present.items()})
    return table.rename(columns={"fell_before_takeover": EARLY}).reset_index()


def engine_table(frame: pd.DataFrame) -> pd.DataFrame | None:
    """Engines side by side ("success / NWT" per engine) when the grid has engines and other axes."""
    axes = axes_of(frame)
    if "sim" not in axes or len(axes) < 2:
        return None
    rest = [a for a in axes if a != "sim"]
    cells = _with_axis_text(frame, axes).groupby([*rest, "sim"], sort=False).agg(success=("success", "mean"), nwt=("nwt", "mean"))
    text = cells.apply(lambda r: f"{r['success']:.2f} / {r['nwt']:.2f}", axis=1).rename("success / NWT")
    wide = text.unstack("sim")
    order = [s for s in frame["sim"].unique() if s in wide.columns]
    return wide[order].fillna("-").reset_index()


EARLY = "fell before takeover (apart)"
HEADLINE = ("trials", EARLY, "NWT", "success rate", "distance (m)")


def headline_table(table: pd.DataFrame) -> pd.DataFrame:
    """The few columns that answer the question: the grid axes, then trials, NWT, success and distance."""
    metric_headings = {heading for heading, _, _ in METRICS.values()} | {"trials", EARLY}
    axes = [c for c in table.columns if c not in metric_headings]
    return table[[*axes, *[c for c in HEADLINE if c in table.columns]]]


def paper_table(frame: pd.DataFrame, paper: dict) -> pd.DataFrame | None:
    """The paper's figures per value of its axis, beside this store's: success / NWT of each LLM
    controller, and the GPT-4 token counts of this store's prompts (cl100k)."""
    axis = paper.get("axis")
    names = {"nwt": "NWT", "success": "success", "gpt4_input_tokens": "GPT-4 input tokens",
             "gpt4_output_tokens": "GPT-4 output tokens"}
    if not axis or axis not in frame or not any(m in paper for m in names):  # findings alone: nothing to print here
        return None
    llm = frame[frame["policy"] == "llm"]
    if "cell_index" in llm:  # grid order, not the store's file order (trial ids are hashes)
        llm = llm.sort_values(["cell_index", "seed"], kind="stable")
    who = "controller" if "controller" in llm and llm["controller"].notna().any() else "model"
    rows = []
    for value in dict.fromkeys(llm[axis].dropna()):
        key, cell = axis_text(value), llm[llm[axis] == value]
        row = {axis: key, **{f"paper {names[m]}": paper[m].get(key, np.nan) for m in names if m in paper}}
        for name, trials in cell.groupby(who, sort=False):
            row[f"{name}: success / NWT"] = f"{trials['success'].mean():.2f} / {trials['nwt'].mean():.3f}"
        for m in ("gpt4_input_tokens", "gpt4_output_tokens"):
            if m in paper and m in cell:
                row[f"ours: {names[m]}"] = round(float(cell[m].mean()))
        rows.append(row)
    return pd.DataFrame(rows) if rows else None


def bar_figure(frame: pd.DataFrame, table: pd.DataFrame, path: Path, title: str, paper: dict | None = None) -> Path:
    """NWT and success rate per cell, as bars grouped by the other axes, one colour per engine (when
    engines are an axis) or per controller (an ablation beside its reference rows). A controller that
    does not use the ablated setting (the seed policy) is a dashed line across the panel; the paper's
    figures (the experiment's `[paper]` table), where it gives them, are black crosses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes = axes_of(frame)
    hue = next((a for a in ("sim", "controller") if a in axes and len(axes) > 1), None)
    groups = [a for a in axes if a != hue]
    labels = table[groups].astype(str).agg("\n".join, axis=1) if groups else pd.Series(["all"] * len(table))
    flat = labels.str.fullmatch(r"[-\n]+") if hue == "controller" else labels.map(lambda _: False)
    x_labels = list(dict.fromkeys(labels[~flat]))
    hues = list(dict.fromkeys(table.loc[~flat, hue])) if hue else [None]
    fig, panels = plt.subplots(1, 2, figsize=(max(6.0, 1.1 * len(x_labels) * max(1, len(hues)) ** 0.5 + 3), 3.6),
                               constrained_layout=True)
    width = 0.8 / len(hues)
    for panel, metric in zip(panels, ("NWT", "success rate")):
        for i, h in enumerate(hues):
            rows = table[~flat] if h is None else table[~flat & (table[hue] == h)]
            row_labels = labels[rows.index]
            xs = [x_labels.index(label) + (i - (len(hues) - 1) / 2) * width for label in row_labels]
            panel.bar(xs, rows[metric], width=width * 0.95, label=h)
        for _, row in table[flat].iterrows():
            panel.axhline(float(row[metric]), color="k", ls="--", lw=1, label=f"{row[hue]} (all cells)")
        published = (paper or {}).get({"NWT": "nwt", "success rate": "success"}[metric], {})
        if published and groups == [paper.get("axis")]:
            marks = [(i, published[label]) for i, label in enumerate(x_labels) if label in published]  # labels: axis_text
            if marks:
                panel.plot(*zip(*marks), "kx", ms=9, mew=2, label=paper.get("source", "paper"))
        panel.set_xticks(range(len(x_labels)), x_labels, fontsize=8)
        panel.set_ylim(0, 1.05)
        panel.set_title(metric)
        panel.grid(axis="y", alpha=0.3)
    if hue:
        fig.legend(*panels[0].get_legend_handles_labels(), loc="outside right center", fontsize=8,
                   title={"sim": "engine"}.get(hue, hue), title_fontsize=8)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path, dpi=120, tight=False)


def trajectory_figure(frame: pd.DataFrame, path: Path) -> Path | None:
    """The front-left leg's joint angles over one trial: the seed policy against the best LLM cell
    (same engine, robot, terrain, seed); without LLM trials, the first seed across cells."""
    from robots import CANONICAL_JOINTS

    if "traj_joint_pos" not in frame:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = frame.sort_values("seed").iloc[0]
    same = frame[(frame["robot"] == first["robot"]) & (frame["terrain"] == first["terrain"])
                 & (frame["seed"] == first["seed"])]
    llm = same[same["policy"] == "llm"]
    if not llm.empty:
        llm_cells = frame[(frame["policy"] == "llm") & frame["cell_id"].isin(llm["cell_id"])]
        best_cell = llm_cells.groupby("cell_id")["nwt"].mean().idxmax()  # among the cells this seed's trial ran
        best = llm[llm["cell_id"] == best_cell]
        chosen = pd.concat([same[(same["policy"] != "llm") & (same["sim"] == best["sim"].iloc[0])], best])
    else:
        chosen = same.drop_duplicates("cell_id").head(6)
    axes = axes_of(frame)
    joints = [i for i, name in enumerate(CANONICAL_JOINTS) if name.startswith(LEG + "_")]
    fig, panels = plt.subplots(len(joints), 1, figsize=(8, 6), sharex=True, constrained_layout=True)
    for _, row in chosen.iterrows():
        q = np.array([np.asarray(step) for step in row["traj_joint_pos"]])
        t = step_times(row, len(q))
        label = " ".join(str(row[a]) for a in axes if str(row[a]) not in ("None", "nan"))
        for panel, j in zip(panels, joints):
            panel.plot(t, q[:, j], lw=1.2, label=label)
            panel.set_ylabel(f"{CANONICAL_JOINTS[j]} (rad)", fontsize=8)
        if row["policy"] == "llm":
            for panel in panels:
                panel.axvline(row["eval_start"], color="k", ls=":", lw=1)
    takeover = float(chosen["eval_start"].max())
    panels[-1].set_xlim(*((takeover - 2.0, takeover + 3.0) if takeover > 0 else (0.0, 5.0)))
    panels[0].legend(fontsize=8, ncols=3)
    panels[-1].set_xlabel("time (s)")
    fig.suptitle(f"{LEG} leg joint positions: {first['robot']} / {first['terrain']}, seed {first['seed']}"
                 + (" (dotted: LLM takes over)" if not llm.empty else ""), fontsize=10)
    return save_figure(fig, path, dpi=120, tight=False)


@dataclass(frozen=True)
class StoreContext:
    """What a report says around its table: the experiment's title, the commands that filled the store,
    the paper's figures, and a warning when the store holds fewer trials than the shipped grid."""

    title: str
    commands: list[str]
    paper: dict
    partial: str = ""
    experiment: Experiment | None = None  # None: not a shipped experiment, nor a file a stored command names


def _experiment_of(name: str, commands: list[str]):
    """The experiment `name`: a shipped one, else the `.toml` file a stored sweep command ran (a user's own grid),
    when it still exists and carries that name; None when neither is found."""
    try:
        return load_experiment(name)
    except ExperimentError:
        pass
    for path in dict.fromkeys(w for c in commands for w in c.split() if w.endswith(".toml")):
        try:
            experiment = load_experiment(path) if Path(path).is_file() else None
        except ExperimentError:
            continue
        if experiment is not None and experiment.name == name:
            return experiment
    return None


def store_context(name: str, frame: pd.DataFrame) -> StoreContext:
    """The context of experiment `name`'s rows in `frame` (an unknown experiment: its name, no figures)."""
    commands = [c for c in frame.get("sweep_command", pd.Series(dtype=str)).dropna().unique()]
    experiment = _experiment_of(name, commands)
    if experiment is None:
        return StoreContext(name, commands, {})
    expected = {t.id for t in experiment.trials()}
    stored = expected & set(frame["trial_id"].astype(str))
    if not stored:  # every row's settings differ from today's grid: an earlier protocol, not a partial run
        partial = (f"**Earlier protocol**: none of these {len(frame)} trials is in today's grid of {len(expected)} "
                   "(they were made before settings this version records, such as the fixed command and the "
                   "clock); `bench sweep` would run the grid anew. The rows are kept as made.")
    elif len(stored) == len(expected):
        partial = ""
    else:
        partial = (f"**Partial store**: {len(stored)} of the grid's {len(expected)} trials; cells with fewer "
                   "trials than seeds, or missing from the table, are not finished (`bench sweep` resumes).")
    return StoreContext(experiment.title, commands, experiment.paper, partial, experiment)


def earlier_ground(group: pd.DataFrame) -> str:
    """A warning when rough-ground trials ran on other ground than today's (before the terrain's margin), or ""."""
    from benchmark.experiments.sweep import on_other_ground

    earlier = int(on_other_ground(group).sum())
    if not earlier:
        return ""
    return (f"**Earlier ground**: {earlier} of these rough-ground trials ran before the rough terrain had its 20 m "
            "margin (the 32 x 8 m core is the same; a robot drifting sideways could walk off its edge), so they are "
            "not today's trials; running the experiment again makes them on today's ground.")


class ReportConflict(ValueError):
    """An existing report was made from another store: replacing it needs `force`."""


def store_digest(group: pd.DataFrame) -> str:
    """Names the trials a report was made from: a partial store and a full one differ."""
    return hashlib.sha256(" ".join(sorted(group["trial_id"].astype(str))).encode()).hexdigest()[:12]


DIGEST = re.compile(r"Store digest: `([0-9a-f]+)`")


def _check_replace(path: Path, digest: str, force: bool) -> None:
    if force or not path.is_file():
        return
    found = DIGEST.search(path.read_text(errors="replace"))
    if found is None or found.group(1) != digest:
        raise ReportConflict(f"{path} was made from another store (digest {found.group(1) if found else 'none'}, "
                             f"this one {digest}); pass --force to replace it, or --out DIR")


def write_reports(frame: pd.DataFrame, out: Path, fmt: str = "md", force: bool = False) -> list[Path]:
    """Tables (`OUT/EXPERIMENT.FMT`) and figures (`OUT/figures/EXPERIMENT_*.png`) per experiment. An existing
    table made from another store is not replaced unless `force`."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown format '{fmt}'; valid: {', '.join(FORMATS)}")
    for name, group in frame.groupby("experiment", sort=False):
        for suffix in ("md", "html"):
            _check_replace(out / f"{name}.{suffix}", store_digest(group), force or suffix != fmt)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, everything in frame.groupby("experiment", sort=False):
        everything = everything.sort_values(["cell_index", "seed"]).reset_index(drop=True)
        group, probes = split_probe_rows(everything)
        context = store_context(str(name), everything)
        probe_lines, probe_figures = probe_section(probes, out, str(name), expected_probe_runs(str(name)))
        path = out / f"{name}.{fmt}"
        if group.empty:  # the probe stage alone so far
            path.write_text(_probe_only_report(str(name), context, everything, probe_lines))
            written += [path, *probe_figures]
            continue
        table, engines = summary_table(group), engine_table(group)
        numbers = summary_table(group, spread=False)
        title, paper = context.title, context.paper
        published = paper_table(group, paper) if paper else None
        bars = bar_figure(group, numbers, out / "figures" / f"{name}_bars.png", title, paper)
        traj = trajectory_figure(group, out / "figures" / f"{name}_trajectories.png")
        figures = [p for p in (bars, traj) if p is not None]
        extra, extra_figures = latency_section(group, out, str(name))
        diagnostics, diagnostic_figures = diagnostics_section(group, out, str(name), _row_label(group))
        matrix, matrix_figures = matrix_section(group, out, str(name), title, probes)
        ablation, ablation_figures = ablation_section(group, probes, out, str(name), context.experiment)
        study = [] if ablation else study_section(group, probes, planned_llm_cells(str(name)))
        extra = extra + realtime_section(group) + matrix + ablation + study + probe_lines + diagnostics
        figures += extra_figures + matrix_figures + ablation_figures + probe_figures + diagnostic_figures
        if fmt == "csv":
            table.to_csv(path, index=False)
        elif fmt == "html":
            parts = [f"<h1>{title}</h1>", f"<p>Store digest: `{store_digest(group)}` ({len(group)} trials)</p>",
                     table.to_html(index=False)]
            if engines is not None:
                parts += ["<h2>Engines side by side (success / NWT)</h2>", engines.to_html(index=False)]
            if published is not None:
                parts += [f"<h2>Beside the paper ({paper['source']})</h2>", published.to_html(index=False)]
            parts += [f'<img src="figures/{p.name}" alt="{p.stem}">' for p in figures]
            path.write_text("\n".join(parts) + "\n")
        else:
            path.write_text(_markdown_report(str(name), context, group, table, engines, figures, published, extra,
                                             digest_of=everything))
        written += [path, *figures]
    return written


def seed_policies(group: pd.DataFrame) -> str:
    """Which seed policies the store's trials ran (sha256 prefix per robot), and whether they are the ones shipped
    now: a store made with earlier policies says so, and is never mixed with a newer one silently."""
    if "seed_policy_sha256" not in group or group["seed_policy_sha256"].isna().all():
        return "Seed policies: not recorded."
    parts = []
    for robot, g in group.dropna(subset=["seed_policy_sha256"]).groupby("robot", sort=False):
        used = sorted(g["seed_policy_sha256"].unique())
        path = load_robot(str(robot)).folder / "policy.npz"
        shipped = hashlib.sha256(path.read_bytes()).hexdigest()[:12] if path.is_file() else None
        note = "the shipped one" if used == [shipped] else (
            f"**not the shipped `{shipped}`: made with an earlier seed policy**" if shipped not in used
            else f"**mixed: the shipped `{shipped}` and earlier ones**")
        parts.append(f"{robot} `{'`, `'.join(used)}` ({note})")
    return "Seed policies: " + "; ".join(parts) + "."


def command_mode(group: pd.DataFrame) -> str:
    """Whether the store's seed phases ran at the paper's fixed command or steered by the heading hold."""
    held = group["heading_hold"] if "heading_hold" in group else pd.Series([None] * len(group))
    if held.isna().all():
        return ("Command: the heading hold steered the seed policy (a store from before the fixed command; "
                "`heading_hold` not recorded).")
    values = sorted({bool(v) for v in held.dropna()})
    return {(False,): "Command: fixed at the robot's (the paper's protocol).",
            (True,): "Command: the heading hold steered the seed policy (--heading-hold)."}.get(
        tuple(values), "Command: **mixed**: some trials at the fixed command, some steered (column `heading_hold`).")


def made_on(group: pd.DataFrame) -> str:
    """The machines a store's trials ran on, by fingerprint (rows from before fingerprints say so)."""
    if "fingerprint_id" not in group or group["fingerprint_id"].isna().all():
        return "Made on: not recorded (a store from before platform fingerprints)."
    rows = group.dropna(subset=["fingerprint_id"]).drop_duplicates("fingerprint_id")
    counts = group["fingerprint_id"].value_counts()
    parts = [f"`{r.fingerprint_id}` ({counts[r.fingerprint_id]} trials): {describe(json.loads(r.fingerprint))}"
             for r in rows.itertuples()]
    missing = int(group["fingerprint_id"].isna().sum())
    return "Made on: " + "; ".join(parts) + (f"; {missing} trials not recorded" if missing else "") + "."


def _walking_text(group: pd.DataFrame) -> str:
    if "walk_window_s" not in group or group["walk_window_s"].isna().all():
        return "criteria not recorded: a store made before the walking metrics"
    row = group.dropna(subset=["walk_window_s"]).iloc[0]
    return (f"walking: progress along the command over every {row['walk_window_s']:g} s window at least "
            f"{row['walk_min_speed']:g} m/s; success distance at least {row['walk_min_distance_m']:g} m")


def _row_label(group: pd.DataFrame) -> str:
    """The column that names a row of the store's grid (its first axis, e.g. `controller`), else `model`."""
    axes = axes_of(group) if "axes" in group else []
    return axes[0] if axes else "model"


def expected_probe_runs(name: str) -> int | None:
    """How many probe runs the shipped experiment's `[probe]` grid holds (None: no such experiment or table)."""
    try:
        experiment = load_experiment(name)
    except ExperimentError:
        return None
    return len(experiment.probe_settings()) if experiment.probe else None


def planned_llm_cells(name: str) -> pd.DataFrame | None:
    """The shipped experiment's LLM cells (model, prompt_strategy, history_mode) and their planned trial counts
    (`trials`), one row each (None: no such experiment), so a partial store's tables show what is still to run."""
    try:
        experiment = load_experiment(name)
    except ExperimentError:
        return None
    counts = Counter(t.cell for t in experiment.trials())  # each cell once, in grid order, with its trial count
    rows = [{**{k: cell.params().get(k) for k in ("policy", "model", "prompt_strategy", "retrieve_k", "memory",
                                                  "distance", "history_mode")}, "trials": n} for cell, n in counts.items()]
    return pd.DataFrame([r for r in rows if r["policy"] == "llm"])


def _probe_only_report(name: str, context: StoreContext, everything: pd.DataFrame, probe_lines: list[str]) -> str:
    lines = [f"# {context.title}", "", f"Experiment `{name}`: the probe stage only so far (no closed-loop trials "
             "stored yet; `bench sweep` runs them).", "", *probe_lines]
    if context.commands:
        lines += ["Made with:", "", *[f"    {c}" for c in context.commands], ""]
    lines += [made_on(everything), "", f"Store digest: `{store_digest(everything)}` ({len(everything)} rows; `bench "
              "report` will not replace this file with a report of another store unless given --force).", ""]
    return "\n".join(lines)


def _markdown_report(name: str, context: StoreContext, group: pd.DataFrame, table: pd.DataFrame,
                     engines: pd.DataFrame | None, figures: list[Path], published: pd.DataFrame | None = None,
                     extra: list[str] = (), digest_of: pd.DataFrame | None = None) -> str:
    versions = json.loads(group["versions"].dropna().iloc[0]) if "versions" in group and group["versions"].notna().any() else {}
    commits = sorted(str(c)[:10] for c in group.get("git_commit", pd.Series(dtype=str)).dropna().unique())
    lines = [f"# {context.title}", "",
             f"Experiment `{name}`: {len(group)} trials in {group['cell_id'].nunique()} cells, "
             f"seeds {sorted(group['seed'].unique().tolist())}. NWT and success cover the evaluated phase only "
             "(for the LLM, from its takeover to the end) and need walking: NWT is the fraction of the phase "
             "before the robot falls or stops walking, success finishing it upright, walking and far enough "
             f"({_walking_text(group)}); `upright` is the fraction before a fall, which standing wins. "
             "Success rates show a Wilson 95% interval, NWT, speed and distance the mean ± one standard "
             "deviation over trials."]
    if "approximate_history" in group and group["approximate_history"].fillna(False).astype(bool).any():
        lines += ["", "**Approximation**: LLM cells with history mode `shifted` ran on llama.cpp's KV-cache shifting "
                      "(cached keys and values keep the dropped pair in context); `bench latency` measures how often "
                      "a reply differs from an exact recompute."]
    cut = ended_at_stop(group)
    if cut:
        lines += ["", f"**Trials ended at their stop**: {cut} of {len(group)} trials ended when the robot first stopped "
                      "walking (`--end-at-stop`). Their NWT and success are exact (decided at the stop); the rest of "
                      "the episode did not run, so their `upright` is not measured, their distance and speed cover the "
                      "walk up to the stop, and their reply diagnostics the replies before it."]
    if context.partial:
        lines += ["", context.partial]
    ground = earlier_ground(group)
    if ground:
        lines += ["", ground]
    if context.commands:
        lines += ["", "Made with:", "", *[f"    {c}" for c in context.commands]]
    lines += ["", to_markdown(headline_table(table)), "", "Detail (every metric; the HTML and CSV reports hold the "
              "same):", "", to_markdown(table)]
    if engines is not None:
        lines += ["", "Engines side by side (success rate / NWT):", "", to_markdown(engines)]
    if published is not None:
        lines += ["", f"Beside the paper ({context.paper.get('source', '')}; its figures as published, ours from this store; GPT-4 token "
                      "counts are cl100k on this store's prompts):", "", to_markdown(published)]
    lines += ["", *extra, *[f"![{p.stem}](figures/{p.name})" for p in figures if f"figures/{p.name})" not in
                                "".join(extra)], ""]
    if versions or commits:
        lines += [f"Versions: {', '.join(f'{k} {v}' for k, v in versions.items())}; "
                  f"git commit {', '.join(commits) or 'unknown'}.", ""]
    lines += [made_on(group), "", seed_policies(group) + " " + command_mode(group), ""]
    rows = group if digest_of is None else digest_of
    lines += [f"Store digest: `{store_digest(rows)}` ({len(group)} trials" + (
              f" and {len(rows) - len(group)} probe runs" if len(rows) > len(group) else "")
              + "; `bench report` will not replace this file with a report of another store unless given --force).", ""]
    return "\n".join(lines)
