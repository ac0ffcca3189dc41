"""The leaderboard: every scorecard row of a store, models as rows (`bench leaderboard`).

    bench leaderboard                         reports/leaderboard/rows -> reports/leaderboard.md and .html

A headline table (probe skill with its 95% interval, closed-loop NWT and success where the full
tier ran), the per-cell detail, paired comparisons (the probability, over bootstrap resamples of
the same probe items, that one model's skill beats another's) and a scatter of probe skill
against closed-loop NWT.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from benchmark.common.figures import save_figure
from benchmark.common.tables import to_markdown
from benchmark.evaluate.probe import ItemAnswers, paired_comparison
from benchmark.evaluate.scorecard import DEFAULT_STORE, load_rows, on_some_cells, row_label, row_strategy, trivial_gain

if TYPE_CHECKING:
    import pandas as pd

REFERENCE_ORDER = ("oracle", "knn", "replay", "hold", "default")


def _closed(row: dict) -> tuple[float | None, float | None, int]:
    cells = row.get("closed_loop") or {}
    if not cells:
        return None, None, 0
    return (float(np.mean([c["nwt"] for c in cells.values()])), float(np.mean([c["success"] for c in cells.values()])),
            int(sum(c["trials"] for c in cells.values())))


CELL_ORDER = ("a1/flat", "a1/rough", "anymal/flat", "anymal/rough")


def best_rows(rows: list[dict]) -> list[dict]:
    """One row per model and probe: the full tier's where it ran (its probe is the quick tier's), else the quick."""
    best: dict = {}
    for r in rows:
        key = (row_label(r), r.get("file_sha256"), r.get("server_model"), r["probe_digest"], str(r["probe_settings"]),
               row_strategy(r))
        if key not in best or (r.get("closed_loop") and not best[key].get("closed_loop")):
            best[key] = r
    return list(best.values())


def _cell_key(name: str) -> tuple:
    return (CELL_ORDER.index(name) if name in CELL_ORDER else len(CELL_ORDER), name)


def rank_correlation(rows: list[dict], models_only: bool = False) -> tuple[float | None, int]:
    """Spearman's rank correlation of probe skill with closed-loop NWT over (row, cell) points, and their count.

    `models_only` leaves the reference controllers out: how the probe orders LLMs, not walkers from freezers."""
    import pandas as pd

    rows = [r for r in rows if not (models_only and r.get("kind") == "reference")]
    points = [(r["probe"]["cells"][cell]["skill"], c["nwt"]) for r in rows
              for cell, c in (r.get("closed_loop") or {}).items() if cell in r["probe"]["cells"]]
    if len(points) < 3:
        return None, len(points)
    x, y = pd.Series([p[0] for p in points]), pd.Series([p[1] for p in points])
    return float(x.rank().corr(y.rank())), len(points)


def headline(rows: list[dict]):
    import pandas as pd

    out = []
    for r in rows:
        p = r["probe"]
        nwt, success, trials = _closed(r)
        gain = trivial_gain(r, rows)
        out.append({"model": row_label(r), "strategy": row_strategy(r), "kind": r.get("kind"),
                    "params": r.get("parameters") or "-",
                    "tier": r["tier"], "probe skill [95%]": f"{p['skill']:.3f} [{p['skill_low']:.3f}, "
                                                            f"{p['skill_high']:.3f}]",
                    "gain over the prompt's trivial answer [95%]": "-" if gain is None else
                    f"{gain[1]:+.3f} [{gain[2]:+.3f}, {gain[3]:+.3f}] over {gain[0]}",
                    "error": round(p["error"], 3), "within 1 step": round(p["within_step"], 2),
                    "parse failures": p["parse_failures"], "s/query": round(p["latency_median_s"], 2),
                    "closed-loop NWT": "-" if nwt is None else f"{nwt:.2f}",
                    "success": "-" if success is None else f"{success:.2f} ({trials} trials)",
                    "wall (min)": round(r["wall_s"] / 60, 1), "_skill": p["skill"]})
    frame = pd.DataFrame(out)
    if frame.empty:
        return frame
    frame["_ref"] = frame["kind"] == "reference"
    frame["_restricted"] = [on_some_cells(r) for r in rows]
    return frame.sort_values(["_ref", "_restricted", "_skill"], ascending=[True, True, False]).drop(
        columns=["_skill", "_ref", "_restricted"])


def per_cell(rows: list[dict]):
    import pandas as pd

    out = []
    for r in rows:
        line = {"model": row_label(r), "tier": r["tier"]}
        for cell, c in sorted(r["probe"]["cells"].items(), key=lambda kv: _cell_key(kv[0])):
            line[f"skill {cell}"] = round(c["skill"], 3)
        for cell, c in sorted((r.get("closed_loop") or {}).items(), key=lambda kv: _cell_key(kv[0])):
            line[f"NWT {cell}"] = f"{c['nwt']:.2f} ± {c['nwt_half_ci']:.2f}"
            lo, hi = c["success_ci"]
            line[f"success {cell}"] = f"{c['success']:.1f} [{lo:.2f}, {hi:.2f}]"
        out.append(line)
    frame = pd.DataFrame(out)
    skills = [c for c in frame.columns if c.startswith("skill ")]
    closed = sorted([c for c in frame.columns if c.startswith(("NWT ", "success "))],
                    key=lambda c: (_cell_key(c.split(" ", 1)[1]), not c.startswith("NWT")))
    return frame[["model", "tier", *skills, *closed]].fillna("-")


def comparisons(rows: list[dict]) -> list[tuple[str, pd.DataFrame]]:
    """(which items, P(row beats column)) for every group of model rows scored on the same probe items and settings.

    A row restricted to some cells (`bench eval --cells`) answered fewer items, so it is compared only with
    rows restricted the same way."""
    import pandas as pd

    models = [r for r in rows if r.get("kind") != "reference"]
    groups: dict = {}
    for r in models:
        key = (r["probe_digest"], str(r["probe_settings"]), tuple(r.get("cells_filter") or ()))
        groups.setdefault(key, {})[row_label(r)] = ItemAnswers.from_json(
            r["probe_items"])
    tables = []
    for (_, _, cells), answers in groups.items():
        if len(answers) < 2:
            continue
        names = list(answers)
        table = pd.DataFrame(index=names, columns=names, dtype=object)
        for a, b in itertools.permutations(names, 2):
            table.loc[a, b] = f"{paired_comparison(answers[a], answers[b]):.3f}"
        items = "the items of " + "+".join(cells) if cells else "all cells' items"
        tables.append((items, table.fillna("-").reset_index(names="P(row > column)")))
    return tables


def scatter(rows: list[dict], path: Path) -> Path | None:
    """Probe skill against closed-loop NWT for the rows that have both (one point per row and cell)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = [(r, cell, r["probe"]["cells"][cell]["skill"], c["nwt"]) for r in rows
              for cell, c in (r.get("closed_loop") or {}).items() if cell in r["probe"]["cells"]]
    if not points:
        return None
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for model in dict.fromkeys(row_label(p[0]) for p in points):
        mine = [p for p in points if row_label(p[0]) == model]
        xs, ys = [p[2] for p in mine], [p[3] for p in mine]
        if mine[0][0].get("kind") == "reference":  # references hollow, LLMs filled diamonds
            ax.scatter(xs, ys, label=f"{model} (reference)", s=30, facecolors="none",
                       edgecolors=f"C{len(ax.collections)}")
        else:
            ax.scatter(xs, ys, label=model, s=45, marker="D")
    ax.set_xlabel("probe skill (1 - error / hold's error), per cell")
    ax.set_ylabel("closed-loop NWT (10 s LLM phase), per cell")
    ax.axvline(0.0, color="grey", lw=0.8, ls=":")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=7)
    ax.set_title("Does imitation under teacher forcing predict control?", fontsize=10)
    return save_figure(fig, path, dpi=120)


