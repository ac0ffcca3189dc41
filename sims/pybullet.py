"""PyBullet backend.

Torque control with the PD law computed in numpy at every 200 Hz substep, inertias taken from the
URDF, self-collision off. Joint dynamics: viscous damping is added to the numpy law; Coulomb
friction is each joint's velocity motor, held at zero velocity with the friction torque as its
maximum force (it acts beside torque control). Bullet has no joint armature (reflected rotor
inertia); it is emulated by a rotor (`with_rotors`): a small disk on each joint's parent link, turning
about the joint's axis, geared to the joint by a Bullet gear constraint at ROTOR_GEAR times the
joint's rate, with inertia armature / ROTOR_GEAR^2, so the joint feels the whole armature.
APPROXIMATION: the rotor also turns with its parent link, which couples the armature into the joints
above it by armature / ROTOR_GEAR (exact only as the gear grows; an ideal armature couples nothing),
and the gear constraint is solved by Bullet's iterative solver. Bullet's gear constraint assumes a free
base (it indexes degrees of freedom past the base's six), so a hung robot keeps a free base, pinned to
the world by a fixed constraint.
PyBullet reports the base pose and velocity at the base's centre of mass; they are moved
to the base link origin so every engine reports the same point.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from sims.base import (BodyPoses, Dynamics, PhysicsConfig, RobotState, initial_joint_pos, pd_torque, quiet_fds,
                       rotate, world_to_base)


with quiet_fds((1, 2)):  # banners on stdout, its build time on stderr
    import pybullet
    from pybullet_utils.bullet_client import BulletClient

from robots import Robot  # noqa: E402  (after the quiet import of pybullet)
from sims.terrain import Terrain  # noqa: E402


def _xyzw_to_wxyz(q) -> np.ndarray:
    return np.array([q[3], q[0], q[1], q[2]])


# The rotor turns this many times faster than its joint. Real reductions are larger (A1 about 9:1, ANYdrive
# 50:1); in `bench validate` the step responses of 10 and 20 agreed within 0.3 ms, and 1 (the same inertia
# turning with the child link) made the A1 calf 33% slower than the one-joint model.
ROTOR_GEAR = 10.0
ROTOR_SUFFIX = "__rotor"


def with_rotors(robot: Robot) -> str:
    """The robot's URDF text with one rotor link per actuated joint: a child of the joint's parent,
    at the joint's origin, turning about its axis, a disk with inertia armature / ROTOR_GEAR^2 about it."""
    tree = ElementTree.parse(robot.urdf)
    root = tree.getroot()
    joints = {joint.get("name"): joint for joint in root.findall("joint")}
    for name, armature in zip(robot.joints, robot.joint_dynamics.armature):
        joint = joints[name]
        axis = np.array([float(v) for v in joint.find("axis").get("xyz").split()])
        axis = axis / math.sqrt(float(axis @ axis))
        about = armature / ROTOR_GEAR**2
        inertia = about / 2 * (np.eye(3) + np.outer(axis, axis))  # a thin disk: half as much across the axis
        link = ElementTree.SubElement(root, "link", name=name + ROTOR_SUFFIX)
        inertial = ElementTree.SubElement(link, "inertial")
        ElementTree.SubElement(inertial, "mass", value="1e-3")
        ElementTree.SubElement(inertial, "inertia", **{f"i{a}{b}": repr(float(inertia[i, j]))
                                                       for i, a in enumerate("xyz") for j, b in enumerate("xyz") if j >= i})
        rotor = ElementTree.SubElement(root, "joint", name=name + ROTOR_SUFFIX, type="continuous")
        ElementTree.SubElement(rotor, "parent", link=joint.find("parent").get("link"))
        ElementTree.SubElement(rotor, "child", link=name + ROTOR_SUFFIX)
        origin = joint.find("origin")
        ElementTree.SubElement(rotor, "origin", xyz=origin.get("xyz", "0 0 0"), rpy=origin.get("rpy", "0 0 0"))
        ElementTree.SubElement(rotor, "axis", xyz=joint.find("axis").get("xyz"))
    return ElementTree.tostring(root, encoding="unicode")


def gear_rotors(p: BulletClient, body: int, joints: list[int], rotors: list[int]) -> None:
    """Free each rotor and tie it to its joint: joint rate + ratio * rotor rate = 0 (Bullet's gear law)."""
    p.setJointMotorControlArray(body, rotors, p.VELOCITY_CONTROL, forces=[0.0] * len(rotors))
    for joint, rotor in zip(joints, rotors):
        p.changeDynamics(body, rotor, maxJointVelocity=1000.0, linearDamping=0.0, angularDamping=0.0)
        gear = p.createConstraint(body, joint, body, rotor, jointType=p.JOINT_GEAR, jointAxis=[1, 0, 0],
                                  parentFramePosition=[0, 0, 0], childFramePosition=[0, 0, 0])
        p.changeConstraint(gear, gearRatio=-1.0 / ROTOR_GEAR, maxForce=1e4, erp=0.0)


