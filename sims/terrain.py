"""Terrain as a parameter: one seeded heightfield that every engine loads identically."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

TERRAINS = ("flat", "rough")


@dataclass(frozen=True)
class Terrain:
    """A rectangle of ground; `rough` is a random heightfield, `flat` a plane at z = 0.

    Heights live on a regular grid of `resolution` metres spanning x in [x_min, x_min + length]
    and y in [-width/2, width/2]. Engines triangulate between grid points; the grid points
    themselves are exact in every engine.
    """

    kind: str = "flat"
    seed: int = 0
    length: float = 32.0  # m along x: 20 s at 1 m/s plus margin
    width: float = 8.0  # m along y
    x_min: float = -4.0
    resolution: float = 0.1  # m between grid points
    roughness: float = 0.04  # m, peak-to-peak height of the rough terrain
    step: float = 0.005  # m, heights are multiples of this
    flat_radius: float = 0.5  # m, the rough terrain is flat around the spawn point

    def __post_init__(self) -> None:
        if self.kind not in TERRAINS:
            from robots import UnknownNameError

            raise UnknownNameError("terrain", self.kind, TERRAINS)

    @property
    def is_flat(self) -> bool:
        return self.kind == "flat"

    @property
    def shape(self) -> tuple[int, int]:
        """(rows along y, columns along x)."""
        return round(self.width / self.resolution) + 1, round(self.length / self.resolution) + 1

    @cached_property
    def heights(self) -> np.ndarray:
        """Grid of heights (rows along y, columns along x), metres."""
        rows, cols = self.shape
        if self.is_flat:
            return np.zeros((rows, cols))
        rng = np.random.default_rng(self.seed)
        raw = rng.uniform(0.0, self.roughness, (rows, cols))
        # Average each point with its neighbours: bumps a foot can step on, not needles.
        padded = np.pad(raw, 1, mode="edge")
        smooth = sum(padded[1 + dy : rows + 1 + dy, 1 + dx : cols + 1 + dx]
                     for dy in (-1, 0, 1) for dx in (-1, 0, 1)) / 9.0
        smooth = (smooth - smooth.min()) / max(np.ptp(smooth), 1e-9) * self.roughness
        heights = np.round(smooth / self.step) * self.step
        xs, ys = self.grid_x, self.grid_y
        near_spawn = (xs[None, :] ** 2 + ys[:, None] ** 2) < self.flat_radius**2
        heights[near_spawn] = 0.0
        return heights

    @property
    def grid_x(self) -> np.ndarray:
        return self.x_min + self.resolution * np.arange(self.shape[1])

    @property
    def grid_y(self) -> np.ndarray:
        return -self.width / 2 + self.resolution * np.arange(self.shape[0])

    @property
    def center(self) -> tuple[float, float]:
        return self.x_min + self.length / 2, 0.0

    def height_at(self, x: float, y: float) -> float:
        """Bilinear height under (x, y); 0 outside the grid."""
        if self.is_flat:
            return 0.0
        fx = (x - self.x_min) / self.resolution
        fy = (y + self.width / 2) / self.resolution
        rows, cols = self.shape
        if not (0 <= fx <= cols - 1 and 0 <= fy <= rows - 1):
            return 0.0
        c0, r0 = min(int(fx), cols - 2), min(int(fy), rows - 2)
        tx, ty = fx - c0, fy - r0
        h = self.heights
        top = h[r0, c0] * (1 - tx) + h[r0, c0 + 1] * tx
        bottom = h[r0 + 1, c0] * (1 - tx) + h[r0 + 1, c0 + 1] * tx
        return float(top * (1 - ty) + bottom * ty)
