"""Left/right mirror symmetry: the maps, the physics they describe, and training's mirrored rollouts."""

from __future__ import annotations

import numpy as np
import pytest

import sims.mujoco
from benchmark.trial.control import FIXED_COMMAND, ControlLoop
from benchmark.training.envs import LocomotionEnv, Randomization
from benchmark.trial.symmetry import mirror_joints, mirror_rl_observation
from robots import available_robots, load_robot
from sims import make_sim
from sims.terrain import Terrain


@pytest.mark.parametrize("robot_name", available_robots())
def test_default_pose_is_mirror_symmetric_and_mirroring_twice_is_identity(robot_name):
    robot = load_robot(robot_name)
    np.testing.assert_allclose(mirror_joints(robot.default_pose), robot.default_pose)
    obs = np.random.default_rng(0).normal(size=(5, 48))
    np.testing.assert_array_equal(mirror_rl_observation(mirror_rl_observation(obs)), obs)


@pytest.mark.parametrize("robot_name", available_robots())
def test_a_mirrored_action_moves_the_robot_as_its_mirror_image(robot_name, monkeypatch):
    """From the symmetric default pose, one control step of action a and one of mirror(a) end in
    mirrored observations: the maps match the engine's joint signs and base frame."""
    monkeypatch.setattr(sims.mujoco, "initial_joint_pos", lambda robot, seed, spread=0.0: robot.default_pose.copy())
    robot, terrain = load_robot(robot_name), Terrain("flat")
    action = np.random.default_rng(1).normal(0.0, 0.5, robot.num_joints)
    observed = []
    for a in (action, mirror_joints(action)):
        sim = make_sim("mujoco", robot, terrain)
        loop = ControlLoop(sim, robot, terrain, heading=FIXED_COMMAND)
        loop.reset(0)
        observed.append(loop.step(a))
        sim.close()
    error = np.abs(mirror_rl_observation(observed[0]) - observed[1]).max()
    unflipped = np.abs(observed[0] - observed[1]).max()  # no mirror at all: the legs moved differently
    assert error < 0.02 < unflipped, (error, unflipped)  # A1's official model is not exactly symmetric


def test_mirrored_rollout_adds_the_mirror_image_of_every_transition():
    from stable_baselines3 import PPO

    from benchmark.training.train import mirrored_rollout

    env = LocomotionEnv("a1", "mujoco", "flat")
    model = PPO("MlpPolicy", env, n_steps=16, batch_size=16, seed=0, device="cpu")
    model.learn(16)  # one rollout, one update
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, n_rollout_steps=16)
    buffer = model.rollout_buffer
    both = mirrored_rollout(buffer, model.policy)
    assert both.n_envs == 2 * buffer.n_envs and both.full
    np.testing.assert_array_equal(both.observations[:, :1], buffer.observations)
    np.testing.assert_allclose(both.observations[:, 1:], mirror_rl_observation(buffer.observations), rtol=1e-6)
    np.testing.assert_allclose(both.actions[:, 1:], mirror_joints(buffer.actions), rtol=1e-6)
    np.testing.assert_array_equal(both.advantages[:, 1:], buffer.advantages)
    np.testing.assert_array_equal(both.log_probs[:, :1], buffer.log_probs)
    assert not np.allclose(both.log_probs[:, 1:], buffer.log_probs)  # recomputed for the mirrored pairs
    env.close()


def test_straight_episodes_keep_the_papers_fixed_command():
    """Also right after an episode whose heading hold steered: its yaw-rate command must not carry over."""
    env = LocomotionEnv("a1", "mujoco", "flat", randomization=Randomization(straight_share=0.0, push_interval_s=100))
    env.reset(seed=3)
    for _ in range(10):
        env.step(np.zeros(12))
    assert env.loop.command[2] != 0.0  # the hold steers toward its random heading
    env.randomization = Randomization(straight_share=1.0, push_interval_s=100)
    env.reset(seed=4)
    for _ in range(20):
        env.step(np.zeros(12))
        np.testing.assert_array_equal(env.loop.command, env.robot.command)
    env.close()


def test_symmetric_inference_is_exactly_mirror_equivariant(tmp_path):
    import dataclasses

    from benchmark.trial.mlp import MlpActor

    actor = MlpActor.load(load_robot("a1").folder / "policy.npz")
    symmetric = dataclasses.replace(actor, meta={**actor.meta, "symmetric": True})
    symmetric.save(tmp_path / "policy.npz")
    loaded = MlpActor.load(tmp_path / "policy.npz")
    obs = np.random.default_rng(2).normal(size=(4, 48))
    for x in obs:
        np.testing.assert_array_equal(loaded(mirror_rl_observation(x)), mirror_joints(loaded(x)))
    if not actor.symmetric:  # a plain actor has a bias the symmetric one removes
        assert max(np.abs(actor(mirror_rl_observation(x)) - mirror_joints(actor(x))).max() for x in obs) > 1e-3


def test_the_mirror_loss_makes_an_asymmetric_actor_equivariant():
    """`mirror_loss_step` pulls mu(s) and M mu(M s) together: a random actor's asymmetry falls by most of it."""
    import gymnasium as gym
    import torch
    from stable_baselines3.common.policies import ActorCriticPolicy

    from benchmark.training.train import mirror_loss_step

    torch.manual_seed(0)
    policy = ActorCriticPolicy(gym.spaces.Box(-10, 10, (48,)), gym.spaces.Box(-4, 4, (12,)), lambda _: 1e-3)
    with torch.no_grad():  # a strongly asymmetric start
        policy.action_net.bias.copy_(torch.linspace(-1.0, 1.0, 12))
    observations = np.random.default_rng(1).normal(size=(512, 48)).astype(np.float32)
    before = mirror_loss_step(policy, observations, weight=1.0, batch_size=128, epochs=20)
    after = mirror_loss_step(policy, observations, weight=1.0, batch_size=128, epochs=0)  # measures only
    assert before > 0.3 and after < 0.2 * before, (before, after)
    assert mirror_loss_step(policy, observations, weight=1.0, batch_size=128, epochs=0) == after  # epochs=0 leaves it


def test_a_symmetric_actor_trains_equivariant_and_ships_as_it_trained(tmp_path):
    """`--symmetric-actor`: PPO's Gaussian mean is (mu(s) + M mu(M s)) / 2 at every update, and the exported
    actor (run with symmetric inference) answers exactly what the trained policy's mean answered."""
    import torch

    from benchmark.trial.mlp import MlpActor
    from benchmark.training.train import TrainConfig, symmetric_actor_policy, train

    path = train(TrainConfig(robot="a1", steps=2048, seed=0, out=str(tmp_path), eval_every=10**9, mirror=False,
                             symmetric_actor=True))
    actor = MlpActor.load(path)
    assert actor.symmetric and actor.meta["symmetric_actor"]
    obs = np.random.default_rng(3).normal(size=(4, 48))
    for x in obs:
        np.testing.assert_allclose(actor(mirror_rl_observation(x)), mirror_joints(actor(x)), atol=1e-12)
    # the policy PPO trained, reloaded: its mean is the exported actor's answer
    from stable_baselines3 import PPO

    model = PPO.load(tmp_path / "ppo_model.zip", custom_objects={"policy_class": symmetric_actor_policy()},
                     device="cpu")
    with torch.no_grad():
        mean = model.policy.get_distribution(torch.as_tensor(obs, dtype=torch.float32)).distribution.mean.numpy()
    np.testing.assert_allclose(mean, np.stack([actor(x) for x in obs]), atol=1e-5)