class PybulletSim:
    """One robot on one terrain in PyBullet."""

    name = "pybullet"

    def __init__(self, robot: Robot, terrain: Terrain, physics: PhysicsConfig = PhysicsConfig()) -> None:
        self.robot, self.terrain, self.physics = robot, terrain, physics
        with quiet_fds():
            self.client = p = BulletClient(connection_mode=pybullet.DIRECT)
        p.setTimeStep(physics.dt)
        p.setPhysicsEngineParameter(deterministicOverlappingPairs=1)
        p.setGravity(0.0, 0.0, physics.gravity)
        self.ground = self._load_terrain()
        with tempfile.TemporaryDirectory() as folder:  # Bullet reads the file while loading it
            urdf = Path(folder) / robot.urdf.name
            urdf.write_text(with_rotors(robot))
            self.body = p.loadURDF(str(urdf), [0.0, 0.0, robot.init_height], flags=p.URDF_USE_INERTIA_FROM_FILE)
        names = {p.getJointInfo(self.body, i)[12].decode(): i for i in range(p.getNumJoints(self.body))}
        joint_names = {p.getJointInfo(self.body, i)[1].decode(): i for i in range(p.getNumJoints(self.body))}
        self._joints = [joint_names[j] for j in robot.joints]
        self._feet = [names[f] for f in robot.foot_links]
        self._fall_links = [-1 if link == robot.base_link else names[link] for link in robot.fall.contact_links]
        self._links = [-1] + [i for name, i in names.items() if not name.endswith(ROTOR_SUFFIX)]
        self._link_names = (robot.base_link, *(p.getJointInfo(self.body, i)[12].decode() for i in self._links[1:]))
        for link in self._links:
            p.changeDynamics(self.body, link, lateralFriction=robot.ground_friction, restitution=0.0)
        self._damping = robot.joint_dynamics.damping
        gear_rotors(p, self.body, self._joints, [joint_names[j + ROTOR_SUFFIX] for j in robot.joints])
        p.setJointMotorControlArray(self.body, self._joints, p.VELOCITY_CONTROL, targetVelocities=[0.0] * len(self._joints),
                                    forces=robot.joint_dynamics.friction.tolist())
        self._com_offset = np.array(p.getDynamicsInfo(self.body, -1)[3])  # base inertial frame in link frame
        self._torque = np.zeros(robot.num_joints)
        self._nominal_mass = p.getDynamicsInfo(self.body, -1)[0]
        self._strength = 1.0
        self.time = 0.0
        if physics.fixed_base:  # hung: the free base pinned where reset puts it
            p.resetBasePositionAndOrientation(self.body, self._com_world([0.0, 0.0, 0.0]), [0, 0, 0, 1])
            p.createConstraint(self.body, -1, -1, -1, p.JOINT_FIXED, [0, 0, 0], [0, 0, 0], self._com_world([0.0, 0.0, 0.0]))
        # Bullet keeps contact points and warm-start impulses across a teleport; restoring this
        # snapshot at every reset makes a trial independent of the trials the sim ran before.
        self._fresh = p.saveState()

    def _load_terrain(self) -> int:
        p, t = self.client, self.terrain
        if t.is_flat:
            shape = p.createCollisionShape(p.GEOM_PLANE)
            position = [0.0, 0.0, 0.0]
        else:
            rows, cols = t.shape
            # Bullet's heightfield is indexed x-fastest and centred on the middle of its height range.
            shape = p.createCollisionShape(
                p.GEOM_HEIGHTFIELD, meshScale=[t.resolution, t.resolution, 1.0],
                heightfieldData=t.heights.ravel().tolist(), numHeightfieldRows=cols, numHeightfieldColumns=rows)
            position = [*t.center, (t.heights.min() + t.heights.max()) / 2]
        ground = p.createMultiBody(0, shape, basePosition=position)
        p.changeDynamics(ground, -1, lateralFriction=1.0, restitution=0.0)  # Bullet multiplies frictions
        return ground

    def reset(self, seed: int = 0) -> RobotState:
        p, robot = self.client, self.robot
        p.restoreState(self._fresh)
        p.resetBasePositionAndOrientation(self.body, self._com_world([0.0, 0.0, 0.0]), [0, 0, 0, 1])
        for joint, q in zip(self._joints, initial_joint_pos(robot, seed)):
            p.resetJointState(self.body, joint, q, 0.0)
        p.resetBaseVelocity(self.body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
        self._torque[:] = 0.0
        self.time = 0.0
        return self._state()

    def _com_world(self, xy: list[float]) -> list[float]:
        z = self.robot.init_height + self.terrain.height_at(0.0, 0.0)
        if self.physics.fixed_base:
            z += self.physics.hang_height
        return list(np.array([xy[0], xy[1], z]) + self._com_offset)

    def step(self, joint_targets: np.ndarray) -> RobotState:
        self._substeps(np.asarray(joint_targets, dtype=float), self.physics.substeps)
        self.time += self.physics.control_dt
        return self._state()

    def _substeps(self, targets: np.ndarray, n: int) -> None:
        p, body, joints, robot = self.client, self.body, self._joints, self.robot
        for _ in range(n):
            states = p.getJointStates(body, joints)
            q = np.array([s[0] for s in states])
            qd = np.array([s[1] for s in states])
            self._torque = pd_torque(robot, targets, q, qd, self._strength)
            p.setJointMotorControlArray(body, joints, p.TORQUE_CONTROL, forces=self._torque - self._damping * qd)
            p.stepSimulation()

    def raw_loop(self, joint_targets: np.ndarray, control_steps: int) -> None:
        p, body, joints = self.client, self.body, self._joints
        kp, kd, limit, damping = self.robot.kp, self.robot.kd, self.robot.torque_limit, self._damping
        for _ in range(control_steps * self.physics.substeps):
            states = p.getJointStates(body, joints)
            q = np.array([s[0] for s in states])
            qd = np.array([s[1] for s in states])
            tau = np.clip(kp * (joint_targets - q) - kd * qd, -limit, limit) - damping * qd
            p.setJointMotorControlArray(body, joints, p.TORQUE_CONTROL, forces=tau)
            p.stepSimulation()

    def _state(self) -> RobotState:
        p, body = self.client, self.body
        com, quat_xyzw = p.getBasePositionAndOrientation(body)
        lin_com, ang = p.getBaseVelocity(body)
        quat = _xyzw_to_wxyz(quat_xyzw)
        rot = world_to_base(quat)  # world -> base
        offset_world = rotate(rot.T, self._com_offset)
        ang_world = np.array(ang)
        lin_world = np.array(lin_com) - np.cross(ang_world, offset_world)  # velocity of the link origin
        states = p.getJointStates(body, self._joints)
        touching = {c[3] for c in p.getContactPoints(bodyA=body, bodyB=self.ground)}
        return RobotState(
            time=self.time,
            base_pos=np.array(com) - offset_world,
            base_quat=quat,
            base_lin_vel=rotate(rot, lin_world),
            base_ang_vel=rotate(rot, ang_world),
            projected_gravity=-rot[:, 2],
            joint_pos=np.array([s[0] for s in states]),
            joint_vel=np.array([s[1] for s in states]),
            joint_torque=self._torque.copy(),
            foot_contact=np.array([f in touching for f in self._feet]),
            fall_contact=any(link in touching for link in self._fall_links),
        )

    def set_dynamics(self, dynamics: Dynamics) -> None:
        p = self.client
        friction = self.robot.ground_friction if dynamics.friction is None else dynamics.friction
        for link in self._links:  # Bullet multiplies the two frictions; the ground keeps 1.0
            p.changeDynamics(self.body, link, lateralFriction=friction)
        p.changeDynamics(self.body, -1, mass=self._nominal_mass * dynamics.base_mass_scale)
        self._strength = dynamics.motor_strength

    def push_base(self, velocity_xy: np.ndarray) -> None:
        if self.physics.fixed_base:
            return
        linear, angular = self.client.getBaseVelocity(self.body)
        self.client.resetBaseVelocity(self.body, [linear[0] + velocity_xy[0], linear[1] + velocity_xy[1], linear[2]],
                                      angular)

    def body_poses(self) -> BodyPoses:
        p, body = self.client, self.body
        com, quat = p.getBasePositionAndOrientation(body)
        rot = world_to_base(_xyzw_to_wxyz(quat))
        positions = [np.array(com) - rotate(rot.T, self._com_offset)]
        quats = [_xyzw_to_wxyz(quat)]
        for s in p.getLinkStates(body, self._links[1:], computeForwardKinematics=True):
            positions.append(np.array(s[4]))
            quats.append(_xyzw_to_wxyz(s[5]))
        return BodyPoses(self._link_names, np.array(positions), np.array(quats))

    def ray_height(self, x: float, y: float) -> float:
        """Terrain height under (x, y), found by casting a ray down."""
        hit = self.client.rayTest([x, y, 5.0], [x, y, -5.0])[0]
        return hit[3][2]

    def close(self) -> None:
        self.client.disconnect()
