"""The 10 Hz episode loop and its per-trial metrics.

One loop for everything: observation -> policy -> targets -> `sim.step`. Metrics count the
evaluated phase only (from `eval_start`, e.g. an LLM's takeover, to the end), so a seed
policy's warm-up never inflates another policy's score.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from benchmark.control import ControlLoop
from benchmark.policies import Policy
from robots import Robot
from sims.base import Simulator
from sims.terrain import Terrain


@dataclass(frozen=True)
class EpisodeConfig:
    duration: float = 10.0  # s of simulated time
    eval_start: float = 0.0  # s; metrics cover [eval_start, duration]

    def __post_init__(self) -> None:
        if not self.duration > 0:
            raise ValueError(f"duration must be > 0 s, got {self.duration}")
        if not 0 <= self.eval_start < self.duration:
            raise ValueError(f"eval_start must be in [0, duration), got {self.eval_start}")


@dataclass(frozen=True)
class TrialResult:
    seed: int
    nwt: float  # normalized walking time: evaluated time before a fall / evaluated duration
    success: bool  # no fall in the evaluated phase
    distance_m: float  # base displacement along the world x axis (forward), evaluated phase
    lateral_drift_m: float  # base displacement along world y, evaluated phase
    mean_vx: float  # mean base-frame forward velocity while walking, m/s
    mean_height_m: float  # mean base height above the terrain while walking
    fall_time: float | None  # s since the start of the episode
    fall_reason: str | None
    control_steps: int
    wall_s: float
    policy_metrics: dict = field(default_factory=dict)  # e.g. the LLM's tokens, latency, parse failures

    def to_dict(self) -> dict:
        """Flat: policy metrics sit beside the trial metrics."""
        out = asdict(self)
        extra = out.pop("policy_metrics")
        return {**out, **extra}


StepCallback = Callable[[ControlLoop], None]


def run_trial(sim: Simulator, robot: Robot, terrain: Terrain, policy: Policy, config: EpisodeConfig,
              seed: int, on_step: StepCallback | None = None) -> TrialResult:
    """Run one episode; `on_step(loop)` sees every control step (state, action, targets)."""
    start = time.perf_counter()
    loop = ControlLoop(sim, robot, terrain)
    steps = int(round(config.duration / loop.dt))
    eval_step = int(round(config.eval_start / loop.dt))
    loop.reset(seed)
    policy.reset(seed)
    eval_origin = loop.state.base_pos.copy()
    vx: list[float] = []
    heights: list[float] = []
    fall_time, last = None, loop.state
    for _ in range(steps):
        loop.step(policy.act(loop.obs, loop.state))
        state = loop.state
        if on_step is not None:
            on_step(loop)
        if loop.steps == eval_step:
            eval_origin = state.base_pos.copy()
        if loop.fall is not None:
            fall_time = loop.time
            break
        last = state
        if loop.steps > eval_step:
            vx.append(float(state.base_lin_vel[0]))
            heights.append(float(state.base_pos[2]) - terrain.height_at(*state.base_pos[:2]))
    evaluated = config.duration - config.eval_start
    walked = (fall_time if fall_time is not None else config.duration) - config.eval_start
    displacement = last.base_pos - eval_origin if fall_time is None or fall_time > config.eval_start else np.zeros(3)
    return TrialResult(
        seed=seed,
        nwt=float(np.clip(walked / evaluated, 0.0, 1.0)),
        success=fall_time is None,
        distance_m=float(displacement[0]),
        lateral_drift_m=float(displacement[1]),
        mean_vx=float(np.mean(vx)) if vx else 0.0,
        mean_height_m=float(np.mean(heights)) if heights else 0.0,
        fall_time=fall_time,
        fall_reason=loop.fall,
        control_steps=loop.steps,
        wall_s=time.perf_counter() - start,
        policy_metrics=policy.metrics(),
    )


def summarize(trials: list[TrialResult]) -> dict:
    """Means over trials: the numbers a table reports."""
    if not trials:
        return {"nwt": 0.0, "success_rate": 0.0, "distance_m": 0.0, "mean_vx": 0.0}
    return {
        "nwt": float(np.mean([t.nwt for t in trials])),
        "success_rate": float(np.mean([t.success for t in trials])),
        "distance_m": float(np.mean([t.distance_m for t in trials])),
        "mean_vx": float(np.mean([t.mean_vx for t in trials])),
    }
