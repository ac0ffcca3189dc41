"""The 10 Hz episode loop and its per-trial metrics.

One loop for everything: observation -> policy -> targets -> `sim.step`. Metrics count the
evaluated phase only (from `eval_start`, e.g. an LLM's takeover, to the end), so a seed
policy's warm-up never inflates another policy's score.

Walking, not standing: the robot walks while its progress along the commanded direction
(world +x, the line the heading hold keeps it on) over the last `Walking.window_s` is at least
`min_speed_fraction` of the commanded speed. NWT is the fraction of the evaluated phase before
the robot first falls or stops walking; success is finishing the phase upright, still walking,
having covered `min_distance_fraction` of the commanded distance. `upright_fraction` is the
old "time before a fall" figure, which a robot standing still wins.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from benchmark.trial.control import FIXED_COMMAND, ControlLoop, HeadingHold, yaw_of
from benchmark.trial.disturbances import NO_DISTURBANCE, Disturbance
from benchmark.trial.policy import Policy
from robots import Robot
from sims.base import Simulator
from sims.terrain import Terrain


@dataclass(frozen=True)
class EpisodeConfig:
    duration: float = 10.0  # s of simulated time
    eval_start: float = 0.0  # s; metrics cover [eval_start, duration]
    heading_hold: bool = False  # steer through the yaw-rate command (benchmark.trial.control.HeadingHold); off: fixed command
    disturbance: Disturbance = NO_DISTURBANCE  # shoves or changed dynamics after eval_start
    end_at_stop: bool = False  # end at the first stop: NWT and success are decided (benchmark.trial.resources.Runtime)

    def __post_init__(self) -> None:
        if not self.duration > 0:
            raise ValueError(f"duration must be > 0 s, got {self.duration}")
        if not 0 <= self.eval_start < self.duration:
            raise ValueError(f"eval_start must be in [0, duration), got {self.eval_start}")


@dataclass(frozen=True)
class Walking:
    """When is a robot walking? Recorded with every result (`walk_*` columns).

    Chosen so that standing and a frozen policy fail at once while an honest walker that
    stumbles passes: standing moves < 0.03 m/s and a model that holds its last action 0.01-0.02
    m/s. A 2 s window holds 4-6 trot cycles (the seed policies step at 2-3 Hz); with 1 s, A1 on
    rough ground dipped to 0.20-0.27 m/s in 4 of 20 MuJoCo trials while walking on, and ANYmal
    on rough ground was pushed backwards by bumps for a second in 11 of 20 (README, "Metrics").
    """

    window_s: float = 2.0  # s of progress a speed is measured over
    min_speed_fraction: float = 0.2  # of the commanded forward speed, over every window
    min_distance_fraction: float = 0.4  # of the commanded distance over the phase, for success

    def min_speed(self, command_vx: float) -> float:
        """m/s of progress every window needs: the walking test's bar for this command."""
        return self.min_speed_fraction * abs(command_vx)


@dataclass(frozen=True)
class TrialResult:
    seed: int
    nwt: float  # normalized walking time: evaluated time before a fall or a stop / evaluated duration
    success: bool  # upright and walking to the end of the evaluated phase, far enough
    upright_fraction: float | None  # evaluated time before a fall / evaluated duration (standing counts); None:
    # the trial ended at its stop (EpisodeConfig.end_at_stop), so a later fall is unknown
    distance_m: float  # base displacement along the world x axis (forward), evaluated phase
    lateral_drift_m: float  # base displacement along world y, evaluated phase
    mean_vx: float  # mean base-frame forward velocity while walking, m/s
    mean_height_m: float  # mean base height above the terrain while walking
    heading_change_rad: float  # net yaw over the evaluated phase (unwrapped: a circle is 2 pi)
    fall_time: float | None  # s since the start of the episode
    fall_reason: str | None
    stop_time: float | None  # s: start of the first window the robot did not walk through
    walk_window_s: float
    walk_min_speed: float  # m/s
    walk_min_distance_m: float
    control_steps: int
    wall_s: float
    ended_at_stop: bool = False  # the episode was cut at its first stop (EpisodeConfig.end_at_stop)
    policy_metrics: dict = field(default_factory=dict)  # e.g. the LLM's tokens, latency, parse failures

    def to_dict(self) -> dict:
        """Flat: policy metrics sit beside the trial metrics."""
        out = asdict(self)
        extra = out.pop("policy_metrics")
        return {**out, **extra}


StepCallback = Callable[[ControlLoop], None]


def first_stop(x: np.ndarray, dt: float, window_s: float, min_speed: float) -> float | None:
    """Seconds into the phase at which the first window without walking starts, or None.

    `x[i]` is the progress along the commanded direction after i control steps of the phase
    (x[0] at its start). A phase shorter than the window is judged over its whole length.
    """
    n = int(round(window_s / dt))
    if len(x) < 2:
        return None
    if len(x) <= n:
        return 0.0 if (x[-1] - x[0]) / ((len(x) - 1) * dt) < min_speed else None
    speeds = (x[n:] - x[:-n]) / (n * dt)
    slow = np.flatnonzero(speeds < min_speed)
    return float(slow[0] * dt) if slow.size else None


def window_stopped(x: list[float], dt: float, window_s: float, min_speed: float) -> bool:
    """Whether the window ending at the newest step of `x` is too slow: checked after every step, the first True
    falls on the window `first_stop` finds first (same arithmetic), so a trial ended there keeps its NWT and success."""
    n = int(round(window_s / dt))
    return len(x) > n and (x[-1] - x[-1 - n]) / (n * dt) < min_speed


