"""The walking reward used to train the seed policies (how it was tuned: README, "Seed policies").

A linear forward term saturating at the command makes the robot walk (exponential tracking
alone gets stuck standing); feet air time rewards stepping over shuffling; heading and
lateral terms stop sideways drift; posture terms (as in legged_gym's hip and default-pose
penalties) keep the gait near the default stance, so the seed policy's examples in an LLM's prompt
show a natural, left-right symmetric trot; the total is clipped at zero so that ending an episode
early by falling is never better than staying up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robots import Robot
from sims.base import RobotState


@dataclass(frozen=True)
class RewardWeights:
    forward: float = 3.0  # x clip(vx / command_vx, -1, 1)
    tracking: float = 1.0  # x exp(-(vx - command_vx)^2 / 0.25)
    lateral: float = -1.0  # x vy^2
    yaw_rate: float = -0.5  # x (wz - command_wz)^2
    heading: float = -1.0  # x |target heading - heading|
    vertical: float = -2.0  # x vz^2
    roll_pitch_rate: float = -0.05  # x (wx^2 + wy^2)
    orientation: float = -2.0  # x (gx^2 + gy^2)
    torque: float = -0.2  # x mean((tau / limit)^2)
    action_rate: float = -0.02  # x mean((a - a_prev)^2)
    air_time: float = 1.0  # x sum over touchdowns of (air time - air_time_target)
    air_time_target: float = 0.2  # s: two control periods off the ground
    height: float = 0.0  # x max(0, height_floor - base height over the terrain): against crouching
    height_floor: float = 0.0  # m
    hip_posture: float = -2.0  # x sum over hip abduction joints of (q - default)^2: no splayed legs
    posture: float = -0.2  # x sum over all joints of (q - default)^2: stay near the default stance
    diagonal_gait: float = 0.5  # x (diagonal foot pairs agreeing - lateral pairs agreeing) / 2: a trot, not a bound
    turning: float = 0.0  # x |heading change over the last `turning_window_s` / window - command wz|: the true
    #                       turning rate, which the 10 Hz sample of wz aliases (see TurningRate)
    turning_window_s: float = 1.0  # s: a few gait cycles, so the gait's own yaw wobble averages out


class FeetAirTime:
    """Seconds each foot has been in the air; reports the total air time of feet landing now."""

    def __init__(self, num_feet: int = 4) -> None:
        self.air = np.zeros(num_feet)
        self.was_touching = np.ones(num_feet, dtype=bool)

    def reset(self) -> None:
        self.air[:] = 0.0
        self.was_touching[:] = True

    def update(self, touching: np.ndarray, dt: float, target: float) -> float:
        landing = touching & ~self.was_touching
        self.air += dt
        reward = float(np.sum((self.air - target) * landing))
        self.air[touching] = 0.0
        self.was_touching = touching.copy()
        return reward


class TurningRate:
    """The base's mean yaw rate over the last `window` control steps, from its heading, not from wz.

    At 10 Hz a trot is phase-locked to the control period, so the sampled body-frame wz sees the same
    gait phases every cycle and its mean is not the robot's turning rate. MuJoCo, flat, fixed command, 3-20 s:
    the earlier A1 policy's sampled wz averaged +0.046 rad/s while its heading changed at -0.009 rad/s; a
    fine-tune with a squared wz penalty of 2 drove its samples to +0.075 rad/s and its heading to -0.023 rad/s.
    A penalty on that sample cannot hold a heading; this term measures the turn itself."""

    def __init__(self, window: int) -> None:
        self.window = max(1, int(window))
        self.yaws: list[float] = []

    def reset(self, yaw: float) -> None:
        self.yaws = [yaw]

    def update(self, yaw: float, dt: float) -> float:
        """Record the newest heading (rad); returns the mean yaw rate (rad/s) over the window so far."""
        step = (yaw - self.yaws[-1] + math.pi) % (2 * math.pi) - math.pi  # unwrap across +-pi
        self.yaws.append(self.yaws[-1] + step)
        del self.yaws[:-self.window - 1]
        return (self.yaws[-1] - self.yaws[0]) / (dt * (len(self.yaws) - 1))


def walking_reward(state: RobotState, robot: Robot, command: np.ndarray, action: np.ndarray,
                   last_action: np.ndarray, air_time_reward: float, w: RewardWeights,
                   heading_error: float = 0.0, base_height: float = math.inf, turning_rate: float = 0.0) -> float:
    vx, vy, vz = state.base_lin_vel
    wx, wy, wz = state.base_ang_vel
    gx, gy, _ = state.projected_gravity
    offset_sq = (state.joint_pos - robot.default_pose) ** 2
    fr, fl, rr, rl = (bool(c) for c in state.foot_contact)  # canonical leg order
    trot = ((fr == rl) + (fl == rr) - (fr == fl) - (rr == rl)) / 2
    cmd_vx = max(float(command[0]), 1e-3)
    total = (
        w.forward * float(np.clip(vx / cmd_vx, -1.0, 1.0))
        + w.tracking * math.exp(-((vx - command[0]) ** 2) / 0.25)
        + w.lateral * vy**2
        + w.yaw_rate * (wz - command[2]) ** 2
        + w.heading * abs(heading_error)
        + w.vertical * vz**2
        + w.roll_pitch_rate * (wx**2 + wy**2)
        + w.orientation * (gx**2 + gy**2)
        + w.torque * float(np.mean((state.joint_torque / robot.torque_limit) ** 2))
        + w.action_rate * float(np.mean((action - last_action) ** 2))
        + w.air_time * air_time_reward
        + w.height * max(0.0, w.height_floor - base_height)
        + w.hip_posture * float(offset_sq[0::3].sum())
        + w.posture * float(offset_sq.sum())
        + w.diagonal_gait * trot
        + w.turning * abs(turning_rate - command[2])
    )
    return max(total, 0.0)
