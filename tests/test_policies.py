"""The shipped seed policies walk; the numpy actor matches the trained torch network."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmark.mlp import MlpActor
from benchmark.policies import RLPolicy
from benchmark.runner import EpisodeConfig, run_trial
from robots import available_robots, load_robot
from sims import make_sim
from sims.terrain import Terrain


@pytest.mark.parametrize("robot_name", available_robots())
def test_shipped_policy_walks_forward_in_mujoco(robot_name):
    robot = load_robot(robot_name)
    policy = RLPolicy(robot)
    sim = make_sim("mujoco", robot, Terrain("flat"))
    try:
        result = run_trial(sim, robot, sim.terrain, policy, EpisodeConfig(duration=5.0), seed=11)
    finally:
        sim.close()
    assert result.success, result.fall_reason
    assert result.mean_vx > 0.5 * robot.command[0] and result.distance_m > 2.0


@pytest.mark.parametrize("robot_name", available_robots())
def test_shipped_policy_documents_how_it_was_made(robot_name):
    robot = load_robot(robot_name)
    meta = json.loads((robot.urdf.parent / "policy.json").read_text())
    assert meta["robot"] == robot_name and "mujoco" in meta["trained_in"].split("+")
    assert meta["command"].startswith("bench train") and "torch" in meta["versions"]
    total, stage = 0, meta  # fine-tuned policies record the run they started from
    while stage:
        total += stage["env_steps"]
        stage = stage.get("init_from")
    assert total >= 500_000
    actor = MlpActor.load(robot.urdf.parent / "policy.npz")
    assert actor.weights[0].shape == (256, 48) and actor.weights[-1].shape == (12, 256 // 2)
    assert (robot.urdf.parent / "policy.npz").stat().st_size < 400_000  # actor only, no optimizer state


def test_numpy_actor_equals_the_torch_network(tmp_path):
    import torch
    import torch.nn as nn

    from benchmark.train import export_actor

    class Stub:  # the attribute path export_actor reads from an SB3 model
        class policy:  # noqa: N801
            mlp_extractor = type("E", (), {"policy_net": nn.Sequential(nn.Linear(48, 16), nn.ELU(),
                                                                        nn.Linear(16, 8), nn.ELU())})()
            action_net = nn.Linear(8, 12)

    actor = export_actor(Stub, {"robot": "a1"})
    actor.save(tmp_path / "p.npz")
    loaded = MlpActor.load(tmp_path / "p.npz")
    obs = np.random.default_rng(0).normal(size=48)
    with torch.no_grad():
        x = torch.tensor(obs, dtype=torch.float32)
        expected = Stub.policy.action_net(Stub.policy.mlp_extractor.policy_net(x)).numpy()
    np.testing.assert_allclose(loaded(obs), np.clip(expected, -5, 5), atol=1e-5)
    assert loaded.meta == {"robot": "a1"}
