"""Robot descriptions as data: one folder per robot with a `robot.toml` and a URDF.

Everything an engine, a policy or a prompt needs to know about a robot is read from here;
no other module branches on a robot's name. A robot is named (a folder of this package, or one
that another installed package names in its `promptwalk.robots` entry-point group) or given as the
path of any folder holding a `robot.toml`: bring your own without editing the package.
"""

from __future__ import annotations

import importlib.metadata
import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

ROBOTS_DIR = Path(__file__).parent
LEGS = ("FR", "FL", "RR", "RL")
JOINT_ROLES = ("hip", "thigh", "calf")
CANONICAL_JOINTS = tuple(f"{leg}_{role}" for leg in LEGS for role in JOINT_ROLES)


class UnknownNameError(ValueError):
    """A name (robot, simulator, terrain, policy) that is not registered."""

    def __init__(self, kind: str, name: str, valid: list[str] | tuple[str, ...]):
        super().__init__(f"unknown {kind} '{name}'; valid: {', '.join(sorted(valid))}")


@dataclass(frozen=True)
class ObservationScales:
    lin_vel: float
    ang_vel: float
    joint_pos: float
    joint_vel: float


@dataclass(frozen=True)
class FallCriteria:
    min_height: float
    max_tilt_deg: float
    contact_links: tuple[str, ...]


@dataclass(frozen=True)
class JointDynamics:
    """What a real joint adds to ideal PD, per joint in canonical order (from the official descriptions)."""

    armature: np.ndarray  # kg m^2, reflected rotor inertia added to the joint's own inertia
    damping: np.ndarray  # N m s / rad, viscous, on top of the PD law's Kd
    friction: np.ndarray  # N m, Coulomb friction (MuJoCo's frictionloss)


@dataclass(frozen=True)
class Robot:
    """A legged robot: its model file and the control facts every engine shares."""

    name: str
    title: str
    urdf: Path
    base_link: str
    joints: tuple[str, ...]  # native names in canonical order
    foot_links: tuple[str, ...]  # canonical leg order
    default_pose: np.ndarray
    kp: float
    kd: float
    torque_limit: np.ndarray  # (12,) N m, canonical order
    action_scale: float
    init_height: float
    command: np.ndarray
    obs_scales: ObservationScales
    fall: FallCriteria
    joint_dynamics: JointDynamics
    ground_friction: float  # sliding friction of foot/terrain contacts at nominal physics

    @property
    def folder(self) -> Path:
        """The robot's folder: robot.toml, the URDF, the shipped seed policy."""
        return self.urdf.parent

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    def targets_from_actions(self, actions: np.ndarray) -> np.ndarray:
        """Joint targets for normalized actions: default pose + action_scale * action."""
        return self.default_pose + self.action_scale * np.asarray(actions, dtype=float)


def per_joint(value: float | list[float], num_joints: int = len(CANONICAL_JOINTS)) -> np.ndarray:
    """A figure given once, per joint role (hip, thigh, calf) or per joint, as one value per joint."""
    values = np.atleast_1d(np.asarray(value, dtype=float))
    if values.size in (1, len(JOINT_ROLES)):
        return np.tile(values, num_joints // values.size)
    if values.size != num_joints:
        raise ValueError(f"expected 1, {len(JOINT_ROLES)} (hip, thigh, calf) or {num_joints} values, got {values.size}")
    return values


ROBOT_PLUGINS = "promptwalk.robots"  # entry-point group: name -> "module:FOLDER", a folder holding robot.toml


def plugin_robots() -> dict[str, Path]:
    """{name: folder} of the robots other installed packages register."""
    out = {}
    for point in importlib.metadata.entry_points(group=ROBOT_PLUGINS):
        try:
            out[point.name] = Path(point.load())
        except Exception as err:  # a broken plugin is one line naming it
            raise ValueError(f"plugin robot '{point.name}' ({point.value}, entry-point group {ROBOT_PLUGINS}) does "
                             f"not load: {type(err).__name__}: {err}") from None
    return out


def available_robots() -> list[str]:
    return sorted({*(p.parent.name for p in ROBOTS_DIR.glob("*/robot.toml")), *plugin_robots()})


@cache
def load_robot(name: str) -> Robot:
    """Read `robots/<name>/robot.toml`, or `<name>/robot.toml` for a folder path; raises
    UnknownNameError or ValueError on bad data."""
    folder = Path(name) if ("/" in name or name.startswith(".")) else ROBOTS_DIR / name
    if not (folder / "robot.toml").is_file() and folder.parent == ROBOTS_DIR:
        folder = plugin_robots().get(name, folder)
    path = folder / "robot.toml"
    if not path.is_file():
        if folder.parent != ROBOTS_DIR and name not in plugin_robots():
            raise UnknownNameError("robot", name, [*available_robots(), "or a folder holding robot.toml"])
        raise UnknownNameError("robot", name, available_robots())
    with path.open("rb") as f:
        data = tomllib.load(f)
    try:
        robot = Robot(
            name=data["name"],
            title=data["title"],
            urdf=path.parent / data["urdf"],
            base_link=data["base_link"],
            joints=tuple(data["joints"]),
            foot_links=tuple(data["foot_links"]),
            default_pose=np.array(data["default_pose"], dtype=float),
            kp=float(data["kp"]),
            kd=float(data["kd"]),
            torque_limit=per_joint(data["torque_limit"]),
            action_scale=float(data["action_scale"]),
            init_height=float(data["init_height"]),
            command=np.array(data["command"], dtype=float),
            obs_scales=ObservationScales(**data["obs_scales"]),
            fall=FallCriteria(
                min_height=float(data["fall"]["min_height"]),
                max_tilt_deg=float(data["fall"]["max_tilt_deg"]),
                contact_links=tuple(data["fall"]["contact_links"]),
            ),
            joint_dynamics=JointDynamics(**{k: per_joint(data["joint_dynamics"][k])
                                            for k in ("armature", "damping", "friction")}),
            ground_friction=float(data["ground_friction"]),
        )
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path}: missing or malformed field {err}") from err
    if len(robot.joints) != len(CANONICAL_JOINTS) or len(robot.default_pose) != len(robot.joints):
        raise ValueError(f"{path}: expected {len(CANONICAL_JOINTS)} joints and default pose values")
    if len(robot.foot_links) != len(LEGS):
        raise ValueError(f"{path}: expected {len(LEGS)} foot links")
    if not robot.urdf.is_file():
        raise ValueError(f"{path}: URDF {robot.urdf} not found")
    return robot
