"""The cell matrix: where a model walks, where copying its prompt walks, and where only a model could.

For an experiment whose grid crosses cells (engine, robot, terrain, disturbance) with controllers that include
the seed policy's action through the text channel (`oracle`) and the walking prompt's trivial answers
(`knn_nearest_only`, `hold_nearest_only`): a figure of success per cell and controller with Wilson intervals,
a table per cell with each language model's closed-loop gain over the better trivial answer of its own prompt (the
`knn` and `hold` rows on the same examples; success, and NWT, paired over the same seeds, bootstrap 95% intervals)
and its speed, and the hard track: the cells where `oracle` walks (success >= 0.9) and both of the walking prompt's
trivial answers fail (< 0.6). Trials whose seed phase fell before the takeover are
left out of every rate here and counted apart.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.common.figures import save_figure
from benchmark.common.tables import (ended_at_stop, fell_before_takeover, live_latency_mean, shared_machine, to_markdown,
                                     wilson)
from benchmark.llm.controller import STRATEGY_FIELDS
from benchmark.llm.reference import REFERENCE_KINDS, TRIVIAL_ANSWERS

CEILING, TRIVIAL = "oracle", ("knn_nearest_only", "hold_nearest_only")  # the hard track's: the walking prompt's
# what decides the examples a prompt shows, so what copying it gives (not the description: `tell_disturbance`)
EXAMPLE_SETTINGS = (*STRATEGY_FIELDS, "history", "encoding", "observation")
CELL_AXES = ("sim", "robot", "terrain", "disturbance")
PAPER_CELLS = {("a1", "flat"), ("a1", "rough"), ("anymal", "flat")}  # where the paper walked a robot with GPT-4
HARD_ORACLE, HARD_TRIVIAL = 0.9, 0.6
BOOTSTRAP = 2000


def applies(group: pd.DataFrame) -> bool:
    controllers = set(group.get("controller", pd.Series(dtype=str)).dropna())
    return CEILING in controllers and bool(controllers & set(TRIVIAL)) and {"sim", "robot", "terrain"} <= set(group)


def _cell_axes(group: pd.DataFrame) -> list[str]:
    return [a for a in CELL_AXES if a in group]


def cell_label(key: tuple, axes: list[str]) -> str:
    values = dict(zip(axes, key))
    paper = (values.get("robot"), values.get("terrain")) in PAPER_CELLS and values.get("disturbance", "none") == "none"
    return "/".join(str(values[a]) for a in axes if not (a == "disturbance" and values[a] == "none")) + (" *" if paper else "")


def _by_seed(trials: pd.DataFrame, metric: str) -> pd.Series:
    return trials.set_index("seed")[metric].astype(float)


def paired_gain(model: pd.DataFrame, trivial: pd.DataFrame, rng: np.random.Generator,
                metric: str = "success") -> tuple[float, float, float, int]:
    """Mean difference of `metric` (success, or NWT) over the seeds both ran, with a bootstrap 95% interval, and the
    seed count."""
    a, b = _by_seed(model, metric), _by_seed(trivial, metric)
    seeds = a.index.intersection(b.index)
    if seeds.empty:
        return float("nan"), float("nan"), float("nan"), 0
    d = (a[seeds] - b[seeds]).to_numpy()
    means = rng.choice(d, size=(BOOTSTRAP, len(d))).mean(axis=1)
    return float(d.mean()), float(np.quantile(means, 0.025)), float(np.quantile(means, 0.975)), len(d)


def cell_rows(group: pd.DataFrame) -> pd.DataFrame:
    """One row per (cell, controller): counted trials, successes, fell before takeover, speed."""
    axes = _cell_axes(group)
    group = group.assign(early=fell_before_takeover(group))
    rows = []
    for key, cell in group.groupby(axes, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        for controller, trials in cell.groupby("controller", sort=False):
            counted = trials[~trials["early"]]
            first = trials.iloc[0]
            rows.append({"cell": cell_label(key, axes), "key": dict(zip(axes, key)), "controller": controller,
                         "examples": tuple(str(first.get(k)) for k in EXAMPLE_SETTINGS), "n": len(counted),
                         "successes": int(counted["success"].sum()), "early": int(trials["early"].sum()),
                         **cell_speed(counted),
                         "model": trials["model"].iloc[0] if "model" in trials else None, "trials": counted})
    return pd.DataFrame(rows)


def ceiling_and_trivial(by: pd.DataFrame) -> tuple[pd.Series | None, list[pd.Series]]:
    """A cell's rows indexed by controller (`cell_rows`): its `oracle` row (None: not run) and the trivial answers
    that counted a trial."""
    oracle = by.loc[CEILING] if CEILING in by.index else None
    return oracle, [by.loc[t] for t in TRIVIAL if t in by.index and by.loc[t, "n"]]


def better(rows: list[pd.Series]) -> pd.Series | None:
    """The row of higher success, and of higher mean NWT among equal successes (None: no row): the trivial answer a
    model must beat, on both of the report's gains."""
    return max(rows, key=lambda t: (t["successes"] / t["n"], t["trials"]["nwt"].mean())) if rows else None


