"""Physics engines behind one Protocol (`sims.base.Simulator`), looked up by name.

Engines are imported lazily: asking for MuJoCo never imports PyBullet.
"""

from __future__ import annotations

import importlib

from robots import Robot, UnknownNameError
from sims.base import PhysicsConfig, Simulator
from sims.terrain import Terrain

SIMULATORS: dict[str, str] = {
    "mujoco": "sims.mujoco:MujocoSim",
    "newton": "sims.newton:NewtonSim",
    "pybullet": "sims.pybullet:PybulletSim",
}
TITLES: dict[str, str] = {"mujoco": "MuJoCo", "newton": "Newton", "pybullet": "PyBullet"}  # for environment ids
# Engines that step many worlds in one call: (robot, terrain, physics, worlds, device, solver).
BATCHED: dict[str, str] = {"newton": "sims.newton:NewtonWorlds"}


def available_sims() -> list[str]:
    return sorted(SIMULATORS)


def _load(path: str):
    module, cls = path.split(":")
    return getattr(importlib.import_module(module), cls)


def make_sim(name: str, robot: Robot, terrain: Terrain, physics: PhysicsConfig = PhysicsConfig(),
             device: str | None = None, solver: str | None = None) -> Simulator:
    """Build engine `name` with `robot` on `terrain`; `device`/`solver` for engines that offer a choice."""
    if name not in SIMULATORS:
        raise UnknownNameError("simulator", name, available_sims())
    return _load(SIMULATORS[name])(robot, terrain, physics, device=device, solver=solver)


def make_worlds(name: str, robot: Robot, terrain: Terrain, worlds: int, physics: PhysicsConfig = PhysicsConfig(),
                device: str | None = None, solver: str | None = None):
    """Build `worlds` copies of the robot stepped together, for engines that batch."""
    if name not in BATCHED:
        raise ValueError(f"simulator '{name}' steps one world; batched engines: {', '.join(sorted(BATCHED))}")
    return _load(BATCHED[name])(robot, terrain, physics, worlds, device=device, solver=solver)


def check_single_device(engine: str, device: str | None, solver: str | None) -> None:
    """For engines with one CPU implementation and one solver: refuse other choices clearly."""
    if device not in (None, "cpu"):
        raise ValueError(f"simulator '{engine}' runs on cpu only, not '{device}'")
    if solver is not None:
        raise ValueError(f"simulator '{engine}' has one solver; --solver applies to newton")
