"""What a policy is: the Protocol every controller implements, and the one way to build one for a cell."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from benchmark.trial.cell import CellSpec
from benchmark.trial.registry import policy_entry
from benchmark.trial.resources import Resources
from robots import Robot
from sims import load_entry_point
from sims.base import RobotState


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


def build_policy(cell: CellSpec, robot: Robot, resources: Resources) -> Policy:
    return load_entry_point(policy_entry(cell.policy).entry_point).from_cell(cell, robot, resources)
