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
    "pybullet": "sims.pybullet:PybulletSim",
}


def available_sims() -> list[str]:
    return sorted(SIMULATORS)


def make_sim(name: str, robot: Robot, terrain: Terrain, physics: PhysicsConfig = PhysicsConfig()) -> Simulator:
    """Build engine `name` with `robot` on `terrain`."""
    if name not in SIMULATORS:
        raise UnknownNameError("simulator", name, available_sims())
    module, cls = SIMULATORS[name].split(":")
    return getattr(importlib.import_module(module), cls)(robot, terrain, physics)
