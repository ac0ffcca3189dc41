"""Shared fixtures: the cells of the benchmark (engine x robot x terrain), and `hold` that keeps its prompts."""

from __future__ import annotations

import itertools
import os

import pytest

from benchmark.llm.reference import HoldModel
from robots import available_robots, load_robot
from sims import available_sims, make_sim
from sims.terrain import TERRAINS, Terrain

CELLS = list(itertools.product(available_sims(), available_robots(), TERRAINS))


def pytest_configure(config: pytest.Config) -> None:
    """Each pytest-xdist worker (and what it starts) runs on cores of its own, so the embedded model's llama.cpp
    threads (one per core allowed, `default_threads`) never share a core with the other worker's tests. Sharing made
    its spinning thread barriers take turns: CI measured Gemma 270M decoding at 0.6 tok/s (44 alone)."""
    worker, count = os.environ.get("PYTEST_XDIST_WORKER"), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_setaffinity") else []
    if worker and 1 < count <= len(cores):
        os.sched_setaffinity(0, set(cores[int(worker.removeprefix("gw")) % count::count]))


class RecordingHold(HoldModel):
    """`hold`, keeping every prompt it was asked."""

    def __init__(self) -> None:
        super().__init__()
        self.prompts: list[str] = []

    def reply_to(self, prompt: str) -> str:
        self.prompts.append(prompt)
        return super().reply_to(prompt)


@pytest.fixture(scope="session")
def make():
    """A simulator per (engine, robot, terrain, seed), built once for the session.

    Tests reset it before use and leave its dynamics nominal. Sharing matters for Newton,
    whose solver setup takes seconds even with warp's kernel cache warm.
    """
    built: dict[tuple, object] = {}

    def _make(sim: str, robot: str, terrain: str = "flat", seed: int = 0):
        key = (sim, robot, terrain, seed)
        if key not in built:
            built[key] = make_sim(sim, load_robot(robot), Terrain(terrain, seed=seed))
        return built[key]

    yield _make
    for s in built.values():
        s.close()