def walking_metrics(x: np.ndarray, yaw: np.ndarray, fall_after: float | None, evaluated: float, dt: float,
                    command_vx: float, walking: Walking = Walking()) -> dict:
    """NWT, success, upright fraction, stop time and net heading change of one evaluated phase.

    `x` and `yaw` hold the phase's progress and heading at every control step up to a fall;
    `fall_after` is the fall's time into the phase (None: no fall)."""
    min_speed = walking.min_speed(command_vx)
    min_distance = walking.min_distance_fraction * abs(command_vx) * evaluated
    stop = first_stop(np.asarray(x, dtype=float), dt, walking.window_s, min_speed)
    upright = fall_after if fall_after is not None else evaluated
    walked = min(upright, stop if stop is not None else evaluated)
    distance = float(x[-1] - x[0]) if len(x) else 0.0
    turns = np.diff(np.asarray(yaw, dtype=float))
    heading = float(np.sum((turns + np.pi) % (2 * np.pi) - np.pi)) if turns.size else 0.0
    return {"nwt": float(np.clip(walked / evaluated, 0.0, 1.0)),
            "success": fall_after is None and stop is None and distance >= min_distance,
            "upright_fraction": float(np.clip(upright / evaluated, 0.0, 1.0)),
            "stop_time": stop, "heading_change_rad": heading, "walk_window_s": walking.window_s,
            "walk_min_speed": min_speed, "walk_min_distance_m": min_distance}


def run_trial(sim: Simulator, robot: Robot, terrain: Terrain, policy: Policy, config: EpisodeConfig,
              seed: int, on_step: StepCallback | None = None, walking: Walking = Walking()) -> TrialResult:
    """Run one episode; `on_step(loop)` sees every control step (state, action, targets)."""
    start = time.perf_counter()
    loop = ControlLoop(sim, robot, terrain, heading=HeadingHold() if config.heading_hold else FIXED_COMMAND)
    steps = int(round(config.duration / loop.dt))
    eval_step = int(round(config.eval_start / loop.dt))
    config.disturbance.start(sim)
    loop.reset(seed)
    policy.reset(seed)
    eval_origin = loop.state.base_pos.copy()
    vx: list[float] = []
    heights: list[float] = []
    progress, yaws = [float(eval_origin[0])], [yaw_of(loop.state.base_quat)]
    fall_time, last, cut = None, loop.state, False
    min_speed = walking.min_speed(float(robot.command[0]))
    for _ in range(steps):
        loop.step(policy.act(loop.obs, loop.state))
        config.disturbance.apply(sim, loop.time - config.eval_start, loop.dt)
        state = loop.state
        if on_step is not None:
            on_step(loop)
        if loop.steps == eval_step:
            eval_origin = state.base_pos.copy()
            progress, yaws = [float(eval_origin[0])], [yaw_of(state.base_quat)]
        if loop.fall is not None:
            fall_time = loop.time
            break
        last = state
        if loop.steps > eval_step:
            vx.append(float(state.base_lin_vel[0]))
            heights.append(float(state.base_pos[2]) - terrain.height_at(*state.base_pos[:2]))
            progress.append(float(state.base_pos[0]))
            yaws.append(yaw_of(state.base_quat))
            if config.end_at_stop and window_stopped(progress, loop.dt, walking.window_s, min_speed):
                cut = True
                break
    evaluated = config.duration - config.eval_start
    fell_in_phase = fall_time is not None and fall_time > config.eval_start
    fall_after = None if fall_time is None else max(0.0, fall_time - config.eval_start)
    if fall_time is not None and not fell_in_phase:
        progress, yaws = progress[:1], yaws[:1]
    displacement = last.base_pos - eval_origin if fall_time is None or fell_in_phase else np.zeros(3)
    metrics = walking_metrics(np.array(progress), np.array(yaws), fall_after, evaluated, loop.dt,
                              float(robot.command[0]), walking)
    stop = metrics.pop("stop_time")
    if cut:
        metrics["upright_fraction"] = None  # the trial ended standing: whether it would have fallen is unknown
    return TrialResult(
        seed=seed,
        **metrics,
        distance_m=float(displacement[0]),
        lateral_drift_m=float(displacement[1]),
        mean_vx=float(np.mean(vx)) if vx else 0.0,
        mean_height_m=float(np.mean(heights)) if heights else 0.0,
        fall_time=fall_time,
        fall_reason=loop.fall,
        stop_time=None if stop is None else config.eval_start + stop,
        control_steps=loop.steps,
        wall_s=time.perf_counter() - start,
        ended_at_stop=cut,
        policy_metrics=policy.metrics(),
    )


def summarize(trials: list[TrialResult]) -> dict:
    """Means over trials: the numbers a table reports."""
    if not trials:
        return {"nwt": 0.0, "success_rate": 0.0, "upright_fraction": 0.0, "distance_m": 0.0, "mean_vx": 0.0}
    upright = [t.upright_fraction for t in trials if t.upright_fraction is not None]  # trials ended at a stop: unknown
    return {
        "nwt": float(np.mean([t.nwt for t in trials])),
        "upright_fraction": float(np.mean(upright)) if upright else None,
        "success_rate": float(np.mean([t.success for t in trials])),
        "distance_m": float(np.mean([t.distance_m for t in trials])),
        "mean_vx": float(np.mean([t.mean_vx for t in trials])),
    }
