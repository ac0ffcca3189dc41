"""The prompting sections of a report: the probe stage's table (each model and prompt strategy against its own
prompt's trivial answers) and the closed loop's diagnostics (does a model freeze, copy, drift or fall, and when),
with their figures. Both read only the numbers the store holds."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.common.figures import save_figure
from benchmark.common.tables import ended_at_stop, live_latency_mean, to_markdown, wilson
from benchmark.llm.controller import LLMSettings, strategy_text
from benchmark.llm.reference import REFERENCE_KINDS, TRIVIAL_ANSWERS

DIAGNOSTICS = ("repeat_fraction", "copy_fraction", "demo_distance_mean", "oracle_distance_mean")
MODEL_NAMES = {"embedded": "Gemma 3 270M", "qwen2.5-coder-0.5b": "Qwen2.5-Coder 0.5B",
               "qwen2.5-coder-1.5b": "Qwen2.5-Coder 1.5B", "hold": "hold (the prompt's last example line)",
               "knn": "knn (the prompt's nearest example)"}
TRIVIAL = {name: f"same_prompt_{name}_skill" for name in TRIVIAL_ANSWERS}  # a trivial answer's probe column
REVISIT_BACK = 10  # how far back (queries) a reply's return to one of the model's own replies counts as a loop
SHOWN_JOINTS = (3, 4, 5, 1)  # FL hip, thigh, calf; FR thigh (canonical order)
JOINT_NAMES = ("FR hip", "FR thigh", "FR calf", "FL hip", "FL thigh", "FL calf",
               "RR hip", "RR thigh", "RR calf", "RL hip", "RL thigh", "RL calf")


def step_times(row: pd.Series, steps: int) -> np.ndarray:
    """The times of a stored trajectory's steps: each is the state after its control step."""
    return np.arange(1, steps + 1) * float(row["control_dt"])


def split_probe_rows(group: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(closed-loop trials, probe rows) of one experiment's store."""
    if "kind" not in group:
        return group, group.iloc[0:0]
    probe = group["kind"] == "probe"
    return group[~probe].reset_index(drop=True), group[probe].reset_index(drop=True)


def _interval(value, low, high, signed: bool = False) -> str:
    if value is None or pd.isna(value):
        return "-"
    f = "+.3f" if signed else ".3f"
    return f"{value:{f}} [{low:{f}}, {high:{f}}]"


def _count(value) -> str:
    """An integer count, or - where the row predates it."""
    return "-" if value is None or pd.isna(value) else str(int(value))


def probe_table(rows: pd.DataFrame) -> pd.DataFrame:
    out = []
    for r in rows.sort_values("cell_index").itertuples():
        out.append({"model": r.model, "strategy": r.strategy, "history": int(r.history), "items": int(r.items),
                    "skill [95%]": _interval(r.skill, r.skill_low, r.skill_high),
                    "same prompt: hold": round(float(r.same_prompt_hold_skill), 3),
                    "same prompt: knn": round(float(r.same_prompt_knn_skill), 3),
                    "gain over the better [95%]": _interval(r.gain, r.gain_low, r.gain_high, signed=True),
                    "within 1 step": round(float(r.within_step), 2), "parse failures": int(r.parse_failures),
                    "s/query (median)": round(float(r.latency_median_s), 2),
                    "cached replies": _count(getattr(r, "cached_replies", None)),
                    "prompt tokens": int(round(float(r.prompt_tokens))), "wall (min)": round(float(r.wall_s) / 60, 1)})
    return pd.DataFrame(out)


def probe_figure(rows: pd.DataFrame, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    strategies = list(dict.fromkeys(rows.sort_values("cell_index")["strategy"]))
    models = list(dict.fromkeys(rows.sort_values("cell_index")["model"]))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.6 * len(strategies)), 3.8))
    width = 0.8 / max(len(models), 1)
    for i, model in enumerate(models):
        mine = rows[rows["model"] == model].set_index("strategy")
        xs = [k + (i - (len(models) - 1) / 2) * width for k, s in enumerate(strategies) if s in mine.index]
        got = [mine.loc[s] for s in strategies if s in mine.index]
        ax.bar(xs, [g["skill"] for g in got], width, label=MODEL_NAMES.get(model, model),
               yerr=[[g["skill"] - g["skill_low"] for g in got], [g["skill_high"] - g["skill"] for g in got]],
               capsize=2)
    trivial = rows.groupby("strategy")[["same_prompt_hold_skill", "same_prompt_knn_skill"]].first().max(axis=1)
    ax.scatter(range(len(strategies)), [trivial[s] for s in strategies], marker="_", s=900, color="black", zorder=3,
               label="the prompt's better trivial answer")
    ax.axhline(0.0, color="grey", lw=0.8, ls=":")
    ax.set_xticks(range(len(strategies)), [name.replace(" (", "\n(") for name in strategies], fontsize=8)
    ax.set_ylabel("probe skill (1 - error / hold's error)")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncols=4)  # below: bars and marks stay clear
    ax.set_title("Probe skill by prompt strategy, against what each prompt gives away", fontsize=10)
    return save_figure(fig, path, dpi=120)


