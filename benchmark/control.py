"""The one 10 Hz control loop: observation -> action -> joint targets -> `sim.step`.

The benchmark runner and the Gymnasium training environment both step the simulator
through this class, so a policy sees the same observations, gains and timing in training
and in evaluation.
"""

from __future__ import annotations

import numpy as np

from benchmark.falls import fall_reason
from benchmark.observation import rl_observation
from robots import Robot
from sims.base import RobotState, Simulator
from sims.terrain import Terrain


class ControlLoop:
    """Holds the latest state, observation and action of one robot in one simulator."""

    def __init__(self, sim: Simulator, robot: Robot, terrain: Terrain, command: np.ndarray | None = None) -> None:
        self.sim, self.robot, self.terrain = sim, robot, terrain
        self.command = robot.command if command is None else np.asarray(command, dtype=float)
        self.dt = sim.physics.control_dt
        self.steps = 0
        self.action = np.zeros(robot.num_joints)
        self.targets = robot.default_pose.copy()
        self.state: RobotState | None = None
        self.obs = np.zeros(0)
        self.fall: str | None = None

    @property
    def time(self) -> float:
        return self.steps * self.dt

    def reset(self, seed: int) -> np.ndarray:
        self.steps = 0
        self.action = np.zeros(self.robot.num_joints)
        self.targets = self.robot.default_pose.copy()
        self.state = self.sim.reset(seed)
        self.fall = None
        self.obs = rl_observation(self.state, self.robot, self.command, self.action)
        return self.obs

    def step(self, action: np.ndarray) -> np.ndarray:
        """Apply normalized `action` for one control period; returns the next observation."""
        self.action = np.asarray(action, dtype=float)
        self.targets = self.robot.targets_from_actions(self.action)
        self.state = self.sim.step(self.targets)
        self.steps += 1
        self.fall = fall_reason(self.state, self.robot, self.terrain)
        self.obs = rl_observation(self.state, self.robot, self.command, self.action)
        return self.obs