FEW_MODELS = 5  # below this many LLMs with a closed loop, their correlation is a direction only


def correlation_text(rows: list[dict]) -> str:
    """Whether probe skill predicts closed-loop NWT: over every point, and over the LLMs' points alone."""
    rho, n = rank_correlation(rows)
    models = sorted({row_label(r) for r in rows if r.get("closed_loop")})
    text = (f"Spearman's rank correlation of probe skill with closed-loop NWT over the {n} (model, cell) points "
            f"that have both: {rho:.2f}." if rho is not None else "Too few points for a correlation.")
    text += f" The points come from {len(models)} row(s) ({', '.join(models)})."
    llm_rho, llm_n = rank_correlation(rows, models_only=True)
    if llm_n == 0:
        return text + (" Only reference controllers have closed-loop rows: it says how the probe orders controllers "
                       "that walk or freeze, not yet how it orders LLMs.")
    if llm_rho is None or np.isnan(llm_rho):
        return text + (f" The LLMs alone give {llm_n} point(s), too few (or too tied) for a correlation of their "
                       "own: the references' walkers and freezers carry the number above.")
    llms = {r["model"] for r in rows if r.get("kind") != "reference" and r.get("closed_loop")}
    text += f" Over the LLMs' {llm_n} points alone ({len(llms)} model(s)): {llm_rho:.2f}"
    if len(llms) < FEW_MODELS:
        return text + (f"; with {len(llms)} model(s) this is a direction, not a measurement: one model's cells differ "
                       "by trial noise, and the rest is which model both imitated and walked better.")
    return text + "."


