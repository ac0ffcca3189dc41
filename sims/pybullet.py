"""PyBullet backend.

Torque control with the PD law computed in numpy at every 200 Hz substep, inertias taken from the
URDF, self-collision off. Joint dynamics: viscous damping is added to the numpy law; Coulomb
friction is each joint's velocity motor, held at zero velocity with the friction torque as its
maximum force (it acts beside torque control). Bullet has no joint armature (reflected rotor
inertia); it is emulated by adding the armature to the child link's inertia about the joint axis
(`add_armature`). APPROXIMATION: a real rotor spins at the joint's rate only, while this extra
inertia turns with the link, so it also loads the joints above it (a thigh carries its calf's
armature too); `bench validate` measures how close the step responses come.
PyBullet reports the base pose and velocity at the base's centre of mass; they are moved
to the base link origin so every engine reports the same point.
"""

from __future__ import annotations

import math

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


def add_armature(p: BulletClient, body: int, joints: list[int], armature: np.ndarray) -> None:
    """Emulate each joint's armature (kg m^2) with extra inertia of its child link about the joint axis.

    APPROXIMATION: a real rotor turns at its joint's rate only, while this inertia turns with the link,
    so it also loads the joints above it (a thigh carries its calf's armature too; giving the thigh
    its armature less the calf's made both joints slower in `bench validate`, so it was not kept).
    Bullet holds a link's inertia as a diagonal in its principal frame, the frame it gives the joint
    axis in; the armature goes to those axes by the squared cosines of the joint axis (exact where
    the axis is principal; here all lie within 0.25 rad of one).
    """
    for joint, extra in zip(joints, armature):
        axis = np.array(p.getJointInfo(body, joint)[13])
        cosines = axis / math.sqrt(sum(a * a for a in axis))  # not np.linalg.norm: BLAS, CPU-dependent bits
        diagonal = np.array(p.getDynamicsInfo(body, joint)[2])
        p.changeDynamics(body, joint, localInertiaDiagonal=(diagonal + extra * cosines**2).tolist())


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
        self.body = p.loadURDF(str(robot.urdf), [0.0, 0.0, robot.init_height], flags=p.URDF_USE_INERTIA_FROM_FILE,
                               useFixedBase=physics.fixed_base)
        names = {p.getJointInfo(self.body, i)[12].decode(): i for i in range(p.getNumJoints(self.body))}
        joint_names = {p.getJointInfo(self.body, i)[1].decode(): i for i in range(p.getNumJoints(self.body))}
        self._joints = [joint_names[j] for j in robot.joints]
        self._feet = [names[f] for f in robot.foot_links]
        self._fall_links = [-1 if link == robot.base_link else names[link] for link in robot.fall.contact_links]
        self._links = [-1] + list(range(p.getNumJoints(self.body)))
        self._link_names = (robot.base_link, *(p.getJointInfo(self.body, i)[12].decode() for i in self._links[1:]))
        for link in self._links:
            p.changeDynamics(self.body, link, lateralFriction=robot.ground_friction, restitution=0.0)
        self._damping = robot.joint_dynamics.damping
        add_armature(p, self.body, self._joints, robot.joint_dynamics.armature)
        p.setJointMotorControlArray(self.body, self._joints, p.VELOCITY_CONTROL, targetVelocities=[0.0] * len(self._joints),
                                    forces=robot.joint_dynamics.friction.tolist())
        self._com_offset = np.array(p.getDynamicsInfo(self.body, -1)[3])  # base inertial frame in link frame
        self._torque = np.zeros(robot.num_joints)
        self._nominal_mass = p.getDynamicsInfo(self.body, -1)[0]
        self._strength = 1.0
        self.time = 0.0
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
