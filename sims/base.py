"""The one interface every physics engine implements, and the state it returns."""

from __future__ import annotations

import contextlib
import math
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from robots import Robot
from sims.terrain import Terrain


@dataclass(frozen=True)
class PhysicsConfig:
    """Shared by every engine: the engine is the only variable in a comparison."""

    dt: float = 0.005  # s, physics and PD rate (200 Hz)
    substeps: int = 20  # physics steps per control step: 0.1 s, the 10 Hz control period
    gravity: float = -9.81
    # Frictional-to-normal impedance ratio of the MuJoCo-family solvers (MuJoCo, Newton's SolverMuJoCo).
    # At 1 (fastest) a standing ANYmal's feet creep outward and the base sinks 8 cm in 5 s; at 10 it
    # settles within 1 cm of PyBullet at about the same speed; at 100 creep stops but stepping is ~25% slower.
    impratio: float = 10.0
    # Hang the robot with its base welded in the air (joint validation, `bench validate`); the base
    # link then sits at `init_height` + `hang_height` above the terrain and the feet touch nothing.
    fixed_base: bool = False
    hang_height: float = 1.0  # m

    @property
    def control_dt(self) -> float:
        return self.dt * self.substeps


class RobotState(NamedTuple):
    """What a controller may know after a control step. Joint arrays are in canonical order.

    A NamedTuple rather than a frozen dataclass: it is built every control step, and a frozen
    dataclass's field-by-field __init__ costs several microseconds of a ~300 us step.
    """

    time: float
    base_pos: np.ndarray  # (3,) world frame, base link origin
    base_quat: np.ndarray  # (4,) w, x, y, z
    base_lin_vel: np.ndarray  # (3,) base frame
    base_ang_vel: np.ndarray  # (3,) base frame
    projected_gravity: np.ndarray  # (3,) unit gravity direction in the base frame
    joint_pos: np.ndarray  # (12,)
    joint_vel: np.ndarray  # (12,)
    joint_torque: np.ndarray  # (12,) applied at the last substep
    foot_contact: np.ndarray  # (4,) bool, FR FL RR RL
    fall_contact: bool  # a link listed in the robot's fall contact_links touches the terrain

    def is_finite(self) -> bool:
        """False if any pose or velocity entry is NaN or infinite (a sum propagates both)."""
        total = 0.0
        for array in (self.base_pos, self.base_quat, self.base_lin_vel, self.base_ang_vel, self.joint_pos,
                      self.joint_vel):
            total += float(array.sum())
        return math.isfinite(total)


@dataclass(frozen=True)
class Dynamics:
    """Physical variations an engine applies for domain randomization; defaults are nominal."""

    friction: float | None = None  # sliding friction of every robot/terrain contact; None: the robot's own
    base_mass_scale: float = 1.0  # factor on the base link's mass (payload, battery)
    motor_strength: float = 1.0  # factor on the PD torque (before the torque limit)


@dataclass(frozen=True)
class BodyPoses:
    """World poses of every robot link, for logging and viewing."""

    names: tuple[str, ...]
    positions: np.ndarray  # (n, 3)
    quats: np.ndarray  # (n, 4) w, x, y, z


class Simulator(Protocol):
    """A physics engine holding one robot on one terrain."""

    name: str

    def __init__(self, robot: Robot, terrain: Terrain, physics: PhysicsConfig = PhysicsConfig()) -> None: ...

    def reset(self, seed: int = 0) -> RobotState:
        """Default pose (joints perturbed by the seed) with the feet just above the terrain."""

    def step(self, joint_targets: np.ndarray) -> RobotState:
        """Advance one control period: `substeps` physics steps of clipped PD torque."""

    def set_dynamics(self, dynamics: Dynamics) -> None:
        """Apply friction, added mass and motor strength until the next call."""

    def push_base(self, velocity_xy: np.ndarray) -> None:
        """Add a horizontal velocity (world frame, m/s) to the base: a shove."""

    def body_poses(self) -> BodyPoses: ...

    def ray_height(self, x: float, y: float) -> float:
        """Terrain height under (x, y) as the engine's own collision model sees it (a ray cast down)."""

    def raw_loop(self, joint_targets: np.ndarray, control_steps: int) -> None:
        """The engine's bare stepping loop on the same model, as a speed reference for `bench perf`."""

    def close(self) -> None: ...


def world_to_base(quat_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix taking world vectors into the frame of quat (w, x, y, z): R^T.

    Written out in floats: numpy's cross/dot on 3-vectors cost tens of microseconds, which
    would be most of a control step's overhead.
    """
    w, x, y, z = (float(c) for c in quat_wxyz)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)],
        [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)],
        [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotate(matrix: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """matrix @ vector for a 3x3 rotation, summed in a fixed order: numpy's `@` goes through BLAS, whose
    kernel (and so the last bit) depends on the CPU (README, "Reproducibility across CPUs")."""
    return (matrix * vector).sum(axis=1)


def world_to_base_batch(quats_wxyz: np.ndarray) -> np.ndarray:
    """`world_to_base` for N quaternions at once: (N, 4) -> (N, 3, 3)."""
    w, x, y, z = np.moveaxis(np.asarray(quats_wxyz, dtype=np.float64), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=-1),
        np.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], axis=-1),
        np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def initial_joint_pos(robot: Robot, seed: int, spread: float = 0.05) -> np.ndarray:
    """The default pose with a seeded uniform perturbation (rad), so trials differ."""
    rng = np.random.default_rng(seed)
    return robot.default_pose + rng.uniform(-spread, spread, robot.num_joints)


def pd_torque(robot: Robot, targets: np.ndarray, q: np.ndarray, qd: np.ndarray, strength: float = 1.0) -> np.ndarray:
    """The 200 Hz joint PD law every engine applies, clipped to each joint's torque limit. The joint's
    own damping, friction and armature (`robot.joint_dynamics`) are the engine's to model."""
    tau = strength * (robot.kp * (targets - q) - robot.kd * qd)
    return np.clip(tau, -robot.torque_limit, robot.torque_limit)


@contextlib.contextmanager
def quiet_fds(fds: tuple[int, ...] = (1,)) -> Iterator[None]:
    """Silence file descriptors meanwhile: engines' C code prints banners (stdout would corrupt
    `--json` output) and warnings that do not apply (Warp's missing CUDA driver on a CPU run)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(fd) for fd in fds]
    with open(os.devnull, "w") as devnull:
        for fd in fds:
            os.dup2(devnull.fileno(), fd)
        try:
            yield
        finally:
            for fd, copy in zip(fds, saved):
                os.dup2(copy, fd)
                os.close(copy)