def _made_with(row: pd.Series) -> str:
    """`, made with the seed policies a1 X`, when the row recorded them."""
    text = row.get("probe_seed_policies")
    if not isinstance(text, str):
        return ""
    return "; made with the seed policies " + ", ".join(f"{robot} {sha[:12]}" for robot, sha in json.loads(text).items())


def with_variants(rows: pd.DataFrame, name: str) -> pd.DataFrame:
    """Probe rows of an ablation, the ablated value named before the strategy (`E1: nearest-only (...)`), so that
    variants of one strategy stay apart in the table and the figure."""
    from benchmark.experiments.experiment import ExperimentError, load_experiment

    if "axes" in rows and rows["axes"].notna().all():  # each row names its probe grid's axes
        grid = list(dict.fromkeys(a for text in rows["axes"] for a in json.loads(text)))
    else:  # rows made before they named them: the shipped experiment's grid
        try:
            grid = list(load_experiment(name).probe.get("grid", {}))
        except ExperimentError:
            return rows
    axes = [a for a in grid if a not in ("model", "prompt_strategy") and a in rows]
    if not axes:
        return rows
    defaults = {f.name: f.default for f in dataclasses.fields(LLMSettings)}  # a row stored before a setting: its default
    labels = rows[axes].apply(lambda col: col.map(lambda v: str(defaults.get(col.name) if pd.isna(v) else v)))
    return rows.assign(strategy=labels.agg(" ".join, axis=1) + ": " + rows["strategy"])


def probe_section(rows: pd.DataFrame, out: Path, name: str, expected: int | None = None) -> tuple[list[str], list[Path]]:
    """Markdown lines and the figure for an experiment's probe stage (empty when it has none); `expected`: the
    probe grid's size, to say when the stage is partial."""
    if rows.empty:
        return [], []
    rows = with_variants(rows, name)
    figure = probe_figure(rows, out / "figures" / f"{name}_probe.png")
    first = rows.iloc[0]
    lines = ["## Probe stage: each model and prompt strategy against its own prompt's trivial answers", "",
             f"Teacher-forced imitation on the probe set `{first['probe_digest']}` ({first['probe_cells']}{_made_with(first)}), "
             f"history {int(first['history'])} ({first['window']}). Skill = 1 - error / error of freezing on the newest "
             "action; every strategy is scored on the same items with the same normalizer. **Same prompt**: the "
             "prompt's own trivial answers, `hold` (copy its last example line) and `knn` (its nearest example's "
             "output). The gain is the model's skill minus the better of them, with a paired 95% bootstrap "
             "interval: at or below 0 the prompt, not the model, carries the imitation. s/query is the median latency as "
             "measured when each reply was made, under the load of that moment (a reply read from the on-disk cache "
             "keeps its first measurement; `cached replies` counts them, - where a row predates the count); "
             "`bench latency --strategies` measures speed per strategy on its own.", "",
             to_markdown(probe_table(rows)), "", f"![probe by strategy](figures/{figure.name})", ""]
    if expected is not None and len(rows) < expected:
        lines[2:2] = [f"**Partial stage**: {len(rows)} of the probe grid's {expected} runs (`bench sweep --stage probe` "
                      "resumes).", ""]
    return lines, [figure]


