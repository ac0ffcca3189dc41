"""How fast is a model as a 10 Hz controller? Query latency by history length and history mode.

    bench latency --histories 10 50 --queries 8

For each history length and mode (sliding window, or grow-then-cut-in-blocks, which keeps
llama.cpp's prompt cache valid between cuts), one A1 trial in MuJoCo: the seed policy fills
the history, then the LLM answers `queries` times. All cells share one loaded model, in one
run; the on-disk cache is bypassed so every latency is real.
"""

from __future__ import annotations

import sys
import numpy as np
from tqdm import tqdm

from benchmark.cell import CellSpec, Resources, Runtime, TrialHooks, run_cell
from benchmark.llm.controller import CONTROL_DT, LLMSettings


def measure(model_spec: str, histories: list[int], modes: list[str], queries: int, threads: int | None = None,
            url: str | None = None) -> list[dict]:
    """One row per (history, mode): latency of `queries` live queries after the seed policy filled the history."""
    resources = Resources(Runtime(threads=threads, cache=False))
    rows = []
    try:
        cells = [(h, m) for h in histories for m in modes]
        for history, mode in tqdm(cells, desc="latency cells", file=sys.stderr, disable=None):
            takeover = round(LLMSettings().seed_start + CONTROL_DT * history, 1)
            settings = LLMSettings(model=model_spec, url=url, history=history, history_mode=mode, llm_after=takeover)
            cell = CellSpec(sim="mujoco", robot="a1", policy="llm", duration=takeover + CONTROL_DT * queries,
                            settings=settings)
            watch = _Queries()
            trial = run_cell(cell, [0], resources, hooks=[watch])[0]
            latency = np.array([q.reply.latency_s for q in watch.queries])
            rows.append({"history": history, "mode": mode, "queries": len(latency),
                         "prompt_tokens": float(np.mean([q.reply.prompt_tokens for q in watch.queries])),
                         "latency_first_s": float(latency[0]), "latency_mean_s": float(latency.mean()),
                         "latency_p95_s": float(np.percentile(latency, 95)),
                         "latency_after_first_s": float(latency[1:].mean()) if len(latency) > 1 else None,
                         "fell": not trial.success})
    finally:
        resources.close()
    return rows


class _Queries(TrialHooks):
    """Keeps the LLM policy's queries of the trial."""

    def start(self, seed, sim, policy, episode):
        self.policy = policy

    def end(self, seed, result) -> None:
        self.queries = list(self.policy.queries)
