"""Observations of the paper's protocol, built from a `RobotState` in the base frame.

RL (48): base linear velocity, base angular velocity, projected gravity, command,
joint positions relative to the default pose, joint velocities, last action; each scaled
by the robot's observation scales. LLM (33): the same without command and last action.
"""

from __future__ import annotations

import numpy as np

from robots import Robot
from sims.base import RobotState

RL_OBS_DIM = 48
LLM_OBS_DIM = 33


def command_scales(robot: Robot) -> np.ndarray:
    s = robot.obs_scales
    return np.array([s.lin_vel, s.lin_vel, s.ang_vel])


def rl_observation(state: RobotState, robot: Robot, command: np.ndarray, last_action: np.ndarray) -> np.ndarray:
    s = robot.obs_scales
    return np.concatenate([
        state.base_lin_vel * s.lin_vel,
        state.base_ang_vel * s.ang_vel,
        state.projected_gravity,
        command * command_scales(robot),
        (state.joint_pos - robot.default_pose) * s.joint_pos,
        state.joint_vel * s.joint_vel,
        last_action,
    ])


def llm_observation(rl_obs: np.ndarray) -> np.ndarray:
    """The LLM's 33 values: the RL observation without command (9:12) and last action (36:48)."""
    return np.concatenate([rl_obs[:9], rl_obs[12:36]])