ROUGH_MARGIN_SINCE = "2026-12-04"  # rough ground got its 20 m margin (sims/terrain.py); scorecards do not record it


def ground_lines(rows: list[dict]) -> list[str]:
    """Which rows ran their rough closed-loop cells on the rough grid before it had its margin."""
    before = [r for r in rows if str(r.get("made_at", "")) < ROUGH_MARGIN_SINCE
              and any("rough" in cell for cell in (r.get("closed_loop") or {}))]
    if not before:
        return []
    return [f"Rough ground: the closed-loop rough cells of {len(before)} row(s) made before {ROUGH_MARGIN_SINCE} ran on "
            "the rough grid's 32 x 8 m core alone, before the 20 m margin it has since (robots drifting sideways "
            "could walk off its edge: docs/matrix.md); running a row's command again remakes it.", ""]


def seed_policy_lines(rows: list[dict], store: Path) -> list[str]:
    """Which seed policies made the probe set and ran the closed loop, so rows of two policies never mix silently."""
    from benchmark.evaluate.probe import DEFAULT_PROBE, load_probe_set
    from benchmark.evaluate.scorecard import stale_seed_policies
    from benchmark.experiments.sweep import shipped_seed_policy_sha256

    lines = []
    probe = load_probe_set(DEFAULT_PROBE)
    for digest in sorted({r["probe_digest"] for r in rows}):
        made = (", ".join(f"{robot} {sha[:12]}" for robot, sha in probe.meta["seed_policy_sha256"].items())
                if digest == probe.digest else "not the shipped probe set")
        lines.append(f"Probe set `{digest}`: made with the seed policies {made}.")
        if digest == probe.digest and any(sha[:12] != shipped_seed_policy_sha256(robot)
                                          for robot, sha in probe.meta["seed_policy_sha256"].items()):
            lines.append("A probe set is a fixed dataset, like a test set, so a newly shipped seed policy leaves it "
                         "as it is and its rows stay comparable (its walks ran at the fixed command: every label is "
                         "a function of what its prompts show); `bench probe --make` makes another.")
    robots = sorted({cell.split("/")[0] for r in rows for cell in (r.get("closed_loop") or {})})
    if robots:
        lines.append("Closed loop: the shipped seed policies are " + ", ".join(
            f"{robot} {shipped_seed_policy_sha256(robot)}" for robot in robots) + ".")
        earlier = [f"{row_label(r)} ({r['tier']}: {', '.join(stale)})" for r in rows
                   if (stale := stale_seed_policies(r, store))]
        if earlier:
            lines.append("**Ran an earlier seed policy** (its `bench eval` command runs the trials again): "
                         + "; ".join(earlier) + ".")
    return [" ".join(lines), ""] if lines else []


