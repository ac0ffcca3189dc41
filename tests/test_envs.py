"""The Gymnasium environment and PPO training (a smoke run; real training never runs in CI)."""

from __future__ import annotations

import csv

import gymnasium as gym
import numpy as np
import pytest

import benchmark.training.envs  # noqa: F401  (registers the environments)
from benchmark.trial.control import ControlLoop
from benchmark.training.envs import LocomotionEnv, Randomization
from benchmark.trial.mlp import MlpActor
from benchmark.training.rewards import FeetAirTime, RewardWeights, TurningRate, walking_reward
from robots import load_robot


def test_environments_are_registered_for_every_cell():
    for env_id in ("promptwalk/A1-Flat-MuJoCo-v0", "promptwalk/Anymal-Rough-PyBullet-v0",
                   "promptwalk/A1-Rough-Newton-v0"):
        assert env_id in gym.registry


def test_env_follows_the_gymnasium_api():
    from gymnasium.utils.env_checker import check_env

    env = gym.make("promptwalk/A1-Rough-MuJoCo-v0").unwrapped
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=1)
    assert obs.shape == (48,) and obs.dtype == np.float32
    env.close()


def test_env_steps_the_same_control_loop_as_the_runner():
    """Without randomization the env's observation is the runner's, step for step."""
    env = LocomotionEnv("a1", "mujoco", "flat", randomization=None)
    env.reset(seed=3)
    seed = int(np.random.default_rng(3).integers(2**31))  # the env draws the trial seed from its rng
    twin = LocomotionEnv("a1", "mujoco", "flat", randomization=None)
    loop = ControlLoop(twin.sim, twin.robot, twin.terrain)
    loop.reset(seed)
    rng = np.random.default_rng(0)
    for _ in range(5):
        action = rng.uniform(-1, 1, 12)
        obs, reward, terminated, truncated, _ = env.step(action)
        np.testing.assert_allclose(obs, loop.step(action).astype(np.float32), atol=1e-5)
        assert reward >= 0.0 and not terminated and not truncated


def test_falling_terminates_and_randomization_changes_the_physics():
    env = LocomotionEnv("a1", "mujoco", "flat", randomization=Randomization(friction=(0.3, 0.3)))
    env.reset(seed=0)
    assert env.sim.model.geom_friction[0, 0] == pytest.approx(0.3)
    for _ in range(60):  # fold every joint hard: the trunk hits the ground
        _, reward, terminated, _, info = env.step(np.full(12, 5.0))
        if terminated:
            break
    assert terminated and reward == 0.0 and info["fall"]


def test_reward_favours_walking_forward_and_is_never_negative():
    robot = load_robot("a1")
    env = LocomotionEnv("a1", "mujoco", "flat", randomization=None)
    env.reset(seed=0)
    state = env.loop.state
    zeros = np.zeros(12)
    walking = state._replace(base_lin_vel=np.array([1.0, 0.0, 0.0]))
    backwards = state._replace(base_lin_vel=np.array([-1.0, 0.0, 0.0]))
    w = RewardWeights()
    r_walk = walking_reward(walking, robot, robot.command, zeros, zeros, 0.0, w)
    r_stand = walking_reward(state, robot, robot.command, zeros, zeros, 0.0, w)
    assert r_walk > r_stand + 2.0
    assert walking_reward(backwards, robot, robot.command, zeros, zeros, 0.0, w) == 0.0


def test_feet_air_time_rewards_long_steps():
    air = FeetAirTime()
    up, down = np.array([False, True, True, True]), np.ones(4, bool)
    assert air.update(up, 0.1, 0.2) == 0.0
    air.update(up, 0.1, 0.2)
    assert air.update(up, 0.1, 0.2) == 0.0
    assert air.update(down, 0.1, 0.2) == pytest.approx(0.4 - 0.2)


def test_turning_rate_is_the_heading_change_over_its_window_across_the_wrap():
    rate = TurningRate(window=10)
    rate.reset(3.1)
    yaws = [3.1 + 0.01 * k for k in range(1, 21)]  # turning left at 0.1 rad/s, through +pi to -pi
    rates = [rate.update((y + np.pi) % (2 * np.pi) - np.pi, 0.1) for y in yaws]
    np.testing.assert_allclose(rates, 0.1, atol=1e-9)
    # a wobble that returns to its heading within the window is no turn at all
    rate.reset(0.0)
    wobble = [rate.update(0.05 * np.sin(np.pi * k / 2), 0.1) for k in range(1, 41)]
    assert abs(wobble[-1]) < 1e-9 and max(map(abs, wobble)) <= 0.5 + 1e-9


def test_the_turning_term_penalizes_turning_against_the_command():
    robot = load_robot("a1")
    env = LocomotionEnv("a1", randomization=None, rewards=RewardWeights(turning=-2.0))
    env.reset(seed=0)
    zeros = np.zeros(12)
    state = env.loop.state._replace(base_lin_vel=np.array([1.0, 0.0, 0.0]))  # walking: above the clip
    w = RewardWeights(turning=-2.0)
    straight = walking_reward(state, robot, robot.command, zeros, zeros, 0.0, w, turning_rate=0.0)
    turning = walking_reward(state, robot, robot.command, zeros, zeros, 0.0, w, turning_rate=0.3)
    assert straight - turning == pytest.approx(0.6)
    env.close()


def test_smoke_training_writes_a_loadable_policy_and_log(tmp_path):
    from benchmark.training.train import TrainConfig, train

    path = train(TrainConfig(robot="a1", sim=("mujoco",), steps=4096, seed=0, out=str(tmp_path), eval_every=2048))
    actor = MlpActor.load(path)
    assert actor.meta["env_steps"] >= 4096 and actor.meta["trained_in"] == "mujoco"
    action = actor(np.zeros(48))
    assert action.shape == (12,) and np.all(np.abs(action) <= 5.0)
    rows = list(csv.DictReader((tmp_path / "train_log.csv").open()))
    assert [int(r["env_steps"]) for r in rows] == [2048, 4096]


def test_training_is_deterministic_for_a_seed(tmp_path):
    from benchmark.training.train import TrainConfig, train

    config = TrainConfig(robot="a1", steps=2048, seed=7, eval_every=10**9)
    a = MlpActor.load(train(TrainConfig(**{**config.__dict__, "out": str(tmp_path / "a")})))
    b = MlpActor.load(train(TrainConfig(**{**config.__dict__, "out": str(tmp_path / "b")})))
    for wa, wb in zip(a.weights, b.weights):
        np.testing.assert_array_equal(wa, wb)
    # no periodic evaluation fell due: the final policy is still evaluated, and logged
    rows = list(csv.DictReader((tmp_path / "a" / "train_log.csv").open()))
    assert [int(r["env_steps"]) for r in rows] == [2048] and rows[0]["eval_nwt"] != ""
