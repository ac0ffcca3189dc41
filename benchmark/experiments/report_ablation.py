"""The paper's ablations on a model that walks: per variant of the ablated setting, the model's closed loop beside
its own prompt's trivial answers, its probe skill on each model rung, the paper's figures, and a verdict on each
of the paper's findings.

Applies to an experiment whose `[paper]` table lists `findings` (each: the variant the paper found better, the one
it found worse, and the claim in words). A finding is judged on the model row's success, paired over the seeds both
variants ran (bootstrap 95% interval): **holds** when the interval lies above 0, **fails** when it lies below 0 or
the two variants succeed alike on every seed while at least one walks, **cannot tell** otherwise (at this n).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.common.figures import save_figure
from benchmark.common.skill import skill, skill_difference, unpaired_skill_difference
from benchmark.common.tables import live_latency_mean, shared_machine, to_markdown, wilson
from benchmark.experiments.experiment import Experiment
from benchmark.experiments.report_matrix import paired_gain
from benchmark.experiments.report_prompting import MODEL_NAMES

TRIVIAL = ("knn", "hold")  # the same prompt's trivial answers, as the walking experiments name their rows
CEILING = "oracle"


def applies(group: pd.DataFrame, experiment: Experiment | None) -> bool:
    paper = experiment.paper if experiment is not None else {}
    return bool(paper.get("findings")) and paper.get("axis") in group and "controller" in group


def _model_rows(group: pd.DataFrame, experiment: Experiment) -> list[str]:
    """The controllers under test, stored or planned: every LLM row but the trivial answers and the ceiling (in the
    walking experiments, the language model)."""
    planned = [c for c in experiment.grid.get("controller", []) if c not in (*TRIVIAL, CEILING)
               and experiment.variants.get("controller", {}).get(c, {}).get("policy") == "llm"]
    llm = group[(group["policy"] == "llm") & ~group["controller"].isin((*TRIVIAL, CEILING))]
    return list(dict.fromkeys([*planned, *llm["controller"]]))


def _name(group: pd.DataFrame, experiment: Experiment, controller: str) -> str:
    """A model row's name as the reports write it (its model's name, e.g. Qwen2.5-Coder 1.5B)."""
    model = experiment.variants.get("controller", {}).get(controller, {}).get("model")
    if model is None and controller in set(group["controller"]):
        model = group[group["controller"] == controller]["model"].iloc[0]
    return MODEL_NAMES.get(model, controller)


def _rate(trials: pd.DataFrame, planned: int | None = None) -> str:
    if trials.empty:
        return "not run yet"
    n, k = len(trials), int(trials["success"].sum())
    low, high = wilson(k, n)
    partial = f" ({n} of {planned})" if planned and n < planned else ""
    return f"{k}/{n} [{low:.2f}, {high:.2f}]{partial}"


def _probe_cell(probes: pd.DataFrame, axis: str, value: str, model: str) -> str:
    rows = probes[(probes.get(axis, pd.Series(dtype=object)).astype(str) == value) & (probes["model"] == model)] \
        if len(probes) and axis in probes else probes.iloc[0:0]
    if rows.empty:
        return "not run yet"
    r = rows.iloc[-1]
    return f"{r['skill']:.3f} [{r['skill_low']:.3f}, {r['skill_high']:.3f}]; gain {r['gain']:+.3f}"


def variant_table(group: pd.DataFrame, probes: pd.DataFrame, experiment: Experiment) -> pd.DataFrame:
    """One row per variant: the paper's figures, each model row's closed loop (success, NWT, tokens read and
    seconds a query, its paired gain over the better trivial answer), the trivial answers and the ceiling, and
    each rung's probe skill with its gain over the same prompt's trivial answers."""
    paper, seeds = experiment.paper, len(experiment.seeds)
    axis, rng = paper["axis"], np.random.default_rng(0)
    values = list(dict.fromkeys(group[axis].dropna().astype(str)))
    probe_models = list(dict.fromkeys(probes["model"])) if len(probes) else []
    out = []
    for value in values:
        here = group[group[axis].astype(str) == value]
        row = {axis: value}
        for metric, name in (("success", "paper success"), ("nwt", "paper NWT")):
            if metric in paper:
                row[name] = paper[metric].get(value, "-")
        by = {c: t for c, t in here.groupby("controller")}
        trivial = [by[t] for t in TRIVIAL if t in by]
        best = max(trivial, key=lambda t: t["success"].mean()) if trivial else None
        for model in _model_rows(group, experiment):
            trials = by.get(model, here.iloc[0:0])
            label = _name(group, experiment, model)
            row[f"{label}: success [95%]"] = _rate(trials, seeds)
            if trials.empty:
                continue
            row[f"{label}: NWT"] = f"{trials['nwt'].mean():.2f}"
            if "read_tokens" in trials and trials["read_tokens"].notna().any():  # what a language model read
                row["tokens read / decoded a query"] = (f"{trials['read_tokens'].mean():.0f} / "
                                                        f"{trials['output_tokens'].mean():.0f}")
                row["s / query"] = f"{live_latency_mean(trials):.1f}{shared_machine(trials)}"
            if best is not None:
                d, low, high, n = paired_gain(trials, best, rng)
                row["gain over the better trivial answer [95%]"] = (
                    f"{d:+.2f} [{low:+.2f}, {high:+.2f}] vs {best['controller'].iloc[0]}" if n else "-")
        for name in (*TRIVIAL, CEILING):
            if name in by:
                row[name] = _rate(by[name])
        for model in probe_models:
            row[f"probe {MODEL_NAMES.get(model, model)}: skill [95%]"] = _probe_cell(probes, axis, value, model)
        out.append(row)
    columns = list(dict.fromkeys(k for row in out for k in row))  # first-seen order, then the model's columns together
    models = [c for c in columns if c.endswith(": success [95%]")]
    mine = [c for c in columns if any(c.startswith(m.removesuffix("success [95%]")) for m in models) or c in (
        "tokens read / decoded a query", "s / query", "gain over the better trivial answer [95%]")]
    head = [c for c in columns if c == axis or c.startswith("paper ")]
    rest = [c for c in columns if c not in head and c not in mine]
    return pd.DataFrame(out, columns=[*head, *mine, *rest]).fillna("-")


def judge(better: pd.DataFrame, worse: pd.DataFrame, rng: np.random.Generator) -> tuple[str, str]:
    """(our figures, verdict) for "`better` walks more often than `worse`", paired over their common seeds."""
    if better.empty or worse.empty:
        return "-", "not run yet"
    d, low, high, n = paired_gain(better, worse, rng)
    if n == 0:
        return "-", "not run yet"
    a, b = better.set_index("seed")["success"], worse.set_index("seed")["success"]
    seeds = a.index.intersection(b.index)
    figures = f"{int(a[seeds].sum())}/{n} vs {int(b[seeds].sum())}/{n}: {d:+.2f} [{low:+.2f}, {high:+.2f}]"
    if low > 0:
        return figures, "holds"
    if high < 0:
        return figures, "fails (reversed)"
    if low == high == 0:  # the same outcome on every seed
        return figures, ("fails: both walk alike" if a[seeds].any() else f"cannot tell: neither walks at n = {n}")
    return figures, f"cannot tell at n = {n}"


def findings_table(group: pd.DataFrame, experiment: Experiment) -> pd.DataFrame:
    """Each of the paper's findings, judged on each model row and on the trivial answers (does copying the same
    prompts show the finding too?)."""
    paper = experiment.paper
    axis, rng = paper["axis"], np.random.default_rng(0)
    rows = []
    for finding in paper["findings"]:
        for model in [*_model_rows(group, experiment), *[t for t in TRIVIAL if t in set(group["controller"])]]:
            mine = group[group["controller"] == model]
            ours, verdict = judge(mine[mine[axis].astype(str) == finding["better"]],
                                  mine[mine[axis].astype(str) == finding["worse"]], rng)
            compared = f"{finding['better']} > {finding['worse']}"
            rows.append({"the paper's finding": finding["says"], "compared": compared,
                         "model": _name(group, experiment, model),
                         "success, paired over seeds [95%]": ours, "here": verdict})
    return pd.DataFrame(rows)


def same_items(one: pd.Series, other: pd.Series) -> bool:
    """Whether two probe rows scored the same items: the same probe set, cells, window and history length (the
    history decides the first item), and as many items."""
    keys = ("probe_digest", "probe_cells", "window", "history")
    return all(str(one.get(k)) == str(other.get(k)) for k in keys) and len(one["item_errors"]) == len(
        other["item_errors"])


def judge_items(better: pd.Series, worse: pd.Series, errors: str = "item_errors") -> tuple[str, str]:
    """(our figures, verdict) for "`better` imitates the seed policy more closely than `worse`", from two probe rows
    of one probe cell: the skill difference with its bootstrap 95% interval, paired over items where both rows
    scored the same items (each in its own number format's units), else each row's items resampled on their own (as
    where a history length moves the first item); `errors` names the answers judged (the model's, or the prompt's
    `knn`: `item_prompt_knn_errors`)."""
    if "+" in str(better["probe_cells"]) or better["probe_cells"] != worse["probe_cells"]:
        return "-", "cannot tell: not one probe cell"
    a, b = (np.asarray(row[errors], dtype=float) for row in (better, worse))
    hold, other_hold = (np.asarray(row["item_hold_errors"], dtype=float) for row in (better, worse))
    paired = same_items(better, worse)
    cells = np.zeros(len(a))
    d, low, high = (skill_difference(a, b, hold, cells, other_hold_errors=other_hold) if paired else
                    unpaired_skill_difference(a, hold, b, other_hold))
    figures = (f"{skill(a, hold, cells):.3f} vs {skill(b, other_hold, np.zeros(len(b))):.3f}: {d:+.3f} "
               f"[{low:+.3f}, {high:+.3f}]" + ("" if paired else " (unpaired: other items)"))
    if low > 0:
        return figures, "holds"
    if high < 0:
        return figures, "fails (reversed)"
    if paired and np.allclose(a / np.maximum(hold, 1e-12), b / np.maximum(other_hold, 1e-12)):
        return figures, "fails: the same answers"
    return figures, f"cannot tell at {len(a)} items"


def probe_findings_table(probes: pd.DataFrame, experiment: Experiment) -> pd.DataFrame:
    """Each of the paper's findings, teacher-forced: per probe rung (and the same prompts' `knn`), the skill of the
    variant the paper found better minus the other's, over the same items."""
    paper = experiment.paper
    axis, rows = paper["axis"], []
    if probes.empty or axis not in probes or "item_errors" not in probes:
        return pd.DataFrame(rows)
    for finding in paper["findings"]:
        judged, knn = [], None
        for model in dict.fromkeys(probes["model"]):
            mine = probes[probes["model"] == model]
            better, worse = (mine[mine[axis].astype(str) == finding[v]] for v in ("better", "worse"))
            if better.empty or worse.empty:
                judged.append((MODEL_NAMES.get(model, model), ("-", "not run yet")))
                continue
            judged.append((MODEL_NAMES.get(model, model), judge_items(better.iloc[0], worse.iloc[0])))
            knn = knn or judge_items(better.iloc[0], worse.iloc[0], "item_prompt_knn_errors")  # the same on every rung
        judged += [("knn (the prompt's nearest example)", knn)] if knn else []
        rows += [{"the paper's finding": finding["says"], "compared": f"{finding['better']} > {finding['worse']}",
                  "answers": name, "probe skill: better vs worse, difference [95%]": ours, "here": verdict}
                 for name, (ours, verdict) in judged]
    return pd.DataFrame(rows)


