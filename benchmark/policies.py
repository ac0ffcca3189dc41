"""Policies map an observation to 12 normalized actions (targets = default + scale * action).

Registered like Gymnasium environments, by entry point, and loaded lazily: a new policy is one
module plus one line in POLICIES. A policy with settings names their dataclass; its fields
become `bench run` options and experiment keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from benchmark.mlp import MlpActor
from benchmark.settings import setting
from robots import Robot, UnknownNameError
from sims import load_entry_point
from sims.base import RobotState

if TYPE_CHECKING:
    from benchmark.cell import CellSpec, Resources


class Policy(Protocol):
    name: str

    @classmethod
    def from_cell(cls, cell: CellSpec, robot: Robot, resources: Resources) -> Policy:
        """The policy a cell describes; shared things (models) come from `resources`."""

    def reset(self, seed: int) -> None: ...

    def act(self, obs: np.ndarray, state: RobotState) -> np.ndarray:
        """Normalized actions (12,) for the 48-dim observation `obs` of `state`."""

    def metrics(self) -> dict:
        """Policy-specific figures for the trial just run (tokens, latency ...); may be empty."""

    def close(self) -> None:
        """Release what the policy owns (not what `resources` lent it)."""


@dataclass(frozen=True)
class PolicyEntry:
    name: str
    entry_point: str  # "module:Class" implementing Policy
    help: str
    settings: str | None = None  # "module:Dataclass" of its settings, if any
    duration: float = 10.0  # s, the default episode of a cell with this policy

    def settings_class(self) -> type | None:
        return load_entry_point(self.settings) if self.settings else None


POLICIES: dict[str, PolicyEntry] = {e.name: e for e in (
    PolicyEntry("llm", "benchmark.llm.controller:LLMPolicy",
                "the paper's protocol: seed policy fills the prompt history, then the LLM drives",
                settings="benchmark.llm.controller:LLMSettings", duration=20.0),
    PolicyEntry("stand", "benchmark.policies:StandPolicy", "holds the default pose; cannot walk"),
    PolicyEntry("rl", "benchmark.policies:SeedPolicy", "the robot's shipped PPO seed policy (or --policy-file)",
                settings="benchmark.policies:SeedSettings"),
)}


def available_policies() -> list[str]:
    return sorted(POLICIES)


def policy_entry(name: str) -> PolicyEntry:
    if name not in POLICIES:
        raise UnknownNameError("policy", name, available_policies())
    return POLICIES[name]


def build_policy(cell: CellSpec, robot: Robot, resources: Resources) -> Policy:
    return load_entry_point(policy_entry(cell.policy).entry_point).from_cell(cell, robot, resources)


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
                                       "(benchmark.clock): each action applies this long after the observation it "
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
        from benchmark.clock import RealtimeClock

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