CELL_STORES = ("reports/data/matrix", "reports/data/hard_track")  # the per-cell closed-loop view's stores


def write_leaderboard(store: Path | str = DEFAULT_STORE, out: Path | str = "reports",
                      command: str = "bench leaderboard", cell_stores: tuple[str, ...] = CELL_STORES) -> tuple[Path, Path | None]:
    """`OUT/leaderboard.md` and, when there are rows, the self-contained `OUT/leaderboard.html`; the matrix and
    hard-track stores, where they exist, add a per-cell closed-loop view."""
    from benchmark.evaluate.leaderboard_html import render
    from benchmark.experiments.report_matrix import closed_loop_view

    rows = load_rows(store)
    out = Path(out)
    page = None
    if rows:
        page = out / "leaderboard.html"
        page.parent.mkdir(parents=True, exist_ok=True)
        page.write_text(render(best_rows(rows), command))
    lines = ["# Leaderboard", "", f"Regenerate: `{command}` (from the scorecard rows in `{store}`; each row says the "
             "command that made it). " + ("The [interactive page](leaderboard.html) sorts by any column and holds "
                                          "every row's settings; it needs no network." if page else ""), "",
             "The **probe** is teacher-forced imitation (`benchmark/evaluate/probe.py`): on the same items for every model, "
             "the decoded reply is compared with the seed policy's action written in the encoding. Skill = 1 - "
             "error / error of `hold` (the newest action in the prompt): hold 0, oracle 1, below 0 worse than "
             "freezing. It measures imitation, not control. **Closed loop** is the paper's protocol (full tier): "
             "NWT and success over the LLM's 10 s; on embedded models a prompt's 50-pair chronological window is "
             "`shifted` (llama.cpp's KV-cache shifting), an **approximation** whose effect is measured in docs/models.md, "
             "while a window-less prompt (`nearest-only`) is read exactly; each trial records which "
             "(`approximate_history`). Intervals are 95% (probe: bootstrap over items; success: Wilson).",
             ""]
    shown = best_rows(rows)
    table = headline(shown)
    if table.empty:
        lines += ["No scorecards yet: `bench eval --llm knn`."]
    else:
        order = {name: i for i, name in enumerate(table["model"])}
        shown.sort(key=lambda r: order.get(row_label(r), len(order)))
        lines += [to_markdown(table), "", "A model's quick-tier row is left out here and on the page where its full "
                  "tier ran (the same probe); the store keeps both. A row named with cells in brackets "
                  "(`bench eval --cells`, for a slow model) answered only those cells' probe items: its skill "
                  "compares with the same cells' column below, not with the overall skills above it.", "",
                  *seed_policy_lines(shown, Path(store)), *ground_lines(shown),
                  "## Per cell", "",
                  to_markdown(per_cell(shown)), ""]
        for items, comparison in comparisons(rows):
            lines += [f"## Paired comparison on {items}", "", "The probability, over 2000 bootstrap resamples of the same probe "
                      "items, that the row's skill beats the column's; near 0.5 the difference is not real, above "
                      "0.975 or below 0.025 it is.", "", to_markdown(comparison), ""]
        figure = scatter(shown, out / "figures" / "leaderboard_probe_vs_closed_loop.png")
        if figure is not None:
            lines += ["## Probe skill against closed-loop NWT", "", correlation_text(shown), "",
                      f"![probe vs closed loop](figures/{figure.name})", ""]
        lines += closed_loop_view(list(cell_stores))
        made = sorted({(r["fingerprint_id"], r["fingerprint"]["cpu"]) for r in rows})
        lines += ["Made on: " + "; ".join(f"`{f}` {cpu}" for f, cpu in made) + ".", "",
                  "Commands:", "", *[f"    {r['command']}" for r in rows], ""]
    path = out / "leaderboard.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
    return path, page