def ablation_figure(group: pd.DataFrame, probes: pd.DataFrame, experiment: Experiment, path: Path) -> Path:
    """Left: closed-loop success per variant (models with Wilson intervals, the trivial answers and the ceiling as
    marks, the paper's figures as black crosses). Right: probe skill per variant and rung, 95% intervals, and the
    prompt's better trivial answer."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paper, axis = experiment.paper, experiment.paper["axis"]
    values = list(dict.fromkeys(group[axis].dropna().astype(str)))
    xs = np.arange(len(values))
    fig, (left, right) = plt.subplots(1, 2, figsize=(max(9.0, 1.5 * len(values) + 4), 4.2), constrained_layout=True)
    models = _model_rows(group, experiment)
    width = 0.7 / max(len(models), 1)
    for i, model in enumerate(models):
        rates, errs = [], [[], []]
        for value in values:
            t = group[(group["controller"] == model) & (group[axis].astype(str) == value)]
            k, n = int(t["success"].sum()), len(t)
            p = k / n if n else np.nan
            low, high = wilson(k, n) if n else (np.nan, np.nan)
            rates.append(p)
            errs[0].append(p - low if n else 0)
            errs[1].append(high - p if n else 0)
        left.bar(xs + (i - (len(models) - 1) / 2) * width, rates, width, yerr=errs, capsize=3,
                 label=_name(group, experiment, model))
    for name, marker, colour in (("knn", "v", "dimgray"), ("hold", "^", "darkgray"), (CEILING, "_", "black")):
        pts = [(x, group[(group["controller"] == name) & (group[axis].astype(str) == v)]["success"].mean())
               for x, v in zip(xs, values)]
        pts = [(x, y) for x, y in pts if not np.isnan(y)]
        if pts:
            left.plot(*zip(*pts), marker, ms=14 if marker == "_" else 7, mew=2, ls="none", label=name, color=colour)
    published = [(x, paper["success"][v]) for x, v in zip(xs, values) if v in paper.get("success", {})]
    if published:
        left.plot(*zip(*published), "kx", ms=9, mew=2, label=paper.get("source", "paper"))
    left.set_ylabel("closed-loop success")
    left.set_title("closed loop (Wilson 95%)", fontsize=9)
    if len(probes) and axis in probes:
        rungs = list(dict.fromkeys(probes["model"]))
        w = 0.7 / len(rungs)
        for i, model in enumerate(rungs):
            mine = probes[probes["model"] == model]
            got = [mine[mine[axis].astype(str) == v] for v in values]
            pts = [(x, r.iloc[-1]) for x, r in zip(xs, got) if len(r)]
            if pts:
                right.bar([x + (i - (len(rungs) - 1) / 2) * w for x, _ in pts], [r["skill"] for _, r in pts], w,
                          yerr=[[r["skill"] - r["skill_low"] for _, r in pts],
                                [r["skill_high"] - r["skill"] for _, r in pts]],
                          capsize=3, label=MODEL_NAMES.get(model, model))
        trivial = [(x, probes[probes[axis].astype(str) == v][["same_prompt_hold_skill", "same_prompt_knn_skill"]]
                    .max(axis=1).max()) for x, v in zip(xs, values)]
        trivial = [(x, y) for x, y in trivial if not np.isnan(y)]
        if trivial:
            right.plot(*zip(*trivial), "_", ms=20, mew=2, color="black", ls="none", label="better trivial answer")
    else:
        right.text(0.5, 0.5, "probe stage not run yet", ha="center", va="center", transform=right.transAxes)
    right.axhline(0.0, color="grey", lw=0.8, ls=":")
    right.set_ylabel("probe skill (1 - error / hold's error)")
    right.set_title("probe, teacher-forced (bootstrap 95%)", fontsize=9)
    for panel in (left, right):
        panel.set_xticks(xs, values, fontsize=8)
        panel.set_xlim(-0.5, len(values) - 0.5)
        panel.set_xlabel(axis)
        if panel.get_legend_handles_labels()[0]:
            panel.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18), ncols=5)
        panel.grid(axis="y", alpha=0.3)
    left.set_ylim(0, 1.05)
    fig.suptitle(experiment.title, fontsize=10)
    return save_figure(fig, path, dpi=120, tight=False)


def ablation_section(group: pd.DataFrame, probes: pd.DataFrame, out: Path, name: str,
                     experiment: Experiment | None) -> tuple[list[str], list[Path]]:
    """The variant table, the findings judged, and the figure (empty when the experiment lists no findings)."""
    if not applies(group, experiment):
        return [], []
    figure = ablation_figure(group, probes, experiment, out / "figures" / f"{name}_ablation.png")
    return (["## The ablation on a model that walks", "",
             f"Per variant of `{experiment.paper['axis']}`: the language model's closed-loop success (Wilson 95%) and "
             "NWT, the tokens it read anew and decoded a query and its seconds a query (2 threads, live queries), its "
             "success minus the better of the same prompt's trivial answers (`knn`, `hold`) paired over seeds "
             "(bootstrap 95%), those answers and the ceiling (`oracle`, the seed policy's action through the same "
             "text), and each rung's teacher-forced probe skill with its gain over the same prompt's trivial answers. "
             "The paper's figures are GPT-4's on its own prompt, where it printed them.", "",
             to_markdown(variant_table(group, probes, experiment)), "",
             "### The paper's findings, here", "",
             "Judged on the model's success paired over the seeds both variants ran: holds when the 95% interval "
             "of the difference lies above 0, fails when it lies below 0 or both variants walk alike on every "
             "seed (and one walks), cannot tell otherwise.", "", to_markdown(findings_table(group, experiment)), "",
             *_probe_findings_lines(probes, experiment),
             f"![{name} ablation](figures/{figure.name})", ""], [figure])


def _probe_findings_lines(probes: pd.DataFrame, experiment: Experiment) -> list[str]:
    table = probe_findings_table(probes, experiment)
    if table.empty:
        return []
    return ["### The paper's findings, teacher-forced", "",
            "The probe's reading of the same findings, before or beside the closed loop: does the variant the paper "
            "found better bring the answers closer to the seed policy's action (probe skill; the difference paired "
            "over the same items, bootstrap 95%)? Holds when its interval lies above 0, fails when "
            "below, cannot tell otherwise. Imitating more closely is not walking: the closed loop decides.", "",
            to_markdown(table), ""]