EXACT = " (exact history)"


def _prompt_labels(llm: pd.DataFrame) -> pd.Series:
    """A trial's prompt strategy, marked when it ran exact history beside shifted rows of the same model and
    prompt (the variant that measures the shifted approximation)."""
    mode = llm["history_mode"] if "history_mode" in llm else pd.Series("sliding", index=llm.index)
    strategies = [strategy_text(r.get("prompt_strategy"), r.get("retrieve_k", 3), r.get("memory", "demonstrations"),
                                r.get("distance", "l2")) for _, r in llm.iterrows()]
    shifted = {(m, s) for m, s, h in zip(llm["model"], strategies, mode) if h == "shifted"}
    return pd.Series([s + EXACT if h != "shifted" and (m, s) in shifted else s
                      for m, s, h in zip(llm["model"], strategies, mode)], index=llm.index, dtype=object)


def study_table(trials: pd.DataFrame, probes: pd.DataFrame, planned: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per (model, prompt strategy) in either stage: its probe skill and gain over the prompt's better
    trivial answer, and its closed loop; the trivial answers' probe skill is read off any probe row of their
    strategy (they do not depend on the model). `planned`: the experiment's LLM cells (model, prompt_strategy,
    history_mode, trials), so rows not run yet, or not all their trials, show as such. The seed policy last."""
    llm = trials[trials["policy"] == "llm"] if "policy" in trials else trials.iloc[0:0]
    cells = pd.concat([llm, planned if planned is not None else llm.iloc[0:0]], ignore_index=True)
    labels = _prompt_labels(cells) if not cells.empty else pd.Series(dtype=object)
    llm = llm.assign(prompt_label=labels.iloc[:len(llm)].to_numpy())  # labelled beside the planned cells, as the keys
    cell_keys = set(zip(cells.get("model", []), labels))
    planned_trials = {} if planned is None or "trials" not in planned else dict(  # (model, label) -> trials planned
        zip(zip(cells["model"].iloc[len(llm):], labels.iloc[len(llm):]), planned["trials"]))
    keys = list(dict.fromkeys([*zip(probes.get("model", []), probes.get("strategy", [])),
                               *zip(cells.get("model", []), labels)]))
    keys.sort(key=lambda k: (k[0] in TRIVIAL, list(MODEL_NAMES).index(k[0]) if k[0] in MODEL_NAMES else 99, k[1]))
    out = []
    for model, label in keys:
        strategy = label.removesuffix(EXACT)
        row = {"model": MODEL_NAMES.get(model, model), "prompt": label}
        mine = probes[probes["strategy"] == strategy] if len(probes) else probes
        mine = mine if model in TRIVIAL or mine.empty else mine[mine["model"] == model]
        if mine.empty or label != strategy:
            row["probe skill [95%]"] = "not run yet" if label == strategy else "-"
            row["gain over the prompt's trivial answer [95%]"] = "-"
        elif model in TRIVIAL:
            row["probe skill [95%]"] = f"{float(mine.iloc[0][TRIVIAL[model]]):.3f}"
            row["gain over the prompt's trivial answer [95%]"] = "-"
        else:
            r = mine.iloc[0]
            row["probe skill [95%]"] = _interval(r["skill"], r["skill_low"], r["skill_high"])
            row["gain over the prompt's trivial answer [95%]"] = _interval(r["gain"], r["gain_low"], r["gain_high"],
                                                                           signed=True)
        row.update(_closed_loop(llm[(llm["model"] == model) & (llm["prompt_label"] == label)],
                                in_study=(model, label) in cell_keys, planned=planned_trials.get((model, label))))
        out.append(row)
    if "policy" in trials:
        rl = trials[trials["policy"] == "rl"]
        if not rl.empty:
            out.append({"model": "seed policy (PPO)", "prompt": "-", "probe skill [95%]": "-",
                        "gain over the prompt's trivial answer [95%]": "-", **_closed_loop(rl)})
    return pd.DataFrame(out)


def _seconds(value: float) -> str:
    return "-" if np.isnan(value) else f"{value:.1f}"


def _closed_loop(g: pd.DataFrame, in_study: bool = True, planned: int | None = None) -> dict:
    """A row's closed-loop columns (`in_study`: the experiment's closed loop holds the row, run or not; `planned`:
    its trial count, to mark a row with fewer trials stored as partial)."""
    if g.empty:
        return {"closed loop: NWT": "not run yet" if in_study else "probe only", "success [95%]": "-", "distance (m)": "-", "s / query": "-",
                "replies repeating / copying": "-"}
    n, wins = len(g), int(g["success"].sum())
    low, high = wilson(wins, n)
    model = g["policy"].eq("llm").all() and g["model"].iloc[0] not in TRIVIAL
    repeat = g["repeat_fraction"].dropna() if "repeat_fraction" in g else pd.Series(dtype=float)
    copy = g["copy_fraction"].dropna() if "copy_fraction" in g else pd.Series(dtype=float)
    partial = f" (partial: {n} of {planned} trials)" if planned and n < planned else ""
    return {"closed loop: NWT": f"{g['nwt'].mean():.2f}", "success [95%]": f"{wins}/{n} [{low:.2f}, {high:.2f}]{partial}",
            "distance (m)": f"{g['distance_m'].mean():.1f}",
            "s / query": _seconds(live_latency_mean(g)) if model else "-",
            "replies repeating / copying": f"{repeat.mean():.2f} / {copy.mean():.2f}" if len(repeat) else "-"}


def study_section(trials: pd.DataFrame, probes: pd.DataFrame, planned: pd.DataFrame | None = None) -> list[str]:
    """The study's headline table (what the README copies), when the store holds a probe stage or more than one
    prompt strategy."""
    strategies = trials["prompt_strategy"].dropna().unique() if "prompt_strategy" in trials else []
    if probes.empty and len(strategies) < 2:  # not a study of prompt strategies
        return []
    table = study_table(trials, probes, planned)
    if table.empty:
        return []
    return ["## The study: each model and prompt, probe and closed loop", "",
            "Probe: teacher-forced skill at the closed loop's history, with the gain over the better of the same "
            "prompt's trivial answers (paired 95% interval). Closed loop: normalized walking time, success with its "
            "Wilson interval, distance walked in the 10 s evaluated, seconds per query (2 threads) and the fraction "
            "of replies that repeat the previous action or copy an example line verbatim. Embedded models run "
            "`shifted` history (llama.cpp's KV-cache reuse, an approximation) on prompts with a chronological window "
            "and read window-less prompts (`nearest-only`) exactly, unless a row's cell says otherwise; a row marked "
            "exact history is the exact twin of a shifted row of the same model and prompt, on the same seeds, and "
            "measures the approximation's effect.", "", "<!-- study table -->", "", to_markdown(table), "",
            "<!-- end of study table -->", ""]


def _cached_share(g: pd.DataFrame) -> str:
    """Cached replies over all queries of a row's trials ("-" when the trials did not count them): a prompt seen
    before (a resumed trial, a robot standing still) reads its reply back, so s / query covers only the live ones."""
    if "cache_hits" not in g or "queries" not in g or g["queries"].fillna(0).sum() == 0:
        return "-"
    return f"{int(g['cache_hits'].fillna(0).sum())}/{int(g['queries'].fillna(0).sum())}"


def revisit_fraction(actions, back: int = REVISIT_BACK) -> float | None:
    """The fraction of a trial's replies that return verbatim to one of the model's own replies 2 to `back` queries
    earlier without repeating the one just before: a model that loops a few of its own lines scores high, one that
    freezes (repeats) or writes new actions scores low. None when the trial stored no replies."""
    if not isinstance(actions, (list, tuple, np.ndarray)) or len(actions) == 0:
        return None
    replies = [tuple(np.round(np.asarray(a, dtype=float), 4)) for a in actions]
    revisits = sum(1 for i in range(2, len(replies)) if replies[i] != replies[i - 1]
                   and replies[i] in replies[max(0, i - back):i - 1])
    return revisits / len(replies)


def _phase_end(r) -> float | None:
    """s after the takeover at which the robot first fell or stopped walking (None: it walked to the end)."""
    ends = [t for t in (r.get("fall_time"), r.get("stop_time")) if t is not None and not pd.isna(t)]
    return float(min(ends) - r["eval_start"]) if ends else None


def diagnostics_table(trials: pd.DataFrame, label: str) -> pd.DataFrame:
    out = []
    for key, g in trials.groupby(label, sort=False):
        n, wins = len(g), int(g["success"].sum())
        low, high = wilson(wins, n)
        ends = [_phase_end(r) for _, r in g.iterrows()]
        stopped = [e for e in ends if e is not None]
        row = {label: key, "trials": n, "NWT": round(float(g["nwt"].mean()), 2),
               "success [95%]": f"{wins / n:.2f} [{low:.2f}, {high:.2f}]",
               "fell or stopped": f"{len(stopped)}/{n}",
               "after (s, median)": round(float(np.median(stopped)), 1) if stopped else "-"}
        cut = ended_at_stop(g)
        if cut:
            row["ended at the stop"] = f"{cut}/{n}"  # their replies end there
        for name in DIAGNOSTICS:
            values = g[name].dropna().astype(float) if name in g else pd.Series(dtype=float)
            row[name.replace("_mean", "").replace("_", " ")] = round(float(values.mean()), 3) if len(values) else "-"
        loops = [v for v in map(revisit_fraction, g.get("diag_llm_actions", [])) if v is not None]
        row[f"revisits (2-{REVISIT_BACK} back)"] = round(float(np.mean(loops)), 3) if loops else "-"
        row["replies from the cache"] = _cached_share(g)
        out.append(row)
    return pd.DataFrame(out)


def targets_figure(row: pd.Series, title: str, path: Path) -> Path | None:
    """One trial's decoded replies against the seed policy's actions for the same states, four joints."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    llm, seed = row.get("diag_llm_actions"), row.get("diag_seed_actions")
    if llm is None or seed is None or len(llm) == 0:
        return None
    llm = np.array([np.asarray(a, dtype=float) for a in llm])
    seed = np.array([np.asarray(a, dtype=float) for a in seed])
    t = float(row["eval_start"]) + 0.1 * np.arange(len(llm))
    fig, axes = plt.subplots(len(SHOWN_JOINTS), 1, figsize=(7.5, 1.6 * len(SHOWN_JOINTS)), sharex=True)
    for ax, j in zip(axes, SHOWN_JOINTS):
        ax.plot(t, seed[:, j], color="black", lw=1.2, label="seed policy (same state, not shown to the model)")
        ax.plot(t, llm[:, j], color="tab:red", lw=1.0, label="model's reply")
        ax.set_ylabel(JOINT_NAMES[j], fontsize=8)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=9)
    return save_figure(fig, path, dpi=110)


