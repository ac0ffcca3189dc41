"""Policies map an observation to 12 normalized actions (targets = default + scale * action).

Registered by name; later policies (rl, llm) add themselves to POLICIES.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from benchmark.mlp import MlpActor
from robots import Robot, UnknownNameError
from sims.base import RobotState


class Policy(Protocol):
    name: str

    def reset(self, seed: int) -> None: ...

    def act(self, obs: np.ndarray, state: RobotState) -> np.ndarray:
        """Normalized actions (12,) for the 48-dim observation `obs` of `state`."""

    def metrics(self) -> dict:
        """Policy-specific figures for the trial just run (tokens, latency ...); may be empty."""


class StandPolicy:
    """Holds the default pose: the baseline every other policy must beat."""

    name = "stand"

    def __init__(self, robot: Robot) -> None:
        self._zeros = np.zeros(robot.num_joints)

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: np.ndarray, state: RobotState) -> np.ndarray:
        return self._zeros

    def metrics(self) -> dict:
        return {}


class RLPolicy:
    """The shipped seed policy of the robot (`robots/<name>/policy.npz`), or a given actor."""

    name = "rl"

    def __init__(self, robot: Robot, actor: MlpActor | None = None, path: Path | None = None) -> None:
        if actor is None:
            path = path or robot.urdf.parent / "policy.npz"
            if not path.is_file():
                raise ValueError(f"no seed policy for robot '{robot.name}' at {path}; train one with "
                                 f"'bench train --robot {robot.name} --ship'")
            actor = MlpActor.load(path)
        self.actor = actor

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: np.ndarray, state: RobotState) -> np.ndarray:
        return self.actor(obs)

    def metrics(self) -> dict:
        return {}


def _llm_policy(robot: Robot, **options) -> Policy:
    from benchmark.llm.policy import LLMPolicy

    return LLMPolicy(robot, **options)


POLICIES: dict[str, Callable[..., Policy]] = {"stand": StandPolicy, "rl": RLPolicy, "llm": _llm_policy}


def available_policies() -> list[str]:
    return sorted(POLICIES)


def make_policy(name: str, robot: Robot, **options) -> Policy:
    if name not in POLICIES:
        raise UnknownNameError("policy", name, available_policies())
    return POLICIES[name](robot, **options)
