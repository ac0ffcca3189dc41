"""How trials run, not what they measure (`Runtime`), and what they share: engines and models kept alive
between trials (`Resources`, one per sweep worker; `SharedModels` across threads)."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from benchmark.common.settings import setting
from benchmark.trial.cell import CellSpec
from robots import Robot
from sims import make_sim
from sims.base import Simulator
from sims.terrain import Terrain

MAX_CACHED_SIMS = 4
DRAFTS = ("ngram", "none")  # speculative decoding of an embedded model
DEFAULT_DRAFT = "ngram"


@dataclass(frozen=True)
class Runtime:
    """How trials run, not what they measure: never part of a cell's identity."""

    threads: int | None = setting(None, "llama.cpp threads (default: PROMPTWALK_THREADS, else the cores allowed; "
                                  "divided by the workers in a sweep)",
                                  positive=True)
    draft: str = setting(DEFAULT_DRAFT, "embedded models: speculative decoding. ngram drafts the reply from token "
                                  "n-grams already in the prompt (llama.cpp's ngram-simple: replies repeat the "
                                  "history's numbers) and checks the draft in one batch; none decodes token by token",
                         choices=DRAFTS)
    cache: bool = True  # the on-disk LLM reply cache
    end_at_stop: bool = setting(False, "end a trial once the robot has stopped walking (the walking test's first slow "
                                       "window): NWT and success are decided by then and come out exactly as over the "
                                       "whole episode; distance, drift and the reply diagnostics cover the trial up "
                                       "to that point, upright is not measured, and the row says ended_at_stop. Saves "
                                       "the queries of a robot that stands (an LLM trial's main cost)")
    slots: int = 1  # embedded models: llama.cpp slots, one per trial in flight (`--concurrency`): their decodes batch
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
        # a disturbance that changes dynamics leaves them changed until its next trial resets them: an engine is
        # shared only by cells with the same disturbance, so an undisturbed or shoved cell never inherits weak motors
        return cell.sim, cell.robot, cell.terrain, cell.terrain_seed, cell.engine, cell.disturbance

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
