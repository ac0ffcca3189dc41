"""Every engine's built model carries the robot's joint dynamics and contact friction (robot.toml),
and the hung-robot validation keeps the engines within the README's bounds of each other."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmark.checks.validate import REFERENCE, ValidateConfig, agreement, validate
from robots import available_robots, load_robot, per_joint
from sims import available_sims, make_sim
from sims.base import PhysicsConfig
from sims.terrain import Terrain


@pytest.mark.parametrize("robot_name", available_robots())
def test_robot_data_holds_joint_dynamics_and_ground_friction(robot_name):
    robot = load_robot(robot_name)
    jd = robot.joint_dynamics
    for values in (jd.armature, jd.damping, jd.friction, robot.torque_limit):
        assert values.shape == (robot.num_joints,) and np.all(values >= 0)
    assert np.all(jd.armature > 0) and np.all(jd.friction > 0)
    assert 0.5 <= robot.ground_friction <= 1.25  # inside the training randomization range
    text = (robot.folder / "robot.toml").read_text()
    assert "[joint_dynamics]" in text and text.count("#") > 10  # sources are written beside the figures


def test_a1_torque_limits_are_the_papers_per_joint_clip():
    np.testing.assert_allclose(load_robot("a1").torque_limit[:3], [23.7, 23.7, 35.55])
    np.testing.assert_allclose(per_joint([1.0, 2.0, 3.0]), [1, 2, 3] * 4)
    with pytest.raises(ValueError, match="expected 1, 3"):
        per_joint([1.0, 2.0])


@pytest.mark.parametrize("robot_name", available_robots())
def test_mujoco_model_carries_the_joint_dynamics(make, robot_name):
    sim = make("mujoco", robot_name)
    robot, m = sim.robot, sim.model
    dofs = sim._qvel_idx
    np.testing.assert_allclose(m.dof_armature[dofs], robot.joint_dynamics.armature)
    np.testing.assert_allclose(m.dof_damping[dofs], robot.joint_dynamics.damping)
    np.testing.assert_allclose(m.dof_frictionloss[dofs], robot.joint_dynamics.friction)
    np.testing.assert_allclose(m.actuator_forcerange[:, 1], robot.torque_limit)
    np.testing.assert_allclose(m.geom_friction[:, 0], robot.ground_friction)


@pytest.mark.parametrize("robot_name", available_robots())
def test_newton_solver_model_carries_the_joint_dynamics(make, robot_name):
    worlds = make("newton", robot_name).worlds
    robot, model = worlds.robot, worlds.model
    dofs = worlds._qd_idx
    np.testing.assert_allclose(model.joint_armature.numpy()[dofs], robot.joint_dynamics.armature, rtol=1e-6)
    np.testing.assert_allclose(model.joint_damping.numpy()[dofs], robot.joint_dynamics.damping, rtol=1e-6)
    np.testing.assert_allclose(model.joint_friction.numpy()[dofs], robot.joint_dynamics.friction, rtol=1e-6)
    np.testing.assert_allclose(model.joint_effort_limit.numpy()[dofs], robot.torque_limit, rtol=1e-6)
    np.testing.assert_allclose(model.shape_material_mu.numpy(), robot.ground_friction, rtol=1e-6)
    mj = worlds.solver.mj_model  # what mujoco_warp integrates
    armature = sorted(mj.dof_armature[6:].tolist())
    np.testing.assert_allclose(armature, sorted(robot.joint_dynamics.armature), rtol=1e-6)
    np.testing.assert_allclose(sorted(mj.dof_frictionloss[6:].tolist()), sorted(robot.joint_dynamics.friction),
                               rtol=1e-6)


@pytest.mark.parametrize("sim_name", available_sims())
def test_coulomb_friction_holds_a_limp_hung_leg(sim_name):
    """No PD at all: a hung leg swings under gravity without joint friction and is held with a large one.
    (PyBullet models it as a velocity motor at zero speed whose maximum force is the friction.)"""
    base = load_robot("a1")
    moved = {}
    for friction in (0.0, 50.0):
        robot = dataclasses.replace(base, kp=0.0, kd=0.0, joint_dynamics=dataclasses.replace(
            base.joint_dynamics, friction=np.full(12, friction), damping=np.zeros(12)))
        sim = make_sim(sim_name, robot, Terrain("flat"), PhysicsConfig(fixed_base=True))
        start = sim.reset(0).joint_pos
        for _ in range(5):
            state = sim.step(robot.default_pose)
        moved[friction] = float(np.abs(state.joint_pos - start).max())
        sim.close()
    assert moved[0.0] > 0.05 and moved[50.0] < 0.01, moved


@pytest.fixture(scope="module")
def validation():
    return validate(ValidateConfig(duration_s=0.6))[0]


@pytest.mark.slow
def test_newton_and_mujoco_step_responses_agree(validation):
    rise = agreement(validation, "newton", "mujoco")
    assert (rise < 0.15).all(), rise
    overshoot = validation[validation.command == "step"].set_index(["robot", "joint", "source"]).overshoot_pct
    gap = (overshoot.xs("newton", level="source") - overshoot.xs("mujoco", level="source")).abs()
    assert (gap < 5.0).all(), gap


@pytest.mark.slow
def test_engines_follow_the_one_joint_model(validation):
    """Every engine's step rise time within 15% of the one-joint model with armature. PyBullet's armature
    is emulated (geared rotors, sims.pybullet.with_rotors), and is held to the same bound."""
    for engine in ("mujoco", "newton", "pybullet"):
        rise = agreement(validation, engine, REFERENCE)
        assert (rise < 0.15).all(), (engine, rise)


@pytest.mark.parametrize("robot_name", available_robots())
def test_pybullet_emulates_the_armature_with_geared_rotors(robot_name):
    """Each joint drives a rotor on its parent link that turns ROTOR_GEAR times as fast, with inertia
    armature / ROTOR_GEAR^2 about the joint axis: the joint feels its whole armature. Swinging the hung
    leg shows the gear holds while the joints move."""
    from sims.pybullet import ROTOR_GEAR, ROTOR_SUFFIX

    robot = load_robot(robot_name)
    sim = make_sim("pybullet", robot, Terrain("flat"), PhysicsConfig(fixed_base=True))
    p, body = sim.client, sim.body
    try:
        joints = {p.getJointInfo(body, i)[1].decode(): i for i in range(p.getNumJoints(body))}
        rotors = [joints[name + ROTOR_SUFFIX] for name in robot.joints]
        for rotor, armature in zip(rotors, robot.joint_dynamics.armature):
            axis = np.array(p.getJointInfo(body, rotor)[13])  # in the rotor's inertial frame
            about_axis = np.array(p.getDynamicsInfo(body, rotor)[2]) @ (axis / np.linalg.norm(axis)) ** 2
            assert about_axis * ROTOR_GEAR**2 == pytest.approx(armature, rel=1e-3)
        sim.reset(0)
        targets = robot.default_pose + 0.3
        for _ in range(2):
            sim.step(targets)
        joint_rate = np.array([s[1] for s in p.getJointStates(body, sim._joints)])
        rotor_rate = np.array([s[1] for s in p.getJointStates(body, rotors)])
        assert np.abs(joint_rate).max() > 0.5  # the leg is moving
        np.testing.assert_allclose(rotor_rate, ROTOR_GEAR * joint_rate, atol=1e-3 * ROTOR_GEAR)
        assert all(not name.endswith(ROTOR_SUFFIX) for name in sim.body_poses().names)  # never drawn or logged
    finally:
        sim.close()
