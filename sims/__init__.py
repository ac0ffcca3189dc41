"""Physics engines behind one Protocol (`sims.base.Simulator`), one record per engine.

Engines are imported lazily from their entry points: asking for MuJoCo never imports PyBullet.
A new engine is one module plus one line in ENGINES, or, from another installed package, one
`Engine` record named in its `promptwalk.engines` entry-point group (`PluginTable`).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

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


def load_entry_point(path: str):
    """The object named by a Gymnasium-style entry point, "package.module:Name"."""
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


class PluginTable(Mapping):
    """A registry: the built-in records, then those other installed packages add through an entry-point group
    (`importlib.metadata`, as pytest and Gymnasium plugins are found), read on first use. `record` turns an
    entry point into the table's value (default: the object it names, which must be a `kind` with that name)."""

    def __init__(self, builtin: dict[str, Any], group: str, noun: str, kind: type | None = None,
                 record: Callable[[importlib.metadata.EntryPoint], Any] | None = None) -> None:
        self.builtin, self.group, self.noun, self.kind = dict(builtin), group, noun, kind
        self._record = record or self._named_object
        self._table: dict[str, Any] | None = None

    def _named_object(self, point: importlib.metadata.EntryPoint) -> Any:
        obj = point.load()
        if self.kind is not None and not isinstance(obj, self.kind):
            raise TypeError(f"it names a {type(obj).__name__}, not a {self.kind.__name__}")
        if getattr(obj, "name", point.name) != point.name:
            raise TypeError(f"its record is named '{obj.name}'")
        return obj

    def names(self) -> list[str]:
        return sorted(self._all())

    def get_named(self, name: str) -> Any:
        """The record of `name`, or the one-line error that lists the valid names."""
        if name not in self._all():
            raise UnknownNameError(self.noun, name, self.names())
        return self._all()[name]

    def plugins(self) -> dict[str, Any]:
        """{name: value} of the entry points alone."""
        return {name: value for name, value in self._all().items() if name not in self.builtin}

    def _all(self) -> dict[str, Any]:
        if self._table is None:
            table = dict(self.builtin)
            for point in importlib.metadata.entry_points(group=self.group):
                where = f"plugin {self.noun} '{point.name}' ({point.value}, entry-point group {self.group})"
                if point.name in table:
                    raise ValueError(f"{where} takes the name of a built-in {self.noun}; rename it")
                try:
                    table[point.name] = self._record(point)
                except Exception as err:  # a broken plugin is one line naming it, not a traceback
                    raise ValueError(f"{where} does not load: {type(err).__name__}: {err}") from None
            self._table = table
        return self._table

    def __getitem__(self, name: str) -> Any:
        return self._all()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())


ENGINES: PluginTable = PluginTable({e.name: e for e in (
    Engine("mujoco", "MuJoCo", "sims.mujoco:MujocoSim", ("mujoco",)),
    Engine("newton", "Newton", "sims.newton:NewtonSim", ("newton", "warp-lang", "mujoco-warp"),
           batched="sims.newton:NewtonWorlds", options="sims.newton_options:NewtonOptions"),
    Engine("pybullet", "PyBullet", "sims.pybullet:PybulletSim", ("pybullet",)),
)}, "promptwalk.engines", "simulator", kind=Engine)


def available_sims() -> list[str]:
    return ENGINES.names()


def engine(name: str) -> Engine:
    return ENGINES.get_named(name)


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
