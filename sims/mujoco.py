"""MuJoCo backend.

The URDF is loaded through MjSpec, given a free base joint and one position actuator per
joint (kp, kv, force range = the robot's PD gains and torque limit), so the 200 Hz PD law
runs inside `mj_step(nstep=20)` with no Python per substep. Speed settings (README, "Engine
settings"): implicitfast integrator (PD damping integrated implicitly), pyramidal friction cone,
`PhysicsConfig.impratio`, condim 3, robot self-collision off (as in PyBullet's default).
The robot's joint dynamics are MuJoCo's own joint attributes: armature, damping, frictionloss.
"""

from __future__ import annotations

import mujoco
import numpy as np

from robots import Robot
from sims.base import BodyPoses, Dynamics, PhysicsConfig, RobotState, initial_joint_pos, rotate
from sims.terrain import Terrain

TERRAIN_BOTTOM = 0.1  # m, thickness of the heightfield box below its lowest point


def build_spec(robot: Robot, terrain: Terrain, physics: PhysicsConfig) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_file(str(robot.urdf))
    spec.compiler.fusestatic = False  # keep the feet as bodies: contacts are reported per foot
    spec.compiler.discardvisual = True
    spec.option.timestep = physics.dt
    spec.option.gravity = [0.0, 0.0, physics.gravity]
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    spec.option.impratio = physics.impratio
    friction = [robot.ground_friction, 0.005, 0.0001]
    for geom in spec.geoms:  # robot geoms collide with the terrain only
        geom.contype, geom.conaffinity, geom.condim, geom.friction = 1, 0, 3, friction
    if physics.fixed_base:
        spec.body(robot.base_link).pos = [0.0, 0.0, robot.init_height + physics.hang_height]
    else:
        spec.body(robot.base_link).add_freejoint()
    jd = robot.joint_dynamics
    for i, joint in enumerate(robot.joints):
        spec.joint(joint).armature = jd.armature[i]
        spec.joint(joint).damping = [jd.damping[i], 0.0, 0.0]
        spec.joint(joint).frictionloss = jd.friction[i]
        actuator = spec.add_actuator(name=joint, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        actuator.set_to_position(kp=robot.kp, kv=robot.kd)
        actuator.forcelimited = True
        actuator.forcerange = [-robot.torque_limit[i], robot.torque_limit[i]]
    ground = spec.worldbody.add_geom(name="terrain", contype=0, conaffinity=1, condim=3, friction=friction)
    if terrain.is_flat:
        ground.type, ground.size = mujoco.mjtGeom.mjGEOM_PLANE, [0.0, 0.0, 1.0]
    else:
        heights = terrain.heights
        low, span = float(heights.min()), max(float(np.ptp(heights)), 1e-4)
        rows, cols = heights.shape
        spec.add_hfield(name="terrain", size=[terrain.size[0] / 2, terrain.size[1] / 2, span, TERRAIN_BOTTOM],
                        nrow=rows, ncol=cols, userdata=((heights - low) / span).ravel().tolist())
        ground.type, ground.hfieldname = mujoco.mjtGeom.mjGEOM_HFIELD, "terrain"
        ground.pos = [*terrain.center, low]
    return spec


def hung_joint_inertia_and_gravity(robot: Robot, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's own inertia (the joint-space mass matrix diagonal, armature excluded; kg m^2) and
    gravity torque (N m), canonical order, for the robot hung by its base in `pose`."""
    sim = MujocoSim(robot, Terrain("flat"), PhysicsConfig(fixed_base=True))
    m, d = sim.model, sim.data
    d.qpos[sim._qpos_idx] = pose
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    dofs = sim._qvel_idx
    return full[dofs, dofs] - m.dof_armature[dofs], -d.qfrc_bias[dofs]


class MujocoSim:
    """One robot on one terrain in MuJoCo."""

    name = "mujoco"

    def __init__(self, robot: Robot, terrain: Terrain, physics: PhysicsConfig = PhysicsConfig()) -> None:
        self.robot, self.terrain, self.physics = robot, terrain, physics
        self.model = build_spec(robot, terrain, physics).compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        mujoco.mj_forward(m, self.data)
        joint_ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in robot.joints]
        self._qpos_idx = np.array([m.jnt_qposadr[j] for j in joint_ids])
        self._qvel_idx = np.array([m.jnt_dofadr[j] for j in joint_ids])
        body_id = lambda name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)  # noqa: E731
        # Per geom a bit mask: bit i for foot i, bit 4 for "touching here is a fall". OR-ing
        # the masks of the geoms in contact gives all foot contacts and the fall flag at once.
        num_feet = len(robot.foot_links)
        geom_bits = np.zeros(m.ngeom, dtype=np.int64)
        for leg, foot in enumerate(robot.foot_links):
            geom_bits[m.geom_bodyid == body_id(foot)] |= 1 << leg
        fall_bodies = [body_id(b) for b in robot.fall.contact_links]
        geom_bits[np.isin(m.geom_bodyid, fall_bodies)] |= 1 << num_feet
        self._geom_bits = geom_bits.tolist()
        self._fall_bit = 1 << num_feet
        self._feet_of_bits = (np.arange(1 << num_feet)[:, None] >> np.arange(num_feet)) & 1 == 1
        # Base pose and joints gathered with one `take` each from views made once. A fixed base has no
        # coordinates: its constant pose and zero velocity are prepended instead.
        self._hung = None
        if physics.fixed_base:
            self._pos_idx, self._vel_idx = self._qpos_idx, self._qvel_idx
            self._hung = (np.array([*m.body_pos[body_id(robot.base_link)], 1.0, 0.0, 0.0, 0.0]), np.zeros(6))
        else:
            self._pos_idx = np.concatenate([np.arange(7), self._qpos_idx])
            self._vel_idx = np.concatenate([np.arange(6), self._qvel_idx])
        d = self.data
        self._qpos, self._qvel, self._act_force = d.qpos, d.qvel, d.actuator_force
        self._rot = np.zeros(9)
        self._base_body = body_id(robot.base_link)
        self._nominal_mass = float(m.body_mass[self._base_body])
        self._robot_bodies = np.arange(1, m.nbody)
        self._body_names = tuple(m.body(i).name for i in self._robot_bodies)

    def reset(self, seed: int = 0) -> RobotState:
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        if self._hung is None:
            d.qpos[:3] = [0.0, 0.0, self.robot.init_height + self.terrain.height_at(0.0, 0.0)]
            d.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]
        d.qpos[self._qpos_idx] = initial_joint_pos(self.robot, seed)
        d.ctrl[:] = self.robot.default_pose
        mujoco.mj_forward(m, d)
        return self._state()

    def step(self, joint_targets: np.ndarray) -> RobotState:
        self.data.ctrl[:] = joint_targets
        mujoco.mj_step(self.model, self.data, nstep=self.physics.substeps)
        return self._state()

    def raw_loop(self, joint_targets: np.ndarray, control_steps: int) -> None:
        m, d, n = self.model, self.data, self.physics.substeps
        d.ctrl[:] = joint_targets
        for _ in range(control_steps):
            mujoco.mj_step(m, d, nstep=n)

    def _state(self) -> RobotState:
        d = self.data
        qpos, qvel = self._qpos.take(self._pos_idx), self._qvel.take(self._vel_idx)
        if self._hung is not None:
            qpos, qvel = np.concatenate([self._hung[0], qpos]), np.concatenate([self._hung[1], qvel])
        mujoco.mju_quat2Mat(self._rot, qpos[3:7])
        body_to_world = self._rot.reshape(3, 3)  # v @ R == R^T v: world -> base
        bits, geom_bits = 0, self._geom_bits  # a Python loop: a handful of contacts, ufunc.reduce is slower
        for geom in d.contact.geom.ravel().tolist():
            bits |= geom_bits[geom]
        return RobotState(
            time=d.time,
            base_pos=qpos[:3],
            base_quat=qpos[3:7],
            base_lin_vel=rotate(body_to_world.T, qvel[:3]),  # free joint: world-frame linear velocity
            base_ang_vel=qvel[3:6],  # free joint: body-frame angular velocity
            projected_gravity=-body_to_world[2],
            joint_pos=qpos[7:],
            joint_vel=qvel[6:],
            joint_torque=self._act_force.copy(),
            foot_contact=self._feet_of_bits[bits & (self._fall_bit - 1)],
            fall_contact=bits >= self._fall_bit,
        )

    def set_dynamics(self, dynamics: Dynamics) -> None:
        m, robot, s = self.model, self.robot, dynamics.motor_strength
        friction = robot.ground_friction if dynamics.friction is None else dynamics.friction
        m.geom_friction[:, 0] = friction  # MuJoCo takes the larger of two geoms': set all
        m.body_mass[self._base_body] = self._nominal_mass * dynamics.base_mass_scale
        m.actuator_gainprm[:, 0] = s * robot.kp
        m.actuator_biasprm[:, 1] = -s * robot.kp
        m.actuator_biasprm[:, 2] = -s * robot.kd

    def push_base(self, velocity_xy: np.ndarray) -> None:
        if self._hung is None:
            self.data.qvel[:2] += velocity_xy

    def body_poses(self) -> BodyPoses:
        mujoco.mj_kinematics(self.model, self.data)  # xpos after mj_step lags qpos by one substep
        ids = self._robot_bodies
        return BodyPoses(self._body_names, self.data.xpos[ids].copy(), self.data.xquat[ids].copy())

    def ray_height(self, x: float, y: float) -> float:
        """Terrain height under (x, y), found by casting a ray down."""
        geomid = np.zeros(1, dtype=np.int32)
        start, top = np.array([x, y, 5.0]), 5.0
        dist = mujoco.mj_ray(self.model, self.data, start, np.array([0.0, 0.0, -1.0]), None, 1, -1, geomid)
        return top - dist

    def close(self) -> None:
        pass
