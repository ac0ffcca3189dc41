"""The one 10 Hz control loop: observation -> action -> joint targets -> `sim.step`.

The benchmark runner and the Gymnasium training environment both step the simulator
through this class, so a policy sees the same observations, gains and timing in training
and in evaluation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchmark.trial.falls import fall_reason
from benchmark.trial.observation import rl_observation
from robots import Robot
from sims.base import RobotState, Simulator
from sims.terrain import Terrain


@dataclass(frozen=True)
class HeadingHold:
    """Heading hold and line following through the command's yaw rate.

    Bumps on rough ground knock the heading off by up to 0.5 rad; at legged_gym's gain of 0.5
    the robot walked on askew for seconds. These gains halved the sideways drift of both
    shipped policies in MuJoCo (60 seeds per cell: ANYmal on rough ground 0.77 -> 0.37 m, A1
    0.96 -> 0.38 m) and did not lower success on rough ground.
    """

    gain: float = 1.5  # yaw-rate command (rad/s) per radian of heading error; 0 turns the hold off
    max_yaw_rate: float = 1.0  # rad/s
    follow_line: bool = True  # aim the heading back at the starting line (off in training: random headings)
    line_gain: float = 1.0  # rad of heading toward the line per metre of sideways offset
    max_line_heading: float = 0.4  # rad


FIXED_COMMAND = HeadingHold(gain=0.0, follow_line=False)  # the paper's protocol: the command never changes


def yaw_of(quat_wxyz: np.ndarray) -> float:
    w, x, y, z = quat_wxyz
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class ControlLoop:
    """Holds the latest state, observation and action of one robot in one simulator.

    Heading hold: the observation's yaw-rate command steers the robot back to
    `target_heading` (the observation carries no heading, so without it a policy's small
    turning bias accumulates into metres of sideways drift). With `heading.follow_line`, the target
    heading points back to the straight line the robot started on (x axis through the start),
    so a sideways bias is steered out too. Training uses random fixed headings instead. The
    LLM never sees commands.
    """

    def __init__(self, sim: Simulator, robot: Robot, terrain: Terrain, command: np.ndarray | None = None,
                 heading: HeadingHold = HeadingHold()) -> None:
        self.sim, self.robot, self.terrain = sim, robot, terrain
        self.base_command = robot.command if command is None else np.asarray(command, dtype=float)
        self.command = self.base_command.copy()
        self.heading = heading
        self.target_heading = 0.0
        self.line_y = 0.0
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

    @property
    def heading_error(self) -> float:
        """Target heading minus current heading, wrapped to [-pi, pi)."""
        error = self.target_heading - yaw_of(self.state.base_quat)
        return (error + math.pi) % (2 * math.pi) - math.pi

    def _update_command(self) -> None:
        h = self.heading
        if h.follow_line:
            offset = float(self.state.base_pos[1]) - self.line_y
            self.target_heading = float(np.clip(-h.line_gain * offset, -h.max_line_heading, h.max_line_heading))
        if h.gain:
            self.command = self.base_command.copy()
            self.command[2] = float(np.clip(h.gain * self.heading_error, -h.max_yaw_rate, h.max_yaw_rate))

    def reset(self, seed: int, target_heading: float = 0.0) -> np.ndarray:
        self.steps = 0
        self.command = self.base_command.copy()  # a held heading's yaw rate must not outlive its episode
        self.target_heading = target_heading
        self.action = np.zeros(self.robot.num_joints)
        self.targets = self.robot.default_pose.copy()
        self.state = self.sim.reset(seed)
        self.line_y = float(self.state.base_pos[1])
        self.fall = None
        self._update_command()
        self.obs = rl_observation(self.state, self.robot, self.command, self.action)
        return self.obs

    def step(self, action: np.ndarray) -> np.ndarray:
        """Apply normalized `action` for one control period; returns the next observation."""
        self.action = np.asarray(action, dtype=float)
        self.targets = self.robot.targets_from_actions(self.action)
        self.state = self.sim.step(self.targets)
        self.steps += 1
        self.fall = fall_reason(self.state, self.robot, self.terrain)
        self._update_command()
        self.obs = rl_observation(self.state, self.robot, self.command, self.action)
        return self.obs
