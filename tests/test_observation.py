"""Observation layout and scaling, and fall detection logic."""

from __future__ import annotations

import numpy as np

from benchmark.trial.falls import fall_reason
from benchmark.trial.observation import LLM_OBS_DIM, RL_OBS_DIM, llm_observation, rl_observation
from robots import load_robot
from sims.base import RobotState
from sims.terrain import Terrain


def _state(**changes) -> RobotState:
    base = RobotState(
        time=0.0, base_pos=np.array([0.0, 0.0, 0.3]), base_quat=np.array([1.0, 0, 0, 0]),
        base_lin_vel=np.array([0.5, -0.1, 0.02]), base_ang_vel=np.array([0.4, 0.0, -0.8]),
        projected_gravity=np.array([0.0, 0.0, -1.0]), joint_pos=load_robot("a1").default_pose + 0.1,
        joint_vel=np.arange(12.0), joint_torque=np.zeros(12), foot_contact=np.ones(4, bool), fall_contact=False)
    return base._replace(**changes)


def test_rl_and_llm_observation_layout():
    robot = load_robot("a1")
    last = np.linspace(-1, 1, 12)
    obs = rl_observation(_state(), robot, robot.command, last)
    assert obs.shape == (RL_OBS_DIM,)
    np.testing.assert_allclose(obs[:3], [1.0, -0.2, 0.04])  # lin vel x 2.0
    np.testing.assert_allclose(obs[3:6], [0.1, 0.0, -0.2])  # ang vel x 0.25
    np.testing.assert_allclose(obs[6:9], [0, 0, -1])
    np.testing.assert_allclose(obs[9:12], [2.0, 0.0, 0.0])  # command vx 1.0 x lin-vel scale
    np.testing.assert_allclose(obs[12:24], 0.1)  # joint pos relative to default
    np.testing.assert_allclose(obs[24:36], np.arange(12.0) * 0.05)
    np.testing.assert_allclose(obs[36:], last)
    llm = llm_observation(obs)
    assert llm.shape == (LLM_OBS_DIM,)
    np.testing.assert_allclose(llm, np.concatenate([obs[:9], obs[12:36]]))


def test_fall_reasons():
    robot, flat = load_robot("a1"), Terrain("flat")
    assert fall_reason(_state(), robot, flat) is None
    assert "trunk" in fall_reason(_state(fall_contact=True), robot, flat)
    assert "above ground" in fall_reason(_state(base_pos=np.array([0, 0, 0.05])), robot, flat)
    tilted = np.array([np.sin(np.radians(70)), 0.0, -np.cos(np.radians(70))])
    assert "tilted 70" in fall_reason(_state(projected_gravity=tilted), robot, flat)
    assert "non-finite" in fall_reason(_state(joint_vel=np.full(12, np.nan)), robot, flat)
    assert "diverged: base speed 80" in fall_reason(_state(base_lin_vel=np.array([80.0, 0, 0])), robot, flat)
