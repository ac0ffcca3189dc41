"""Physics engines behind one Protocol (`sims.base.Simulator`), one record per engine.

Engines are imported lazily from their entry points: asking for MuJoCo never imports PyBullet.
A new engine is one module plus one line in ENGINES.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass

from robots import Robot, UnknownNameError
from sims.base import PhysicsConfig, Simulator
from sims.terrain import Terrain


@dataclass(frozen=True)
class Engine:
    """What the rest of promptwalk knows about an engine, without importing it."""

    name: str
    title: str  # for tables and Gymnasium ids
    entry_point: str  # "module:Class" of its Simulator
    packages: tuple[str, ...]  # distributions whose versions a result row records
    batched: str | None = None  # "module:Class" stepping many worlds in one call, if any
    options: str | None = None  # "module:Dataclass" of the engine's own options (device, solver ...)


ENGINES: dict[str, Engine] = {e.name: e for e in (
    Engine("mujoco", "MuJoCo", "sims.mujoco:MujocoSim", ("mujoco",)),
    Engine("newton", "Newton", "sims.newton:NewtonSim", ("newton", "warp-lang", "mujoco-warp"),
           batched="sims.newton:NewtonWorlds", options="sims.newton_options:NewtonOptions"),
    Engine("pybullet", "PyBullet", "sims.pybullet:PybulletSim", ("pybullet",)),
)}


def load_entry_point(path: str):
    """The object named by a Gymnasium-style entry point, "package.module:Name"."""
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def available_sims() -> list[str]:
    return sorted(ENGINES)


def engine(name: str) -> Engine:
    if name not in ENGINES:
        raise UnknownNameError("simulator", name, available_sims())
    return ENGINES[name]


def option_fields() -> dict[str, dataclasses.Field]:
    """Every engine option by name (for the CLI and experiment files): {name: field}."""
    out = {}
    for record in ENGINES.values():
        if record.options:
            out.update({f.name: f for f in dataclasses.fields(load_entry_point(record.options))})
    return out


def engine_options(name: str, options: dict | None = None):
    """Engine `name`'s options object built from `options`; a key it does not take is one clear error."""
    record, options = engine(name), dict(options or {})
    if record.options is None:
        if options:
            raise ValueError(f"option '{next(iter(options))}' does not apply to simulator '{name}'; "
                             f"engines with options: {', '.join(n for n, e in ENGINES.items() if e.options)}")
        return None
    cls = load_entry_point(record.options)
    valid = [f.name for f in dataclasses.fields(cls)]
    unknown = [k for k in options if k not in valid]
    if unknown:
        raise ValueError(f"option '{unknown[0]}' does not apply to simulator '{name}'; valid: {', '.join(valid)}")
    return cls(**options)


def make_sim(name: str, robot: Robot, terrain: Terrain, physics: PhysicsConfig = PhysicsConfig(),
             options: dict | None = None) -> Simulator:
    """Build engine `name` with `robot` on `terrain`; `options` only for engines that take them."""
    opts = engine_options(name, options)
    cls = load_entry_point(engine(name).entry_point)
    return cls(robot, terrain, physics) if opts is None else cls(robot, terrain, physics, opts)


def make_worlds(name: str, robot: Robot, terrain: Terrain, worlds: int, physics: PhysicsConfig = PhysicsConfig(),
                options: dict | None = None):
    """Build `worlds` copies of the robot stepped together, for engines that batch."""
    record = engine(name)
    if record.batched is None:
        batched = ", ".join(n for n, e in ENGINES.items() if e.batched)
        raise ValueError(f"simulator '{name}' steps one world; batched engines: {batched}")
    return load_entry_point(record.batched)(robot, terrain, physics, worlds, engine_options(name, options))
