"""Gymnasium environments over `sims/`, for training the seed policies.

Registered as `promptwalk/<Robot>-<Terrain>-<Engine>-v0`, e.g. `promptwalk/A1-Flat-MuJoCo-v0`:

    import gymnasium as gym, benchmark.training.envs
    env = gym.make("promptwalk/A1-Rough-MuJoCo-v0")

Actions are the 12 normalized joint offsets (target = default + action_scale * action) at
10 Hz; observations the 48-dim RL observation. Episodes end on a fall (terminated) or after
`episode_s` (truncated). Domain randomization (friction, base mass, motor strength, pushes,
observation noise) is what lets a policy trained in one engine walk in the others.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from benchmark.trial.control import FIXED_COMMAND, ControlLoop, HeadingHold, yaw_of
from benchmark.trial.observation import RL_OBS_DIM
from benchmark.training.rewards import FeetAirTime, RewardWeights, TurningRate, walking_reward
from robots import available_robots, load_robot
from sims import ENGINES, make_sim
from sims.base import Dynamics
from sims.terrain import TERRAINS, Terrain

ACTION_LIMIT = 5.0  # normalized units; the paper's encodings cover [-5, 5]


@dataclass(frozen=True)
class Randomization:
    """Ranges sampled uniformly at every reset; `None` in the env means nominal physics."""

    friction: tuple[float, float] = (0.5, 1.25)
    base_mass_scale: tuple[float, float] = (0.9, 1.2)
    motor_strength: tuple[float, float] = (0.9, 1.1)
    push_interval_s: float = 5.0
    push_velocity: float = 0.5  # m/s, max horizontal shove per axis
    obs_noise: float = 1.0  # factor on the per-quantity noise amplitudes below
    heading: float = 0.5  # rad: target headings are drawn from [-heading, heading], so the policy
    #                       learns to follow the yaw-rate command that holds a heading
    straight_share: float = 0.5  # of episodes under the paper's fixed command (no heading hold): yaw rate
    #                              tracked at 0, the start heading held without being observed


def observation_noise_amplitudes(scales) -> np.ndarray:
    """Uniform noise amplitudes per observation entry (legged_gym's figures, scaled)."""
    return np.concatenate([
        np.full(3, 0.1 * scales.lin_vel), np.full(3, 0.2 * scales.ang_vel), np.full(3, 0.05), np.zeros(3),
        np.full(12, 0.01 * scales.joint_pos), np.full(12, 1.5 * scales.joint_vel), np.zeros(12),
    ])


class LocomotionEnv(gym.Env):
    """One robot walking at its command velocity in one engine on one terrain."""

    metadata = {"render_modes": []}

    def __init__(self, robot: str = "a1", sim: str = "mujoco", terrain: str = "flat", terrain_seed: int = 0,
                 episode_s: float = 20.0, randomization: Randomization | None = Randomization(),
                 rewards: RewardWeights = RewardWeights()) -> None:
        self.robot = load_robot(robot)
        self.terrain = Terrain(terrain, seed=terrain_seed)
        self.sim = make_sim(sim, self.robot, self.terrain)
        self._hold = HeadingHold(follow_line=randomization is None)
        self.loop = ControlLoop(self.sim, self.robot, self.terrain, heading=self._hold)
        self.randomization, self.rewards = randomization, rewards
        self.max_steps = int(round(episode_s / self.loop.dt))
        self.action_space = gym.spaces.Box(-ACTION_LIMIT, ACTION_LIMIT, (self.robot.num_joints,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (RL_OBS_DIM,), np.float32)
        self._noise = observation_noise_amplitudes(self.robot.obs_scales)
        self._air = FeetAirTime(len(self.robot.foot_links))
        self._turning = TurningRate(round(rewards.turning_window_s / self.loop.dt))
        self._push_every = int(round(randomization.push_interval_s / self.loop.dt)) if randomization else 0

    def _observe(self) -> np.ndarray:
        obs = self.loop.obs
        if self.randomization is not None and self.randomization.obs_noise > 0:
            obs = obs + self.np_random.uniform(-1.0, 1.0, obs.shape) * self._noise * self.randomization.obs_noise
        return obs.astype(np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        r = self.randomization
        if r is not None:
            u = self.np_random.uniform
            self.sim.set_dynamics(Dynamics(friction=u(*r.friction), base_mass_scale=u(*r.base_mass_scale),
                                           motor_strength=u(*r.motor_strength)))
        straight = r is not None and self.np_random.uniform() < r.straight_share
        self.loop.heading = FIXED_COMMAND if straight else self._hold
        target = self.np_random.uniform(-r.heading, r.heading) if r is not None and not straight else 0.0
        self.loop.reset(int(self.np_random.integers(2**31)), target_heading=target)
        self._air.reset()
        self._turning.reset(yaw_of(self.loop.state.base_quat))
        return self._observe(), {}

    def step(self, action: np.ndarray):
        loop = self.loop
        last_action = loop.action
        loop.step(np.clip(action, -ACTION_LIMIT, ACTION_LIMIT))
        if self._push_every and loop.steps % self._push_every == 0:
            self.sim.push_base(self.np_random.uniform(-1.0, 1.0, 2) * self.randomization.push_velocity)
        air = self._air.update(loop.state.foot_contact, loop.dt, self.rewards.air_time_target)
        turning = self._turning.update(yaw_of(loop.state.base_quat), loop.dt)
        x, y, z = loop.state.base_pos
        reward = walking_reward(loop.state, self.robot, loop.command, loop.action, last_action, air, self.rewards,
                                loop.heading_error, base_height=float(z) - self.terrain.height_at(x, y),
                                turning_rate=turning)
        terminated = loop.fall is not None
        truncated = loop.steps >= self.max_steps
        info = {"fall": loop.fall} if terminated else {}
        obs = self._observe()
        if not np.isfinite(obs).all() or not np.isfinite(reward):  # a blown-up engine step must not reach PPO
            obs, reward, terminated = np.zeros_like(obs), 0.0, True
        return obs, (0.0 if terminated else reward), terminated, truncated, info

    def close(self) -> None:
        self.sim.close()


def env_id(robot: str, terrain: str, sim: str) -> str:
    return f"promptwalk/{robot.capitalize()}-{terrain.capitalize()}-{ENGINES[sim].title}-v0"


def register_all() -> list[str]:
    ids = []
    for robot in available_robots():
        for terrain in TERRAINS:
            for sim in ENGINES:
                ids.append(env_id(robot, terrain, sim))
                if ids[-1] not in gym.registry:
                    gym.register(ids[-1], entry_point=LocomotionEnv,
                                 kwargs={"robot": robot, "sim": sim, "terrain": terrain})
    return ids


register_all()