def same_prompt_trivial(by: pd.DataFrame, controller: str) -> pd.Series | None:
    """The better of the trivial answers (`knn`, `hold`) run on the examples a model's prompt shows (the same
    EXAMPLE_SETTINGS), in a cell's rows indexed by controller (`cell_rows`): what copying that prompt gives. None
    where none ran."""
    mine = by.loc[controller, "examples"]
    trivial = [by.loc[c] for c in by.index
               if by.loc[c, "model"] in TRIVIAL_ANSWERS and by.loc[c, "examples"] == mine and by.loc[c, "n"]]
    return better(trivial)


def is_hard_cell(by: pd.DataFrame) -> bool:
    """The hard track's rule on a cell's rows indexed by controller: the ceiling walks (`oracle` success >= 0.9) and
    every trivial answer run fails (< 0.6)."""
    oracle, trivial = ceiling_and_trivial(by)
    return bool(oracle is not None and oracle["n"] and oracle["successes"] / oracle["n"] >= HARD_ORACLE and trivial
                and all(t["successes"] / t["n"] < HARD_TRIVIAL for t in trivial))


def cell_speed(trials: pd.DataFrame) -> dict:
    """Seconds a query and a trial's wall time as if every reply were live: the live replies' mean latency, or,
    where every reply came from the reply cache, the latency recorded when they were made (`replayed`); a trial's
    cached replies add that latency each to its wall time, so a replayed cell does not read as fast."""
    s_query, replayed, shared = live_latency_mean(trials), False, shared_machine(trials)
    if np.isnan(s_query) and "latency_recorded_mean_s" in trials and trials["latency_recorded_mean_s"].notna().any():
        recorded = trials.dropna(subset=["latency_recorded_mean_s"])  # weighted by queries, as the live mean is
        weights = recorded["queries"] if "queries" in recorded else None
        s_query, replayed = float(np.average(recorded["latency_recorded_mean_s"], weights=weights)), True
    if "trial_wall_s" not in trials or trials.empty:
        return {"s_query": s_query, "trial_s": float("nan"), "replayed": replayed, "shared": shared}
    cached = trials["cache_hits"].fillna(0) if "cache_hits" in trials else 0.0
    wall = trials["trial_wall_s"] + (cached * s_query if not np.isnan(s_query) else 0.0)
    return {"s_query": s_query, "trial_s": float(wall.median()), "replayed": replayed, "shared": shared}


def _rate(successes: int, n: int) -> str:
    if n == 0:
        return "-"
    low, high = wilson(successes, n)
    return f"{successes}/{n} ({successes / n:.2f} [{low:.2f}, {high:.2f}])"


