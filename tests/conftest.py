"""Shared fixtures: the cells of the benchmark (engine x robot x terrain), and `hold` that keeps its prompts."""

from __future__ import annotations

import itertools
import os

import pytest

from benchmark.llm.models import default_threads
from benchmark.llm.reference import HoldModel
from robots import available_robots, load_robot
from sims import available_sims, make_sim
from sims.terrain import TERRAINS, Terrain

CELLS = list(itertools.product(available_sims(), available_robots(), TERRAINS))


def pytest_configure(config: pytest.Config) -> None:
    """Each pytest-xdist worker (and what it starts) gives the embedded model its share of the cores
    (`PROMPTWALK_THREADS`), so llama.cpp's threads never outnumber the cores beside the other worker's tests: then
    its spinning thread barriers take turns, and CI measured Gemma 270M decoding at 0.6 tok/s (44 alone)."""
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if os.environ.get("PYTEST_XDIST_WORKER") and count > 1 and "PROMPTWALK_THREADS" not in os.environ:
        os.environ["PROMPTWALK_THREADS"] = str(max(1, default_threads() // count))


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
