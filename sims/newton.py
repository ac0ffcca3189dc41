"""Newton backend (warp-lang), on CPU or CUDA, stepping many worlds at once.

`NewtonWorlds` holds N copies of the robot (one per world, independent seeds) on one shared
terrain and steps them in one solver call; `NewtonSim` is the one-world `Simulator`.
Solvers (`--solver`): `mujoco` (default; Newton's SolverMuJoCo on mujoco_warp) and `featherstone`
(faster, but went to NaN on heightfields here). Contacts (`--contacts`): `newton` (default; Newton's
own CollisionPipeline runs before every substep and hands its contacts to the solver) or `mujoco`
(mujoco_warp's own narrow phase, which on heightfields fills its per-pair buffer with prisms not in
contact and drops the feet: mujoco_warp issue #1083). The PD law runs inside the solver as joint
target stiffness/damping with each joint's torque limit as its effort limit; the robot's armature,
damping and Coulomb friction are Newton's joint attributes; contact settings match the MuJoCo
backend (implicitfast, pyramidal cone, impratio 10, self-collision off). Warp compiles its kernels on first use (30-90 s on
CPU) into ~/.cache/warp; later runs load them in seconds.
"""

from __future__ import annotations

import sys
import time
import warnings
from collections.abc import Sequence

import numpy as np

from robots import Robot
from sims.base import (BodyPoses, Dynamics, PhysicsConfig, RobotState, initial_joint_pos, pd_torque, quiet_fds,
                        world_to_base_batch)
from sims.newton_options import NewtonOptions
from sims.terrain import Terrain

# Contact and constraint-row room per world in mujoco_warp. Newton's own pipeline reports up to ~200
# contacts for A1 on the rough heightfield (triangle pairs within the detection gap); at 200 the
# buffer overflowed and dropped some (mujoco_warp printed "Increase nconmax"), so there is room for 2x.
NCONMAX, NJMAX = 400, 1600


def default_device() -> str:
    wp = _quiet_warp()
    return "cuda" if wp.is_cuda_available() else "cpu"


def _quiet_warp():
    """Warp logs every kernel module it loads; keep warnings, drop the chatter."""
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    with quiet_fds((2,)):  # on a machine without CUDA, Warp's C code warns once at init; CPU runs do not care
        wp.init()
    return wp


