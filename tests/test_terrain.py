"""The terrain is one seeded grid of heights, identical in every engine."""

from __future__ import annotations

import numpy as np
import pytest

from robots import UnknownNameError
from sims import available_sims
from sims.terrain import Terrain


def test_rough_terrain_is_seeded_and_bounded():
    a, b, c = Terrain("rough", seed=1), Terrain("rough", seed=1), Terrain("rough", seed=2)
    np.testing.assert_array_equal(a.heights, b.heights)
    assert not np.array_equal(a.heights, c.heights)
    assert 0.0 <= a.heights.min() and a.heights.max() <= a.roughness + 1e-12
    assert np.ptp(a.heights) > 0.5 * a.roughness
    assert a.height_at(0.0, 0.0) == 0.0  # flat spawn patch


def test_height_at_interpolates_the_grid():
    t = Terrain("rough", seed=4)
    i, j = 17, 123
    x, y = t.grid_x[j], t.grid_y[i]
    assert t.height_at(x, y) == pytest.approx(t.heights[i, j])
    mid = t.height_at(x + t.resolution / 2, y)
    assert mid == pytest.approx((t.heights[i, j] + t.heights[i, j + 1]) / 2)


def test_flat_terrain_is_zero():
    assert Terrain("flat").height_at(3.0, -1.0) == 0.0


def test_unknown_terrain_lists_valid_names():
    with pytest.raises(UnknownNameError, match="unknown terrain 'stairs'; valid: flat, rough"):
        Terrain("stairs")


@pytest.mark.parametrize("sim", available_sims())
def test_engine_heights_match_the_grid(make, sim):
    s = make(sim, "a1", "rough", seed=7)
    t = s.terrain
    rng = np.random.default_rng(0)
    rows, cols = t.shape
    for i, j in zip(rng.integers(1, rows - 1, 25), rng.integers(1, cols - 1, 25)):
        assert s.ray_height(t.grid_x[j], t.grid_y[i]) == pytest.approx(t.heights[i, j], abs=1e-4)
    # Along grid edges every triangulation interpolates linearly, as height_at does. Points sit
    # a micrometre off the edge: MuJoCo's ray test can slip between triangles exactly on one.
    eps = 1e-6
    for i, j, u in zip(rng.integers(1, rows - 1, 25), rng.integers(1, cols - 1, 25), rng.uniform(0, 1, 25)):
        x, y = t.grid_x[j] + u * t.resolution, t.grid_y[i] + eps
        assert s.ray_height(x, y) == pytest.approx(t.height_at(x, y), abs=1e-4)
        x, y = t.grid_x[j] + eps, t.grid_y[i] + u * t.resolution
        assert s.ray_height(x, y) == pytest.approx(t.height_at(x, y), abs=1e-4)


def test_the_margin_surrounds_the_core_without_changing_it():
    """Rough ground reaches `margin` metres past the core on every side (a robot drifting sideways walked off the
    8 m core's edge), the core's heights are the same with or without it, and the digest tells the grounds apart."""
    wide, bare = Terrain("rough", seed=3), Terrain("rough", seed=3, margin=0.0)
    rows, cols = wide.core
    np.testing.assert_array_equal(wide.heights[rows, cols], bare.heights)
    assert wide.grid_y[0] == pytest.approx(-wide.width / 2 - wide.margin) and wide.grid_x[-1] == pytest.approx(
        wide.x_min + wide.length + wide.margin)
    outside = wide.heights[: rows.start]  # the band beyond y = -4 m
    assert np.ptp(outside) > 0.5 * wide.roughness and outside.max() <= wide.roughness + 1e-12
    assert wide.height_at(0.0, -wide.width / 2 - 2.0) == pytest.approx(
        wide.heights[rows.start - 20, round((0.0 - wide.grid_x[0]) / wide.resolution)])
    assert len({wide.digest, bare.digest, Terrain("rough", seed=4).digest, Terrain("flat").digest}) == 4
