"""The built-in policies: `stand` (the default pose) and `rl` (the robot's shipped PPO seed policy)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmark.common.settings import setting
from benchmark.trial.cell import CellSpec
from benchmark.trial.clock import RealtimeClock
from benchmark.trial.mlp import MlpActor
from benchmark.trial.resources import Resources
from robots import Robot
from sims.base import RobotState


class StandPolicy:
    """Holds the default pose: the baseline every other policy must beat."""

    name = "stand"

    def __init__(self, robot: Robot) -> None:
        self._zeros = np.zeros(robot.num_joints)

    @classmethod
    def from_cell(cls, cell: CellSpec, robot: Robot, resources: Resources) -> StandPolicy:
        return cls(robot)

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: np.ndarray, state: RobotState) -> np.ndarray:
        return self._zeros

    def metrics(self) -> dict:
        return {}

    def close(self) -> None:
        pass


@dataclass(frozen=True)
class SeedSettings:
    """The seed policy's cell: which actor, and the protocol's timing. With an LLM cell's `seed_start`
    and `llm_after`, the seed-policy row walks the same trajectory up to the takeover and is evaluated
    over exactly the LLM's phase, from the same state."""

    policy_file: str | None = setting(None, "a policy.npz written by bench train, instead of the robot's shipped "
                                            "one (evaluate before you ship)")
    seed_start: float = setting(0.0, "s: stand until then (1 in the LLM protocol)", minimum=0)
    llm_after: float = setting(0.0, "s: metrics start here (an LLM cell's takeover, for a reference row over the "
                                    "same phase)", minimum=0)
    action_delay: float = setting(0.0, "s: from llm_after on, the seed policy on the realtime clock "
                                       "(benchmark.trial.clock): each action applies this long after the observation it "
                                       "answers, the last one held meanwhile; 0: every step, as trained", minimum=0)

    eval_start_setting = "llm_after"

    @property
    def eval_start(self) -> float:
        return self.llm_after


def seed_policy_path(robot: Robot, settings: SeedSettings | None = None) -> Path:
    """The actor a seed-policy cell runs: the given file, else the robot's shipped policy.npz."""
    given = settings.policy_file if settings else None
    path = Path(given) if given else robot.folder / "policy.npz"
    if not path.is_file():
        hint = "" if given else f"; train one with 'bench train --robot {robot.name} --ship'"
        raise ValueError(f"no seed policy for robot '{robot.name}' at {path}{hint}")
    return path


class SeedPolicy:
    """The shipped seed policy of the robot (`robots/<name>/policy.npz`), or a given actor."""

    name = "rl"

    def __init__(self, robot: Robot, actor: MlpActor | None = None, path: Path | None = None,
                 start: float = 0.0, delay: float = 0.0, delay_from: float = 0.0) -> None:
        self.actor = actor or MlpActor.load(path or seed_policy_path(robot))
        self.start, self._zeros = start, np.zeros(robot.num_joints)
        self.clock = RealtimeClock(delay) if delay > 0 else None
        self.delay_from, self._last = delay_from, self._zeros
    @classmethod
    def from_cell(cls, cell: CellSpec, robot: Robot, resources: Resources) -> SeedPolicy:
        s = cell.settings
        return cls(robot, path=seed_policy_path(robot, s), start=s.seed_start, delay=s.action_delay,
                   delay_from=s.llm_after)

    def reset(self, seed: int) -> None:
        self._last = self._zeros

    def act(self, obs: np.ndarray, state: RobotState) -> np.ndarray:
        if state.time < self.start - 1e-9:
            return self._zeros
        if self.clock is None or state.time < self.delay_from - 1e-9:
            self._last = self.actor(obs)
            return self._last
        if not self.clock.latencies:
            self.clock.reset(self._last)  # until the first delayed action arrives, the last one is held
        return self.clock.step(state.time, lambda: (self.actor(obs), 0.0))

    def metrics(self) -> dict:
        return {} if self.clock is None else {"clock": "realtime", **self.clock.metrics()}

    def close(self) -> None:
        pass
