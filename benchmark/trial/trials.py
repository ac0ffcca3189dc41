"""`run_cell`: the one path from a checked cell to its trials' results, and the hooks that watch them.

    cell = make_cell({"sim": "pybullet", "robot": "anymal", "policy": "rl"})
    results = run_cell(cell, seeds=range(5))
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from benchmark.trial.cell import CellSpec
from benchmark.trial.disturbances import DISTURBANCES
from benchmark.trial.policy import Policy, build_policy
from benchmark.trial.resources import Resources
from benchmark.trial.runner import EpisodeConfig, StepCallback, TrialResult, run_trial
from robots import load_robot
from sims.base import Simulator
from sims.terrain import Terrain


class TrialHooks:
    """Watch trials as they run: `start` may return a per-step callback; `end` sees the result."""

    def start(self, seed: int, sim: Simulator, policy: Policy, episode: EpisodeConfig) -> StepCallback | None:
        return None

    def end(self, seed: int, result: TrialResult) -> None:
        pass


class KeepPolicy(TrialHooks):
    """Keeps the policy of the last trial, to read what it saw afterwards (queries, the last prompt)."""

    def start(self, seed: int, sim: Simulator, policy: Policy, episode: EpisodeConfig) -> None:
        self.policy = policy


def run_cell(cell: CellSpec, seeds: Iterable[int], resources: Resources | None = None,
             hooks: Sequence[TrialHooks] = ()) -> list[TrialResult]:
    """Run one trial per seed of `cell`; engines and models come from `resources` (or are made
    and closed here). Hooks see every trial as it runs, so finished trials survive an error."""
    own = resources is None
    resources = resources or Resources()
    try:
        robot = load_robot(cell.robot)
        terrain = Terrain(cell.terrain, seed=cell.terrain_seed)
        sim = resources.sim(cell, robot, terrain)
        policy = build_policy(cell, robot, resources)
        episode = EpisodeConfig(duration=cell.duration, eval_start=cell.eval_start, heading_hold=cell.heading_hold,
                                disturbance=DISTURBANCES[cell.disturbance], end_at_stop=resources.runtime.end_at_stop)
        results = []
        try:
            for seed in seeds:
                steps = [cb for cb in (h.start(seed, sim, policy, episode) for h in hooks) if cb is not None]
                on_step = (lambda loop: [cb(loop) for cb in steps]) if steps else None
                result = run_trial(sim, robot, terrain, policy, episode, seed=seed, on_step=on_step)
                for hook in hooks:
                    hook.end(seed, result)
                results.append(result)
        finally:
            policy.close()
        return results
    finally:
        if own:
            resources.close()


def run_side_by_side(cell: CellSpec, seeds: list[int], resources: Resources, hooks: Sequence[TrialHooks] = (),
                     concurrency: int = 2) -> None:
    """Up to `concurrency` trials of `cell` in flight as threads, each on engines of its own (engines are not
    thread-safe), all asking the models of `resources.shared`: an embedded model made with `runtime.slots` =
    `concurrency` gives each trial a llama.cpp slot, so their queries are read and decoded in shared batches."""
    from concurrent.futures import ThreadPoolExecutor

    def one(seed: int) -> None:
        mine = Resources(resources.runtime, resources.shared)
        try:
            run_cell(cell, [seed], mine, hooks=hooks)
        finally:
            mine.close()

    with ThreadPoolExecutor(max_workers=concurrency, thread_name_prefix="trial") as pool:
        for future in [pool.submit(one, seed) for seed in seeds]:
            future.result()
