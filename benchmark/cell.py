"""A cell and its trials: the one path from a description to results.

    cell = make_cell({"sim": "pybullet", "robot": "anymal", "policy": "rl"})
    results = run_cell(cell, seeds=range(5))

`CellSpec` is everything a trial depends on except its seed: engine, robot, terrain, policy
and the policy's own settings, engine options and the episode. `run_cell` builds robot,
terrain, engine and policy, runs the trials and returns their results; `bench run`, sweep
workers, `bench latency`, `bench prompt` and training's evaluations all call it. `Resources`
keeps engines and models alive between calls (a sweep worker holds one).
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from benchmark.llm.models import DEFAULT_DRAFT, DRAFTS
from benchmark.policies import POLICIES, Policy, available_policies, build_policy, policy_entry
from benchmark.runner import EpisodeConfig, StepCallback, TrialResult, run_trial
from benchmark.settings import SettingError, build, check, coerce, hints, setting
from robots import Robot, load_robot
from sims import available_sims, engine, engine_options, load_entry_point, make_sim, option_fields
from sims.base import Simulator
from sims.terrain import TERRAINS, Terrain

MAX_CACHED_SIMS = 4


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


@dataclass(frozen=True)
class Runtime:
    """How trials run, not what they measure: never part of a cell's identity."""

    threads: int | None = setting(None, "llama.cpp threads (default: all cores, or cores / workers in a sweep)",
                                  positive=True)
    draft: str = setting(DEFAULT_DRAFT, "embedded models: speculative decoding. ngram drafts the reply from token "
                                  "n-grams already in the prompt (llama.cpp's ngram-simple: replies repeat the "
                                  "history's numbers) and checks the draft in one batch; none decodes token by token",
                         choices=DRAFTS)
    cache: bool = True  # the on-disk LLM reply cache
    requests_per_minute: float | None = None  # remote LLM servers: at most this many queries a minute
    price_in: float | None = setting(None, "USD per 1M input tokens, for a cost estimate", minimum=0)
    price_out: float | None = setting(None, "USD per 1M output tokens", minimum=0)
    price_cached_in: float | None = setting(None, "USD per 1M cached input tokens (default: --price-in)", minimum=0)


class Resources:
    """Engines and models kept between trials (a sweep worker's state); closed together. Threads that
    run trials side by side each hold their own Resources (engines are not thread-safe) over one
    `shared` model table, so they talk to a server through one client and one rate limit."""

    def __init__(self, runtime: Runtime = Runtime(), shared: SharedModels | None = None) -> None:
        self.runtime = runtime
        self.sims: dict[tuple, Simulator] = {}
        self.shared = shared
        self.models: dict[tuple, Any] = shared.models if shared else {}

    @staticmethod
    def _sim_key(cell: CellSpec) -> tuple:
        return cell.sim, cell.robot, cell.terrain, cell.terrain_seed, cell.engine

    def use_sim(self, cell: CellSpec, sim: Simulator) -> None:
        """Run `cell`'s trials in this engine instance (e.g. one wrapped to record every substep)."""
        self.sims[self._sim_key(cell)] = sim

    def sim(self, cell: CellSpec, robot: Robot, terrain: Terrain) -> Simulator:
        key = self._sim_key(cell)
        if key not in self.sims:
            if len(self.sims) >= MAX_CACHED_SIMS:
                self.sims.pop(next(iter(self.sims))).close()
            self.sims[key] = make_sim(cell.sim, robot, terrain, options=cell.engine_options)
        return self.sims[key]

    def model(self, key: tuple, factory: Callable[[], Any]):
        """A model kept for the life of these resources (or of the shared table), built on first use."""
        with self.shared.lock if self.shared else contextlib.nullcontext():
            if key not in self.models:
                self.models[key] = factory()
            return self.models[key]

    def close(self) -> None:
        for sim in self.sims.values():
            sim.close()
        self.sims.clear()
        if self.shared is None:  # a shared table is closed by its owner
            for model in self.models.values():
                model.close()
            self.models.clear()


@dataclass
class SharedModels:
    """Models shared by threads running trials side by side."""

    models: dict = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def close(self) -> None:
        for model in self.models.values():
            model.close()
        self.models.clear()


class TrialHooks:
    """Watch trials as they run: `start` may return a per-step callback; `end` sees the result."""

    def start(self, seed: int, sim: Simulator, policy: Policy, episode: EpisodeConfig) -> StepCallback | None:
        return None

    def end(self, seed: int, result: TrialResult) -> None:
        pass


class KeepPolicy(TrialHooks):
    """Keeps the policy of the last trial, to read what it saw afterwards (queries, the last prompt)."""

    def start(self, seed: int, sim: Simulator, policy: Policy, episode: EpisodeConfig) -> None:
        self.policy = policy


def run_cell(cell: CellSpec, seeds: Iterable[int], resources: Resources | None = None,
             hooks: Sequence[TrialHooks] = ()) -> list[TrialResult]:
    """Run one trial per seed of `cell`; engines and models come from `resources` (or are made
    and closed here). Hooks see every trial as it runs, so finished trials survive an error."""
    own = resources is None
    resources = resources or Resources()
    try:
        robot = load_robot(cell.robot)
        terrain = Terrain(cell.terrain, seed=cell.terrain_seed)
        sim = resources.sim(cell, robot, terrain)
        policy = build_policy(cell, robot, resources)
        episode = EpisodeConfig(duration=cell.duration, eval_start=cell.eval_start, heading_hold=cell.heading_hold)
        results = []
        try:
            for seed in seeds:
                steps = [cb for cb in (h.start(seed, sim, policy, episode) for h in hooks) if cb is not None]
                on_step = (lambda loop: [cb(loop) for cb in steps]) if steps else None
                result = run_trial(sim, robot, terrain, policy, episode, seed=seed, on_step=on_step)
                for hook in hooks:
                    hook.end(seed, result)
                results.append(result)
        finally:
            policy.close()
        return results
    finally:
        if own:
            resources.close()
