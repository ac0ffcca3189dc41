"""How fast is a model as a 10 Hz controller? Query latency by history length and history mode.

    bench latency --histories 10 50 --queries 8

For each history length and mode (sliding window, or grow-then-cut-in-blocks, which keeps
llama.cpp's prompt cache valid between cuts), one A1 trial in MuJoCo: the seed policy fills
the history, then the LLM answers `queries` times. All cells share one loaded model, in one
run; the on-disk cache is bypassed so every latency is real.
"""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
from tqdm import tqdm

from benchmark.llm.models import make_model
from benchmark.llm.policy import LLMConfig, LLMPolicy
from benchmark.llm.prompt import PromptConfig
from benchmark.runner import EpisodeConfig, run_trial
from robots import load_robot
from sims import make_sim
from sims.terrain import Terrain


def measure(model_spec: str, histories: list[int], modes: list[str], queries: int, threads: int | None = None,
            url: str | None = None) -> list[dict]:
    robot, terrain = load_robot("a1"), Terrain("flat")
    model = make_model(model_spec, url=url, cache=False, threads=threads)
    sim = make_sim("mujoco", robot, terrain)
    rows = []
    try:
        cells = [(h, m) for h in histories for m in modes]
        for history, mode in tqdm(cells, desc="latency cells", file=sys.stderr, disable=None):
            base = LLMConfig(model=model_spec, prompt=PromptConfig(history=history), history_mode=mode, cache=False)
            takeover = round(base.seed_start + 0.1 * history, 1)
            config = replace(base, llm_after=takeover)
            policy = LLMPolicy(robot, config, model=model)
            trial = run_trial(sim, robot, terrain, policy, EpisodeConfig(takeover + 0.1 * queries, takeover), seed=0)
            latency = np.array([q.reply.latency_s for q in policy.queries])
            rows.append({"history": history, "mode": mode, "queries": len(latency),
                         "prompt_tokens": float(np.mean([q.reply.prompt_tokens for q in policy.queries])),
                         "latency_first_s": float(latency[0]), "latency_mean_s": float(latency.mean()),
                         "latency_p95_s": float(np.percentile(latency, 95)),
                         "latency_after_first_s": float(latency[1:].mean()) if len(latency) > 1 else None,
                         "fell": not trial.success})
    finally:
        sim.close()
        model.close()
    return rows