class NewtonWorlds:
    """N worlds, one robot each, stepped together."""

    def __init__(self, robot: Robot, terrain: Terrain, physics: PhysicsConfig = PhysicsConfig(), worlds: int = 1,
                 options: NewtonOptions | None = None) -> None:
        options = options or NewtonOptions()
        device, solver = options.device, options.solver
        wp = _quiet_warp()
        import newton

        if device is not None and device.startswith("cuda") and not wp.is_cuda_available():
            raise ValueError(f"device '{device}' requested but no CUDA device is available; valid: cpu")

        self.robot, self.terrain, self.physics, self.worlds = robot, terrain, physics, worlds
        self.device = device or default_device()
        started = time.perf_counter()
        print(f"newton: building {worlds} world(s) on {self.device} with {solver} "
              "(first use compiles warp kernels, 30-90 s on CPU; cached afterwards)", file=sys.stderr)
        one = newton.ModelBuilder()
        newton.solvers.SolverMuJoCo.register_custom_attributes(one)
        one.default_shape_cfg.mu = robot.ground_friction
        height = robot.init_height + (physics.hang_height if physics.fixed_base else 0.0)
        one.add_urdf(str(robot.urdf), xform=wp.transform(wp.vec3(0.0, 0.0, height), wp.quat_identity()),
                     floating=not physics.fixed_base, enable_self_collisions=False, collapse_fixed_joints=False,
                     joint_damping_mode="passive")
        names = [label.split("/")[-1] for label in one.joint_label]
        self._q_idx = np.array([one.joint_q_start[names.index(j)] for j in robot.joints])
        self._qd_idx = np.array([one.joint_qd_start[names.index(j)] for j in robot.joints])
        jd = robot.joint_dynamics
        for i, dof in enumerate(self._qd_idx):
            one.joint_target_ke[dof], one.joint_target_kd[dof] = robot.kp, robot.kd
            one.joint_effort_limit[dof] = robot.torque_limit[i]
            one.joint_armature[dof], one.joint_damping[dof] = jd.armature[i], jd.damping[i]
            one.joint_friction[dof] = jd.friction[i]
        bodies = [label.split("/")[-1] for label in one.body_label]
        self._body_names = tuple(bodies)
        self._bodies_per_world = len(bodies)
        self._coords, self._dofs = one.joint_coord_count, one.joint_dof_count

        scene = newton.ModelBuilder()
        newton.solvers.SolverMuJoCo.register_custom_attributes(scene)
        scene.default_shape_cfg.mu = robot.ground_friction
        scene.replicate(one, worlds)
        self._add_terrain(scene, newton, wp)
        scene.gravity = (0.0, 0.0, physics.gravity)
        self.model = scene.finalize(device=self.device)
        if solver == "mujoco":
            with warnings.catch_warnings():  # mujoco_warp raises nconmax for heightfields and says so
                warnings.filterwarnings("ignore", message=".*Value for nconmax is changed")
                self.solver = newton.solvers.SolverMuJoCo(
                    self.model, use_mujoco_contacts=options.contacts == "mujoco", nconmax=NCONMAX, njmax=NJMAX,
                    cone="pyramidal", impratio=physics.impratio, integrator="implicitfast")
        else:
            self.solver = newton.solvers.SolverFeatherstone(self.model)
        self.pipeline = self.contacts = None
        if options.contacts == "newton" or solver != "mujoco":
            self.pipeline = newton.CollisionPipeline(self.model, rigid_contact_max=self._max_contacts(),
                                                     soft_contact_max=0)
            self.contacts = self.pipeline.contacts()
        self._state, self._next = self.model.state(), self.model.state()
        self.control = self.model.control()
        self._com = self.model.body_com.numpy()[0].astype(np.float64)  # base COM in the base frame
        self._shape_body = self.model.shape_body.numpy()
        self._shape_margin = self.model.shape_margin.numpy()
        self._geom_shape = getattr(self.solver, "mjc_geom_to_newton_shape", None)
        shape_body = self._shape_body
        foot_bodies = [bodies.index(f) for f in robot.foot_links]
        fall_bodies = [bodies.index(b) for b in robot.fall.contact_links]
        local_body = np.where(shape_body >= 0, shape_body % self._bodies_per_world, -1)
        self._shape_world = np.where(shape_body >= 0, shape_body // self._bodies_per_world, -1)
        self._shape_foot = np.full(len(shape_body), -1)
        for leg, body in enumerate(foot_bodies):
            self._shape_foot[local_body == body] = leg
        self._shape_falls = np.isin(local_body, fall_bodies) & (shape_body >= 0)
        self._strength = np.ones(worlds)
        self._nominal_base_mass = float(self.model.body_mass.numpy()[0])
        self._targets = np.tile(robot.default_pose, (worlds, 1))
        self.time = 0.0
        self._wp, self._graph, self._use_graph = wp, None, False
        self.reset(range(worlds))
        self.step(self._targets)  # the first step compiles the solver's kernels
        # On CUDA a control period is captured once as a CUDA graph and replayed: one launch
        # instead of thousands of kernel launches from Python (needs warp's memory pool).
        device = wp.get_device(self.device)
        self._use_graph = device.is_cuda and wp.is_mempool_enabled(device)
        print(f"newton: ready in {time.perf_counter() - started:.1f} s", file=sys.stderr)

    def _max_contacts(self) -> int:
        """Room for every world's contacts: SolverMuJoCo's own buffer size, or 64 a world."""
        count = getattr(self.solver, "get_max_contact_count", None)
        return int(count()) if count is not None else 64 * self.worlds

    def _add_terrain(self, scene, newton, wp) -> None:
        t = self.terrain
        if t.is_flat:
            scene.add_ground_plane()
            return
        heights = t.heights
        rows, cols = heights.shape
        field = newton.Heightfield(data=heights, nrow=rows, ncol=cols, hx=t.size[0] / 2, hy=t.size[1] / 2,
                                   min_z=float(heights.min()), max_z=float(heights.max()))
        scene.add_shape_heightfield(xform=wp.transform(wp.vec3(*t.center, 0.0), wp.quat_identity()),
                                    heightfield=field)

    # -- batch interface -------------------------------------------------------------------
    def reset(self, seeds: Sequence[int]) -> None:
        import newton

        seeds = list(seeds)
        q = self.model.joint_q.numpy().reshape(self.worlds, self._coords).astype(np.float64)
        if not self.physics.fixed_base:
            z = self.robot.init_height + self.terrain.height_at(0.0, 0.0)
            q[:, :3] = [0.0, 0.0, z]
            q[:, 3:7] = [0.0, 0.0, 0.0, 1.0]  # x, y, z, w
        for w, seed in enumerate(seeds):
            q[w, self._q_idx] = initial_joint_pos(self.robot, seed)
        self._state.joint_q.assign(q.ravel().astype(np.float32))
        self._state.joint_qd.zero_()
        newton.eval_fk(self.model, self._state.joint_q, self._state.joint_qd, self._state)
        self._targets = np.tile(self.robot.default_pose, (self.worlds, 1))
        self._write_targets(self._targets)
        self.time = 0.0

    def _write_targets(self, targets: np.ndarray) -> None:
        full = np.zeros((self.worlds, self._coords), dtype=np.float32)
        full[:, self._q_idx] = targets
        self.control.joint_target_q.assign(full.ravel())

    def step(self, targets: np.ndarray) -> None:
        """Advance every world one control period; `targets` is (worlds, 12), canonical order."""
        self._targets = np.asarray(targets, dtype=np.float64).reshape(self.worlds, -1)
        self._write_targets(self._targets)
        self._control_period()
        self.time += self.physics.control_dt

    def _control_period(self) -> None:
        """`substeps` solver steps, replayed from a CUDA graph where one can be used."""
        wp = self._wp
        if self._graph is not None:
            wp.capture_launch(self._graph)
        elif self._use_graph:
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                self._solver_steps()
            self._graph = capture.graph
            wp.capture_launch(self._graph)
        else:
            self._solver_steps()

    def _solver_steps(self) -> None:
        first = self._state
        for _ in range(self.physics.substeps):
            if self.pipeline is not None:
                self.pipeline.collide(self._state, self.contacts)
            self.solver.step(self._state, self._next, self.control, self.contacts, self.physics.dt)
            self._state, self._next = self._next, self._state
        if self._state is not first:  # odd substeps: end in the buffer we began in, so a replay can follow
            first.assign(self._state)
            self._state, self._next = first, self._state

    def set_dynamics(self, dynamics: Dynamics) -> None:
        """Friction, base mass and motor strength for every world (domain randomization)."""
        import newton

        model = self.model
        mu = model.shape_material_mu.numpy()
        mu[:] = self.robot.ground_friction if dynamics.friction is None else dynamics.friction
        model.shape_material_mu.assign(mu)
        mass = model.body_mass.numpy()
        base = np.arange(self.worlds) * self._bodies_per_world
        mass[base] = self._nominal_base_mass * dynamics.base_mass_scale
        model.body_mass.assign(mass)
        inv_mass = model.body_inv_mass.numpy()
        inv_mass[base] = 1.0 / mass[base]
        model.body_inv_mass.assign(inv_mass)
        dofs = (np.arange(self.worlds)[:, None] * self._dofs + self._qd_idx[None]).ravel()
        for array, gain in ((model.joint_target_ke, self.robot.kp), (model.joint_target_kd, self.robot.kd)):
            values = array.numpy()
            values[dofs] = gain * dynamics.motor_strength
            array.assign(values)
        self._strength[:] = dynamics.motor_strength
        flags = newton.ModelFlags
        self.solver.notify_model_changed(flags.SHAPE_PROPERTIES | flags.BODY_INERTIAL_PROPERTIES
                                         | flags.JOINT_DOF_PROPERTIES)
        self._graph = None  # recapture against whatever the solver re-uploaded

    def push_base(self, velocity_xy: np.ndarray) -> None:
        """Add a horizontal velocity to every world's base."""
        if self.physics.fixed_base:
            return
        qd = self._state.joint_qd.numpy().reshape(self.worlds, self._dofs)
        qd[:, :2] += np.asarray(velocity_xy, dtype=np.float32)
        self._state.joint_qd.assign(qd.ravel())

    def raw_loop(self, targets: np.ndarray, control_steps: int) -> None:
        """The bare solver loop on the same model, as the speed reference for `bench perf`."""
        self._write_targets(np.asarray(targets, dtype=np.float64).reshape(self.worlds, -1))
        for _ in range(control_steps):
            self._control_period()

    def states(self) -> list[RobotState]:
        """The RobotState of every world."""
        all_body_q = self._state.body_q.numpy().astype(np.float64)  # read once: contacts need every body's pose
        body_q = all_body_q.reshape(self.worlds, self._bodies_per_world, 7)[:, 0]
        body_qd = self._state.body_qd.numpy().reshape(self.worlds, self._bodies_per_world, 6)[:, 0].astype(np.float64)
        q = self._state.joint_q.numpy().reshape(self.worlds, self._coords)[:, self._q_idx].astype(np.float64)
        qd = self._state.joint_qd.numpy().reshape(self.worlds, self._dofs)[:, self._qd_idx].astype(np.float64)
        feet, falls = self._contacts(all_body_q)
        quat = body_q[:, [6, 3, 4, 5]]  # x, y, z, w -> w, x, y, z
        to_base = world_to_base_batch(quat)
        omega = body_qd[:, 3:]
        com_world = np.einsum("nji,j->ni", to_base, self._com)  # R @ com, with R = to_base^T
        v_origin = body_qd[:, :3] - np.cross(omega, com_world)  # COM velocity -> origin
        lin_vel = np.einsum("nij,nj->ni", to_base, v_origin)
        ang_vel = np.einsum("nij,nj->ni", to_base, omega)
        torque = pd_torque(self.robot, self._targets, q, qd, self._strength[:, None])
        return [RobotState(time=self.time, base_pos=body_q[w, :3], base_quat=quat[w], base_lin_vel=lin_vel[w],
                           base_ang_vel=ang_vel[w], projected_gravity=-to_base[w, :, 2], joint_pos=q[w],
                           joint_vel=qd[w], joint_torque=torque[w], foot_contact=feet[w],
                           fall_contact=bool(falls[w]))
                for w in range(self.worlds)]

    def _contacts(self, body_q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which feet of each world touch the terrain, and whether a fall link does."""
        feet = np.zeros((self.worlds, len(self.robot.foot_links)), dtype=bool)
        falls = np.zeros(self.worlds, dtype=bool)
        if self.contacts is not None:
            s1, s2 = self._newton_contacts(body_q)
        else:
            s1, s2 = self._mujoco_contacts()
        # the robot's shape in a robot-terrain pair (terrain shapes belong to no world);
        # robot-against-robot pairs are not contacts with the terrain
        robot_shape = np.where(self._shape_world[s1] < 0, s2, np.where(self._shape_world[s2] < 0, s1, -1))
        robot_shape = robot_shape[robot_shape >= 0]
        leg, world = self._shape_foot[robot_shape], self._shape_world[robot_shape]
        feet[world[leg >= 0], leg[leg >= 0]] = True
        falls[world[self._shape_falls[robot_shape]]] = True
        return feet, falls

    def _newton_contacts(self, body_q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shape pairs touching (surface separation <= 0) in Newton's own contact buffer, which
        also holds pairs within the detection gap."""
        c = self.contacts
        count = int(c.rigid_contact_count.numpy()[0])
        s0, s1 = c.rigid_contact_shape0.numpy()[:count], c.rigid_contact_shape1.numpy()[:count]

        def to_world(shape: np.ndarray, point: np.ndarray) -> np.ndarray:
            body = self._shape_body[shape]
            pose = body_q[np.maximum(body, 0)]
            x, y, z, w = pose[:, 3], pose[:, 4], pose[:, 5], pose[:, 6]
            rot = world_to_base_batch(np.stack([w, x, y, z], axis=1))  # world -> body; its transpose rotates out
            moved = np.einsum("nji,nj->ni", rot, point) + pose[:, :3]
            return np.where((body >= 0)[:, None], moved, point)  # static shapes: points are in the world frame

        p0 = to_world(s0, c.rigid_contact_point0.numpy()[:count].astype(np.float64))
        p1 = to_world(s1, c.rigid_contact_point1.numpy()[:count].astype(np.float64))
        normal = c.rigid_contact_normal.numpy()[:count]
        thickness = (c.rigid_contact_margin0.numpy()[:count] - self._shape_margin[s0]
                     + c.rigid_contact_margin1.numpy()[:count] - self._shape_margin[s1])
        touching = np.einsum("ni,ni->n", normal, p1 - p0) - thickness <= 0.0
        return s0[touching], s1[touching]

    def _mujoco_contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """Shape pairs touching in mujoco_warp's contact list (`--contacts mujoco`)."""
        none = np.zeros(0, dtype=np.int64)
        data = getattr(self.solver, "mjw_data", None)
        if data is None or self._geom_shape is None:
            return none, none
        count = int(data.nacon.numpy()[0])
        if count == 0:
            return none, none
        touching = data.contact.dist.numpy()[:count] <= 0.0  # the list also holds pairs within the margin
        geoms = data.contact.geom.numpy()[:count][touching]
        worlds = data.contact.worldid.numpy()[:count][touching]
        geom_shape = self._geom_shape.numpy()  # (worlds, geoms) -> shape index, -1 for none
        s1, s2 = geom_shape[worlds, geoms[:, 0]], geom_shape[worlds, geoms[:, 1]]
        both = (s1 >= 0) & (s2 >= 0)
        return s1[both], s2[both]

    def body_poses(self, world: int = 0) -> BodyPoses:
        body_q = self._state.body_q.numpy().reshape(self.worlds, self._bodies_per_world, 7)[world].astype(np.float64)
        return BodyPoses(self._body_names, body_q[:, :3].copy(), body_q[:, [6, 3, 4, 5]].copy())


class NewtonSim:
    """One robot on one terrain in Newton: the `Simulator` protocol over a one-world NewtonWorlds."""

    name = "newton"

    def __init__(self, robot: Robot, terrain: Terrain, physics: PhysicsConfig = PhysicsConfig(),
                 options: NewtonOptions | None = None) -> None:
        self.robot, self.terrain, self.physics = robot, terrain, physics
        self.worlds = NewtonWorlds(robot, terrain, physics, 1, options)

    def reset(self, seed: int = 0) -> RobotState:
        self.worlds.reset([seed])
        return self.worlds.states()[0]

    def step(self, joint_targets: np.ndarray) -> RobotState:
        self.worlds.step(np.asarray(joint_targets)[None])
        return self.worlds.states()[0]

    def raw_loop(self, joint_targets: np.ndarray, control_steps: int) -> None:
        self.worlds.raw_loop(np.asarray(joint_targets)[None], control_steps)

    def set_dynamics(self, dynamics: Dynamics) -> None:
        self.worlds.set_dynamics(dynamics)

    def push_base(self, velocity_xy: np.ndarray) -> None:
        self.worlds.push_base(velocity_xy)

    def body_poses(self) -> BodyPoses:
        return self.worlds.body_poses(0)

    def ray_height(self, x: float, y: float) -> float:
        """Terrain height under (x, y) in the MuJoCo model Newton's solver built."""
        import mujoco

        model = self.worlds.solver.mj_model
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        geomid = np.zeros(1, dtype=np.int32)
        dist = mujoco.mj_ray(model, data, np.array([x, y, 5.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geomid)
        return 5.0 - dist

    def close(self) -> None:
        pass
