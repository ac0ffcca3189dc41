"""A cell: everything a trial depends on except its seed, checked once.

    cell = make_cell({"sim": "pybullet", "robot": "anymal", "policy": "rl"})

`CellSpec` holds engine, robot, terrain, policy and the policy's own settings, engine options
and the episode; `make_cell` builds one from flat settings (`bench run` options, an experiment's
cell, `--set`) and names what is wrong. `benchmark.trial.trials.run_cell` runs its trials.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from benchmark.common.settings import SettingError, build, check, coerce, hints, setting
from benchmark.trial.disturbances import DISTURBANCES
from benchmark.trial.registry import POLICIES, available_policies, policy_entry
from robots import load_robot
from sims import available_sims, engine, engine_options, load_entry_point, option_fields
from sims.terrain import TERRAINS, Terrain


@dataclass(frozen=True)
class CellSpec:
    """Everything one trial depends on except its seed."""

    sim: str = setting("mujoco", "physics engine", choices=available_sims, noun="simulator")
    robot: str = setting("a1", "robot: a shipped name, or a folder holding robot.toml")
    terrain: str = setting("flat", "terrain", choices=TERRAINS)
    terrain_seed: int = setting(0, "seed of the rough heightfield")
    policy: str = setting("llm", "controller (default llm: the main job)", choices=available_policies)
    duration: float | None = setting(None, "episode length in s (default: the policy's, 20 for llm, else 10)",
                                     positive=True)
    heading_hold: bool = setting(False, "steer back to the starting line through the seed policy's yaw-rate command "
                                        "(which the LLM never sees); off: the paper's protocol, the command fixed at "
                                        "the robot's (vx 1 m/s) throughout, so every example in a prompt is a "
                                        "function of what the prompt shows")
    disturbance: str = setting("none", "what happens after the takeover that the demonstrations never showed "
                                       "(weak_motors, weaker_motors, shoves; benchmark.trial.disturbances)",
                               choices=lambda: list(DISTURBANCES), added_later=True)
    engine: tuple[tuple[str, Any], ...] = ()  # the engine's own options, as (name, value) pairs
    settings: Any = None  # the policy's settings dataclass (None: the policy has none)

    def __post_init__(self) -> None:
        entry = policy_entry(self.policy)
        if self.duration is None:
            object.__setattr__(self, "duration", entry.duration)
        cls = entry.settings_class()
        if self.settings is None and cls is not None:
            object.__setattr__(self, "settings", cls())

    @property
    def eval_start(self) -> float:
        """s: metrics cover [eval_start, duration] (an LLM's takeover; 0 for the others)."""
        return float(getattr(self.settings, "eval_start", 0.0))

    @property
    def engine_options(self) -> dict:
        return dict(self.engine)

    def params(self) -> dict:
        """Flat, parquet-friendly parameters: cell fields, engine options, policy settings."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("engine", "settings")}
        out.update(self.engine)
        if self.settings is not None:
            for key, value in dataclasses.asdict(self.settings).items():
                out[key] = "+".join(value) if isinstance(value, (tuple, list)) else value
        return out

    def id_params(self) -> dict:
        """`params` as trial ids read them: a policy setting added after results were stored is left out at its
        default, so a store made before it keeps its ids (nothing reruns)."""
        later = {f.name: f.default for f in dataclasses.fields(self) if f.metadata.get("added_later")}
        if self.settings is not None:
            later.update({f.name: f.default for f in dataclasses.fields(self.settings) if f.metadata.get("added_later")})
        return {k: v for k, v in self.params().items() if not (k in later and v == later[k])}

    def label(self) -> str:
        return f"{self.sim}/{self.robot}/{self.terrain}/{self.policy}"


CELL_FIELDS = {f.name: f for f in dataclasses.fields(CellSpec) if f.name not in ("engine", "settings")}


def setting_fields() -> dict[str, dataclasses.Field]:
    """Every key a cell can be given: cell fields, every policy's settings, every engine's options."""
    out = dict(CELL_FIELDS)
    for entry in POLICIES.values():
        cls = entry.settings_class()
        if cls is not None:
            out.update({f.name: f for f in dataclasses.fields(cls)})
    out.update(option_fields())
    return out


def make_cell(values: dict, where: str = "settings", strict: bool = True) -> CellSpec:
    """A checked CellSpec from flat settings (`bench run` options, an experiment's cell, `--set`).

    Keys no policy or engine knows are an error naming the valid ones. A key that applies to
    another policy or engine is an error when `strict` (a user asked for it), and dropped
    otherwise (an experiment grid sets the LLM's history for its seed-policy cells too).
    """
    known = setting_fields()
    unknown = [k for k in values if k not in known]
    if unknown:
        raise SettingError(f"{where}: unknown setting '{unknown[0]}'; valid: {', '.join(known)}")
    base = {}
    for key in CELL_FIELDS:
        if key in values:
            base[key] = coerce(values[key], hints(CellSpec)[key], key)
            check(CELL_FIELDS[key], base[key])
    policy = base.get("policy", CELL_FIELDS["policy"].default)
    sim = base.get("sim", CELL_FIELDS["sim"].default)
    entry, record = policy_entry(policy), engine(sim)
    cls = entry.settings_class()
    mine = {f.name for f in dataclasses.fields(cls)} if cls else set()
    engine_keys = {f.name for f in dataclasses.fields(load_entry_point(record.options))} if record.options else set()
    rest = {k: v for k, v in values.items() if k not in CELL_FIELDS}
    if strict:
        for key in rest:
            if key not in mine and key not in engine_keys:
                owner = f"simulator '{sim}'" if key in option_fields() else f"policy '{policy}'"
                raise SettingError(f"{where}: '{key}' does not apply to {owner}")
    settings = build(cls, {k: v for k, v in rest.items() if k in mine}, where) if cls else None
    options = build(load_entry_point(record.options), {k: v for k, v in rest.items() if k in engine_keys}, where) \
        if record.options else None
    pairs = tuple(dataclasses.asdict(options).items()) if options else ()
    cell = CellSpec(**base, engine=pairs, settings=settings)
    validate(cell)
    return cell


def validate(cell: CellSpec) -> None:
    """Fail before anything runs on names and values a trial would trip over."""
    load_robot(cell.robot)
    Terrain(cell.terrain, seed=cell.terrain_seed)
    engine_options(cell.sim, cell.engine_options)
    if not cell.eval_start < cell.duration:
        name = getattr(cell.settings, "eval_start_setting", "eval_start")
        raise SettingError(f"{name} ({cell.eval_start:g} s) must be before the end of the episode "
                           f"(duration {cell.duration:g} s)")
    check_settings = getattr(cell.settings, "validate", None)
    if check_settings is not None:
        check_settings()
