"""Shared fixtures: the cells of the benchmark (engine x robot x terrain)."""

from __future__ import annotations

import itertools

import pytest

from robots import available_robots, load_robot
from sims import available_sims, make_sim
from sims.terrain import TERRAINS, Terrain

CELLS = list(itertools.product(available_sims(), available_robots(), TERRAINS))


@pytest.fixture
def make():
    """Build a simulator and close it after the test."""
    built = []

    def _make(sim: str, robot: str, terrain: str = "flat", seed: int = 0):
        s = make_sim(sim, load_robot(robot), Terrain(terrain, seed=seed))
        built.append(s)
        return s

    yield _make
    for s in built:
        s.close()
