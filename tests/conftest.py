"""Shared fixtures: the cells of the benchmark (engine x robot x terrain), and `hold` that keeps its prompts."""

from __future__ import annotations

import itertools

import pytest

from benchmark.llm.reference import HoldModel
from robots import available_robots, load_robot
from sims import available_sims, make_sim
from sims.terrain import TERRAINS, Terrain

CELLS = list(itertools.product(available_sims(), available_robots(), TERRAINS))

# Files whose tests are mostly llama.cpp reading prompts on two threads: on one worker, one after another. Two such
# processes at once on two cores take turns at llama.cpp's spinning thread barriers (measured: `bench throughput` on
# Gemma 270M, 72 s alone, 135 s each with a second beside it; decode 44 against 13 tok/s).
ONE_WORKER_FILES = {"test_history_modes.py", "test_lockstep.py"}


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Group tests for `--dist loadgroup`: a file's tests stay on one worker (its module fixtures built once), and
    the files in ONE_WORKER_FILES share one worker. Runs before xdist reads the groups."""
    for item in items:
        name = item.path.name
        item.add_marker(pytest.mark.xdist_group("embedded-llm" if name in ONE_WORKER_FILES else name))


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
