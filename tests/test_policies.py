"""The shipped seed policies walk; the numpy actor matches the trained torch network."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmark.trial.cell import CellSpec
from benchmark.trial.trials import run_cell
from benchmark.trial.mlp import MlpActor
from robots import available_robots, load_robot


# The seed-policy criteria in MuJoCo, over 20 trials of 10 s (seeds 0-19): success rate under the
# walking metrics (the 0.8 in every cell), mean forward speed (0.6 m/s at the 1 m/s command)
# and mean |sideways drift|. A trial takes ~0.1 s of CPU.
MIN_SPEED = {("a1", "flat"): 0.6, ("a1", "rough"): 0.6, ("anymal", "flat"): 0.6, ("anymal", "rough"): 0.6}
MIN_SUCCESS = {cell: 0.8 for cell in MIN_SPEED}


@pytest.mark.parametrize(("robot_name", "terrain"), sorted(MIN_SPEED))
def test_shipped_policy_walks_in_mujoco_at_the_fixed_command(robot_name, terrain):
    trials = run_cell(CellSpec(sim="mujoco", robot=robot_name, terrain=terrain, policy="rl"), range(20))
    assert np.mean([t.success for t in trials]) >= MIN_SUCCESS[(robot_name, terrain)], [t.fall_reason for t in trials]
    assert np.mean([t.mean_vx for t in trials]) >= MIN_SPEED[(robot_name, terrain)]


@pytest.mark.parametrize(("robot_name", "terrain"), sorted(MIN_SPEED))
def test_with_the_heading_hold_every_shipped_policy_keeps_its_line(robot_name, terrain):
    """Seed-policy-only evaluation may steer (`--heading-hold`): sideways drift stays under 1 m in 10 s."""
    trials = run_cell(CellSpec(sim="mujoco", robot=robot_name, terrain=terrain, policy="rl", heading_hold=True),
                      range(20))
    assert np.mean([abs(t.lateral_drift_m) for t in trials]) < 1.0, [t.lateral_drift_m for t in trials]


STRAIGHT = [r for r in available_robots() if MlpActor.load(load_robot(r).folder / "policy.npz").symmetric]


@pytest.mark.parametrize("robot_name", STRAIGHT)  # policies trained for the fixed command (symmetric inference)
def test_a_policy_trained_for_the_fixed_command_walks_straight_without_help(robot_name):
    """MuJoCo, flat, 19 s of walking at the fixed command: the straight-walking targets (bench straight)."""
    from benchmark.checks.straight import TARGETS, StraightConfig, measure

    frame, _ = measure(StraightConfig(robot=(robot_name,), sim=("mujoco",), trials=3))
    assert (frame["yaw_rad"].abs() <= TARGETS["abs_yaw_rad"]).all(), frame
    assert (frame["y_m"].abs() <= TARGETS["abs_y_m"]).all() and (frame["x_m"] >= TARGETS["x_m"]).all(), frame


@pytest.mark.parametrize("robot_name", available_robots())
def test_shipped_policy_documents_how_it_was_made(robot_name):
    robot = load_robot(robot_name)
    meta = json.loads((robot.folder / "policy.json").read_text())
    assert meta["robot"] == robot_name and "mujoco" in meta["trained_in"].split("+")
    assert meta["command"].startswith("bench train") and "torch" in meta["versions"]
    total, stage = 0, meta  # fine-tuned policies record the run they started from
    while stage:
        total += stage["env_steps"]
        stage = stage.get("init_from")
    assert total >= 500_000
    actor = MlpActor.load(robot.folder / "policy.npz")
    assert actor.weights[0].shape == (256, 48) and actor.weights[-1].shape == (12, 256 // 2)
    assert (robot.folder / "policy.npz").stat().st_size < 400_000  # actor only, no optimizer state


def test_numpy_actor_equals_the_torch_network(tmp_path):
    import torch
    import torch.nn as nn

    from benchmark.training.train import export_actor

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


def test_an_llm_cells_seed_phase_runs_at_the_papers_fixed_command():
    """Every example in the prompt is a function of what the prompt shows: no hidden yaw-rate command."""
    from benchmark.trial.cell import make_cell
    from benchmark.trial.trials import TrialHooks, run_cell

    class Commands(TrialHooks):
        seen: list = []

        def start(self, seed, sim, policy, episode):
            return lambda loop: self.seen.append(loop.command.copy())

    watch = Commands()
    cell = make_cell({"policy": "llm", "model": "hold", "history": 5, "duration": 3.0, "llm_after": 2.0})
    run_cell(cell, [0], hooks=[watch])
    robot = load_robot("a1")
    assert len(watch.seen) == 30
    np.testing.assert_array_equal(np.array(watch.seen), np.tile(robot.command, (30, 1)))
    held = make_cell({"policy": "llm", "model": "hold", "history": 5, "duration": 3.0, "llm_after": 2.0,
                      "heading_hold": True})
    watch.seen.clear()
    run_cell(held, [0], hooks=[watch])
    assert np.abs(np.array(watch.seen)[:, 2]).max() > 0  # the opt-in hold does steer