def progress_figure(trials: pd.DataFrame, label: str, path: Path) -> Path | None:
    """Every trial's forward progress after the takeover, one panel per row; a + marks where a stop began (the first
    window of the walking test's length with too little progress), an x a fall. None when no trial stored its base
    trajectory."""
    if "traj_base_x" not in trials:
        return None
    have = trials[trials["traj_base_x"].map(lambda x: isinstance(x, (list, np.ndarray)) and len(x) > 0)]
    if have.empty:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(have.groupby(label, sort=False))
    cols = min(3, len(groups))
    rows = -(-len(groups) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(max(3.4 * cols, 6.0), 2.8 * rows + 0.5), sharex=True, sharey=True,
                             squeeze=False)
    for ax, (key, g) in zip(axes.flat, groups):
        for _, r in g.sort_values("seed").iterrows():
            x = np.asarray(r["traj_base_x"], dtype=float)
            t = step_times(r, len(x)) - float(r["eval_start"])
            after = t >= -1e-9
            if not after.any():
                continue
            progress = x[after] - x[after][0]
            ax.plot(t[after], progress, lw=0.9)
            end = _phase_end(r)
            if end is not None:
                i = min(int(np.searchsorted(t[after], end)), len(progress) - 1)
                fell_first = pd.notna(r.get("fall_time")) and float(r["fall_time"]) - float(r["eval_start"]) <= end
                ax.plot(t[after][i], progress[i], marker="x" if fell_first else "+", color="black", ms=7)
        total = int((trials[label] == key).sum())
        ax.set_title(f"{key}\n({len(g)} trials)" if len(g) == total else f"{key}\n({len(g)} of {total} trials: those "
                     "that stored it)", fontsize=8)
    for ax in axes.flat[len(groups):]:
        ax.axis("off")
    for column in range(cols):  # the lowest panel of each column carries the time axis
        lowest = axes[(len(groups) - 1 - column) // cols, column]
        lowest.xaxis.set_tick_params(labelbottom=True)
        lowest.set_xlabel("s after the takeover", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("forward progress (m)", fontsize=8)
    first = have.iloc[0]
    fig.suptitle(f"Progress after the takeover, every trial\n(+ a stop begins: under {first['walk_min_speed']:.2f} m/s "
                 f"over {first['walk_window_s']:g} s; x a fall)", fontsize=9)
    return save_figure(fig, path, dpi=110)


def diagnostics_section(trials: pd.DataFrame, out: Path, name: str, label: str) -> tuple[list[str], list[Path]]:
    """Markdown lines and figures for the LLM trials' diagnostics (empty when no trial recorded them)."""
    if trials.empty or "repeat_fraction" not in trials or trials["repeat_fraction"].isna().all():
        return [], []
    llm = trials[trials["repeat_fraction"].notna()]
    lines = ["## Closed-loop diagnostics", "",
             "Per LLM trial, averaged per row: when the robot first fell or stopped walking after the takeover, the "
             "fraction of replies that repeat the action before them (freezing) or copy an example line of their "
             "prompt verbatim, and the mean absolute distance (action units, as written) of each reply from the "
             "nearest demonstration action and from the seed policy's action for the same state (the oracle, "
             "computed alongside, never shown to the model). Revisits counts the replies that return verbatim to "
             f"one of the model's own replies 2 to {REVISIT_BACK} queries before without repeating the last one: a model "
             "looping a few of its own lines (which a chronological history then shows it as examples) rather than "
             "freezing on one; a gait that copies the same demonstration lines every cycle revisits too, and the "
             "progress figure tells the two apart. Replies from the cache counts the replies read "
             "back from the on-disk reply cache: a prompt seen before (a resumed or rerun trial, or a robot standing "
             "still so that its prompt repeats) gets the same greedy reply without a model call, and s / query "
             "covers the live replies only.", "", to_markdown(diagnostics_table(llm, label)), ""]
    figures = []
    progress = progress_figure(trials, label, out / "figures" / f"{name}_progress.png")
    if progress is not None:
        figures.append(progress)
        lines += ["Where each trial stops or falls: its forward progress after the takeover (the trials that stored "
                  "their base trajectory), a mark where a stop began or a fall came:", "",
                  f"![progress after the takeover](figures/{progress.name})", ""]
    models = llm[~llm["model"].isin(REFERENCE_KINDS)]
    for key, group in models.groupby(label, sort=False):
        best = group.sort_values(["nwt", "seed"], ascending=[False, True]).iloc[0]
        figure = targets_figure(best, f"{key}, seed {int(best['seed'])}: NWT {best['nwt']:.2f}",
                                out / "figures" / f"{name}_targets_{key}.png")
        if figure is not None:
            figures.append(figure)
            lines += [f"{key}: the replies of its longest walk (seed {int(best['seed'])}, NWT {best['nwt']:.2f}) "
                      "against the seed policy's actions for the same states:", "",
                      f"![{key}: replies against the seed policy](figures/{figure.name})", ""]
    return lines, figures
