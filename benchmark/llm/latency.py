"""How fast is a model as a 10 Hz controller, and what does a fast approximation cost?

    bench latency --histories 10 50 --queries 8
    bench latency --histories 50 --modes sliding --strategies chronological nearest nearest-only sorted cycle

For each history length and history mode, one A1 trial in MuJoCo: the seed policy fills the
history, then the LLM answers `queries` times (the on-disk cache is off, so every latency is
real). Modes: `sliding` (exact, the paper's), `block` (exact, grows then cuts 10 pairs, so
llama.cpp's prefix cache stays valid between cuts) and `shifted` (the sliding window with
llama.cpp's KV-cache shifting: cached chunks are moved to their new positions instead of
recomputed, which is an APPROXIMATION: their keys and values were computed with the dropped
pair still in context).

Drafts: `ngram` (the default) is llama.cpp's n-gram speculative decoding, which drafts the reply
from earlier tokens and checks the draft in one batch; `--drafts ngram none` measures both and
how many replies the draft changes.

Drift: every reply of every row is compared with a cold recompute of the same prompt (no
cache at all): the fraction of identical replies and the mean absolute difference of the
decoded actions. For `shifted`, `outcome_changed` says whether the trial ended differently
(success or NWT) from the exact `sliding` trial of the same seed.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from tqdm import tqdm

from benchmark.trial.cell import CellSpec
from benchmark.trial.resources import Resources, Runtime
from benchmark.trial.trials import KeepPolicy, run_cell
from benchmark.llm.controller import CONTROL_DT, LLMSettings
from benchmark.llm.replies import parse_reply
from benchmark.llm.strategies import DEFAULT_STRATEGY

MODES = ("sliding", "block", "shifted")


def _drift(policy) -> dict:
    """Replies against a cold recompute of the same prompts, on the same model."""
    model, identical, diffs = policy.model, 0, []
    for q in policy.queries:
        again = model.complete(q.prompt, policy.settings.sampling, policy.constraint, cold=True)
        identical += again.text == q.reply.text
        a = parse_reply(q.reply.text, policy.encoding, policy.robot.num_joints)
        b = parse_reply(again.text, policy.encoding, policy.robot.num_joints)
        if a is not None and b is not None:
            diffs.append(float(np.mean(np.abs(a - b))))
    n = max(1, len(policy.queries))
    return {"identical_to_cold": identical / n, "action_diff_vs_cold": float(np.mean(diffs)) if diffs else None}


def measure(model_spec: str, histories: list[int], modes: list[str], queries: int, threads: int | None = None,
            url: str | None = None, drift: bool = True, drafts: tuple[str, ...] = (Runtime.draft,),
            strategies: tuple[str, ...] = (DEFAULT_STRATEGY,)) -> list[dict]:
    """One row per (history, mode, draft, prompt strategy): latency of `queries` live queries after the seed policy filled the
    history. Every cell loads its own model, so none starts from what another cell (or a cold recompute) left
    in llama.cpp's cache: a shifted cell that followed another's cold recomputes measured 27 s instead of 2 s.
    With both drafts, `same_as_no_draft` is the fraction of replies equal to the undrafted cell's, query by query."""
    rows, replies, started = [], {}, time.perf_counter()
    cells = [(h, m, d, s) for h in histories for m in modes for d in drafts for s in strategies]
    bar = tqdm(cells, desc="latency cells", file=sys.stderr, disable=None)
    for history, mode, draft, strategy in bar:
        resources = Resources(Runtime(threads=threads, cache=False, draft=draft))
        try:
            takeover = round(LLMSettings().seed_start + CONTROL_DT * history, 1)
            settings = LLMSettings(model=model_spec, url=url, history=history, history_mode=mode, llm_after=takeover,
                                   prompt_strategy=strategy)
            cell = CellSpec(sim="mujoco", robot="a1", policy="llm", duration=takeover + CONTROL_DT * queries,
                            settings=settings)
            watch = KeepPolicy()
            trial = run_cell(cell, [0], resources, hooks=[watch])[0]
            policy = watch.policy
            latency = np.array([q.reply.latency_s for q in policy.queries])
            replies[history, mode, draft, strategy] = [q.reply.text for q in policy.queries]
            row = {"history": history, "mode": mode, "draft": draft, "strategy": strategy,
                   "approximate": settings.approximate,
                   "queries": len(latency),
                   "prompt_tokens": float(np.mean([q.reply.prompt_tokens for q in policy.queries])),
                   "latency_first_s": float(latency[0]), "latency_mean_s": float(latency.mean()),
                   "latency_p95_s": float(np.percentile(latency, 95)),
                   "latency_after_first_s": float(latency[1:].mean()) if len(latency) > 1 else None,
                   "success": trial.success, "nwt": trial.nwt}
            if drift and hasattr(policy.model, "cache_reuse"):
                row.update(_drift(policy))
            rows.append(row)
            if bar.disable:  # not a terminal (nohup, CI, a pipe): a line per cell instead of nothing
                named = f", {strategy}" if strategy != DEFAULT_STRATEGY else ""
                print(f"bench: latency cell {len(rows)}/{len(cells)} (history {history}, {mode}, draft {draft}{named}): "
                      f"{row['latency_mean_s']:.2f} s a query, {time.perf_counter() - started:.0f} s so far",
                      file=sys.stderr, flush=True)
        finally:
            resources.close()
    for row in rows:
        plain = replies.get((row["history"], row["mode"], "none", row["strategy"]))
        if row["draft"] != "none" and plain is not None:
            mine = replies[row["history"], row["mode"], row["draft"], row["strategy"]]
            row["same_as_no_draft"] = sum(a == b for a, b in zip(mine, plain)) / max(1, min(len(mine), len(plain)))
        exact = next((r for r in rows if r["history"] == row["history"] and r["mode"] == "sliding"
                      and r["draft"] == row["draft"] and r["strategy"] == row["strategy"]), None)
        if row["approximate"] and exact is not None:
            row["outcome_changed"] = (row["success"], round(row["nwt"], 6)) != (exact["success"], round(exact["nwt"], 6))
    return rows
