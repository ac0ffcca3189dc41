"""Every engine x robot x terrain cell stands; joint order and contacts mean the same everywhere."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmark.trial.policies import SeedPolicy, StandPolicy
from benchmark.trial.runner import EpisodeConfig, run_trial
from robots import LEGS, available_robots, load_robot
from sims import available_sims, make_sim
from sims.base import PhysicsConfig, world_to_base, world_to_base_batch
from sims.terrain import Terrain

from conftest import CELLS


def _stand(sim, seconds: float = 3.0):
    robot = sim.robot
    state = sim.reset(0)
    for _ in range(int(seconds / sim.physics.control_dt)):
        state = sim.step(robot.default_pose)
    return state


@pytest.mark.parametrize("sim_name,robot_name,terrain", CELLS)
def test_every_cell_stands_for_5_s(make, sim_name, robot_name, terrain):
    sim = make(sim_name, robot_name, terrain)
    result = run_trial(sim, sim.robot, sim.terrain, StandPolicy(sim.robot), EpisodeConfig(duration=5.0), seed=3)
    assert result.upright_fraction == 1.0 and result.fall_time is None, result.fall_reason
    assert not result.success and result.nwt == 0.0  # standing is not walking
    assert abs(result.distance_m) < 0.1 and abs(result.lateral_drift_m) < 0.1


@pytest.mark.parametrize("robot_name", available_robots())
def test_standing_height_agrees_across_engines(make, robot_name):
    heights = {name: _stand(make(name, robot_name))[1][2] for name in available_sims()}
    assert max(heights.values()) - min(heights.values()) < 0.03, heights


@pytest.mark.parametrize("sim_name,robot_name", [(s, r) for s in available_sims() for r in available_robots()])
def test_state_is_consistent_while_standing(make, sim_name, robot_name):
    sim = make(sim_name, robot_name)
    state = _stand(sim, 2.0)
    assert state.foot_contact.tolist() == [True] * 4 and not state.fall_contact
    assert state.projected_gravity[2] < -0.98 and np.linalg.norm(state.projected_gravity) == pytest.approx(1.0)
    assert np.linalg.norm(state.base_lin_vel) < 0.05 and np.linalg.norm(state.base_ang_vel) < 0.1
    np.testing.assert_allclose(state.joint_pos, sim.robot.default_pose, atol=0.35)
    assert np.all(np.abs(state.joint_torque) <= sim.robot.torque_limit + 1e-9)
    assert state.time == pytest.approx(2.0)
    poses = sim.body_poses()
    names = list(poses.names)
    assert names[0] == sim.robot.base_link
    np.testing.assert_allclose(poses.positions[0], state.base_pos, atol=1e-6)
    for leg, foot in enumerate(sim.robot.foot_links):  # feet sit on the ground, legs named in order
        pos = poses.positions[names.index(foot)]
        front, right = LEGS[leg][0] == "F", LEGS[leg][1] == "R"
        assert pos[2] < 0.06
        assert (pos[0] > state.base_pos[0]) == front and (pos[1] < state.base_pos[1]) == right


@pytest.mark.parametrize("sim_name,robot_name", [(s, r) for s in available_sims() for r in available_robots()])
@pytest.mark.parametrize("joint", [0, 4, 6, 8, 10])
def test_commanding_one_canonical_joint_moves_that_joint(make, sim_name, robot_name, joint):
    sim = make(sim_name, robot_name)
    robot = sim.robot
    before = _stand(sim, 1.0)
    feet_before = _foot_positions(sim)
    targets = robot.default_pose.copy()
    targets[joint] += 0.3
    for _ in range(3):
        after = sim.step(targets)
    moved = after.joint_pos - before.joint_pos
    assert int(np.argmax(np.abs(moved))) == joint and moved[joint] > 0.1, moved.round(3)
    feet_moved = _foot_positions(sim) - feet_before
    leg = joint // 3
    if joint % 3 == 0:  # hip abduction about +x swings the foot toward +y (the base rolls too)
        assert feet_moved[leg, 1] > 0.02 and int(np.argmax(feet_moved[:, 1])) == leg, feet_moved.round(3)
    else:
        distance = np.linalg.norm(feet_moved, axis=1)
        assert int(np.argmax(distance)) == leg, distance.round(3)


def _foot_positions(sim) -> np.ndarray:
    """Feet relative to the base, in the base frame: leg kinematics, whatever touches the ground."""
    poses = sim.body_poses()
    feet = np.array([poses.positions[poses.names.index(f)] for f in sim.robot.foot_links])
    return (feet - poses.positions[0]) @ world_to_base(poses.quats[0]).T


@pytest.mark.parametrize("sim_name", available_sims())
def test_a_limp_robot_falls_and_the_trial_says_why(sim_name):
    robot = dataclasses.replace(load_robot("a1"), kp=0.0)
    sim = make_sim(sim_name, robot, Terrain("flat"))
    try:
        result = run_trial(sim, robot, sim.terrain, StandPolicy(robot), EpisodeConfig(duration=3.0), seed=0)
    finally:
        sim.close()
    assert not result.success and result.fall_time is not None and result.upright_fraction < 1.0
    assert result.upright_fraction == pytest.approx(result.fall_time / 3.0) and result.nwt == 0.0
    assert "ground" in result.fall_reason


@pytest.mark.parametrize("sim_name", available_sims())
def test_seeds_perturb_the_initial_pose_reproducibly(make, sim_name):
    sim = make(sim_name, "a1")
    a, b, c = sim.reset(1).joint_pos, sim.reset(2).joint_pos, sim.reset(1).joint_pos
    np.testing.assert_allclose(a, c)
    assert not np.allclose(a, b)


@pytest.mark.parametrize("sim_name", ["mujoco", "pybullet"])
def test_a_trial_does_not_depend_on_the_trials_before_it(make, sim_name):
    """A sweep spreads a cell's trials over workers: seed 1 must walk the same after seed 0 or not.
    (PyBullet keeps contact points across a teleport unless its state is restored.)"""

    sim = make(sim_name, "a1", "rough")
    policy = SeedPolicy(sim.robot)
    walk = lambda seed: run_trial(sim, sim.robot, sim.terrain, policy, EpisodeConfig(4.0), seed)  # noqa: E731
    first = walk(1)
    walk(0)
    again = walk(1)
    assert first.distance_m > 1.0 and again.distance_m == first.distance_m
    assert again.lateral_drift_m == first.lateral_drift_m


@pytest.mark.parametrize("sim_name", available_sims())
def test_an_exploding_simulation_is_a_failed_trial_with_a_reason(sim_name):
    """Absurd gains at a coarse timestep blow the integration up: reported, never a crash."""
    robot = dataclasses.replace(load_robot("a1"), kp=5000.0, kd=0.0, torque_limit=np.full(12, 1e6))
    sim = make_sim(sim_name, robot, Terrain("flat"), PhysicsConfig(dt=0.02, substeps=5))
    try:
        result = run_trial(sim, robot, sim.terrain, StandPolicy(robot), EpisodeConfig(duration=3.0), seed=0)
    finally:
        sim.close()
    assert not result.success and result.fall_time is not None and result.fall_time < 3.0
    assert result.fall_reason


def test_batched_rotation_matches_the_one_quaternion_version():
    quats = np.random.default_rng(3).standard_normal((7, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    batch = world_to_base_batch(quats)
    for quat, matrix in zip(quats, batch):
        np.testing.assert_allclose(matrix, world_to_base(quat), atol=1e-12)
    np.testing.assert_allclose(batch @ batch.transpose(0, 2, 1), np.broadcast_to(np.eye(3), (7, 3, 3)), atol=1e-12)