def matrix_figure(rows: pd.DataFrame, path: Path, title: str) -> Path:
    """Success per cell (rows) and controller (columns): colour the rate, text k/n and the Wilson interval."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = list(dict.fromkeys(rows["cell"]))
    controllers = list(dict.fromkeys(rows["controller"]))
    rate = np.full((len(cells), len(controllers)), np.nan)
    fig, ax = plt.subplots(figsize=(1.45 * len(controllers) + 2.5, 0.42 * len(cells) + 1.6))
    for _, r in rows.iterrows():
        i, j = cells.index(r["cell"]), controllers.index(r["controller"])
        if r["n"]:
            rate[i, j] = r["successes"] / r["n"]
            low, high = wilson(r["successes"], r["n"])
            text = f"{r['successes']}/{r['n']}\n[{low:.2f}, {high:.2f}]"
        else:
            text = "-"
        if r["early"]:
            text += f" +{r['early']}e"
        ax.text(j, i, text, ha="center", va="center", fontsize=6.5,
                color="black" if np.isnan(rate[i, j]) or rate[i, j] >= 0.5 else "white")  # viridis: dark below 0.5
    for i, j in np.argwhere(np.isnan(rate)):
        if not ((rows["cell"] == cells[i]) & (rows["controller"] == controllers[j])).any():
            ax.text(j, i, "not run", ha="center", va="center", fontsize=6.5, color="grey")
    ax.imshow(np.ma.masked_invalid(rate), cmap="viridis", vmin=0, vmax=1, aspect="auto")
    ax.set_xticks(range(len(controllers)), [c.replace("_", "\n", 1) for c in controllers], fontsize=7)
    ax.set_yticks(range(len(cells)), cells, fontsize=7)
    ax.set_title(f"{title}\nsuccess k/n [Wilson 95%]; +Ne: trials whose seed phase fell before the takeover (apart); "
                 "* the paper's cells", fontsize=8)
    return save_figure(fig, path)


def probe_screen(probes: pd.DataFrame, key: dict) -> dict:
    """Each probed model's teacher-forced skill and gain over the same prompt's trivial answers in one cell (its
    engine's probe set, `cell_skills` and `cell_gains` of the probe rows; a disturbed cell's probe cell is named
    ROBOT/TERRAIN/DISTURBANCE); {} where none reaches it."""
    if probes is None or probes.empty or "cell_gains" not in probes:
        return {}
    disturbance = key.get("disturbance") or "none"  # named as probe.probe_cell reads it
    out, name = {}, f"{key.get('robot')}/{key.get('terrain')}" + ("" if disturbance == "none" else f"/{disturbance}")
    for r in probes.itertuples():
        if getattr(r, "sim", None) != key.get("sim") or not isinstance(r.cell_gains, str):
            continue
        skills, gains = json.loads(r.cell_skills), json.loads(r.cell_gains)
        if name in gains:
            gain, low, high = gains[name]
            told = " told" if getattr(r, "tell_disturbance", None) is True else ""  # the told prompt's own run
            out[f"probe: {r.model}{told}"] = f"skill {skills[name]:.2f}; gain {gain:+.2f} [{low:+.2f}, {high:+.2f}]"
    return out


def matrix_section(group: pd.DataFrame, out: Path, name: str, title: str,
                   probes: pd.DataFrame | None = None) -> tuple[list[str], list[Path]]:
    """The figure, the per-cell table with each model's paired gain and speed, each probed model's skill and gain in
    the cell, and the hard track."""
    if not applies(group):
        return [], []
    rows = cell_rows(group)
    figure = matrix_figure(rows, out / "figures" / f"{name}_matrix.png", title)
    rng = np.random.default_rng(0)
    model_of = rows.drop_duplicates("controller").set_index("controller")["model"]
    models = [c for c, m in model_of.items() if isinstance(m, str) and m not in REFERENCE_KINDS]  # language models
    table, hard = [], []
    for cell, r in rows.groupby("cell", sort=False):
        by = r.set_index("controller")
        oracle, trivial = ceiling_and_trivial(by)
        best = better(trivial)
        entry = {"cell": cell, "fell before takeover (apart)": int(r["early"].max()),
                 "oracle": _rate(oracle["successes"], oracle["n"]) if oracle is not None else "-",
                 "best trivial answer": f"{best.name}: {_rate(best['successes'], best['n'])}" if best is not None else "-"}
        is_hard = is_hard_cell(by)
        entry["hard track"] = "yes" if is_hard else ""
        if is_hard:
            hard.append(cell)
        for model in models:
            if model not in by.index or not by.loc[model, "n"]:
                entry[model] = "not run"
                continue
            m, copying = by.loc[model], same_prompt_trivial(by, model)
            text = _rate(m["successes"], m["n"])
            if copying is not None:
                gain, low, high, n = paired_gain(m["trials"], copying["trials"], rng)
                text += f"; gain {gain:+.2f} [{low:+.2f}, {high:+.2f}] over {n} seeds"
                text += "" if copying.name in TRIVIAL else f" (over `{copying.name}`, its prompt's)"
                gain, low, high, n = paired_gain(m["trials"], copying["trials"], rng, "nwt")
                text += f" (NWT {gain:+.2f} [{low:+.2f}, {high:+.2f}])"
            if not np.isnan(m["s_query"]):
                text += f"; {m['s_query']:.1f} s a query, {3600 / m['trial_s']:.1f} trials an hour"
                text += " (replayed from the reply cache: as first measured)" if m["replayed"] else ""
                text += m["shared"]
                cut = ended_at_stop(m["trials"])
                text += f" ({cut} of {len(m['trials'])} ended at their stop)" if cut else ""
            entry[model] = text
        entry.update(probe_screen(probes, r["key"].iloc[0]))
        table.append(entry)
    lines = ["", "## The cell matrix", "",
             f"![success per cell and controller](figures/{figure.name})", "",
             "Success counts only trials whose seed phase reached the takeover; those that fell before it are counted "
             "apart (the controller under test never acted). The gain is each model's success minus the better of its "
             "prompt's trivial answers (`knn`, `hold` on the same examples: nearest-only's for the walking prompt, "
             "another row's where named), paired over the seeds both ran, with a bootstrap 95% interval; in brackets "
             "the same for NWT (the fraction of the model's phase it walked), which still moves where both fall every "
             "time. Speed: seconds a query (live queries) and trials an hour "
             "(median trial, each reply the reply cache served counted at the live latency, so a resumed or replayed "
             "trial costs what a live one does). "
             "`*` marks the paper's cells (A1 flat and rough, ANYmal flat). A model row that says `not run` is a "
             "partial store's gap, not a result. `probe:` columns screen a cell teacher-forced on its engine's probe "
             "set: skill, and the gain over the same prompt's trivial answers with its paired 95% interval (at or "
             "below 0 the prompt carries the imitation).", "", to_markdown(pd.DataFrame(table)), "",
             f"**The hard track** (oracle success >= {HARD_ORACLE}, both trivial answers < {HARD_TRIVIAL}): "
             + (", ".join(hard) if hard else "no cell yet") + ".", ""]
    return lines, [figure]


def closed_loop_view(stores: list[Path]) -> list[str]:
    """The leaderboard's per-cell closed-loop view: controllers as rows, cells as columns, success k/n (trials whose
    seed phase fell before the takeover left out), from the matrix and hard-track stores that exist."""
    from benchmark.common.store import load_results

    lines = []
    for store in [Path(s) for s in stores if Path(s).is_dir() and any(Path(s).glob("trials/*"))]:
        group = load_results(store)
        group = group.sort_values(["cell_index", "seed"])
        if not applies(group):
            continue
        rows = cell_rows(group)
        hard = [cell for cell, r in rows.groupby("cell", sort=False) if is_hard_cell(r.set_index("controller"))]
        rows = rows.assign(text=[f"{r.successes}/{r.n}" if r.n else "-" for r in rows.itertuples()],
                           cell=[f"{c} (hard)" if c in hard else c for c in rows["cell"]])
        pivot = rows.pivot(index="controller", columns="cell", values="text").reindex(
            index=list(dict.fromkeys(rows["controller"])), columns=list(dict.fromkeys(rows["cell"]))).fillna("not run")
        name = group["experiment"].iloc[0]
        lines += [f"## Closed loop per cell: `{name}`", "",
                  f"Success k/n per cell (`bench sweep {name}`, report: [{name}.md]({name}.md)); trials whose seed phase "
                  "fell before the takeover are left out; `*` marks the paper's cells; `not run` is a partial store's "
                  "gap. **Hard track** "
                  f"(`oracle` success >= {HARD_ORACLE}, both trivial answers < {HARD_TRIVIAL}; `(hard)` in the header), "
                  "where a model's own contribution can show: " + (", ".join(hard) if hard else "no cell yet") + ".",
                  "", to_markdown(pivot.reset_index()), ""]
    return lines
