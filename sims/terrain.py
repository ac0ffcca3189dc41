"""Terrain as a parameter: one seeded heightfield that every engine loads identically."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import cached_property

import numpy as np

TERRAINS = ("flat", "rough")


@dataclass(frozen=True)
class Terrain:
    """Ground for a robot; `rough` is a random heightfield, `flat` a plane at z = 0.

    The rough grid's core is a rectangle x in [x_min, x_min + length], y in [-width/2, width/2] where the robot
    starts and walks; `margin` metres of rough ground from a second random stream surround it, so that a robot
    drifting sideways over 20 s stays on rough ground instead of walking off the edge (it did, off the 8 m core:
    ANYmal in PyBullet at y = 4 m after 17 s). The core's heights do not depend on the margin. Heights live on a
    regular grid of `resolution` metres; engines triangulate between grid points, which are exact in every engine.
    """

    kind: str = "flat"
    seed: int = 0
    length: float = 32.0  # m along x, the core: 20 s at 1 m/s plus margin
    width: float = 8.0  # m along y, the core
    x_min: float = -4.0
    margin: float = 20.0  # m of rough ground around the core on every side: 20 s at 1 m/s from the start
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
    def size(self) -> tuple[float, float]:
        """(along x, along y) of the whole grid, core and margin, metres."""
        return self.length + 2 * self.margin, self.width + 2 * self.margin

    @property
    def shape(self) -> tuple[int, int]:
        """(rows along y, columns along x) of the whole grid."""
        return round(self.size[1] / self.resolution) + 1, round(self.size[0] / self.resolution) + 1

    @property
    def core(self) -> tuple[slice, slice]:
        """The core's (rows, columns) in the whole grid."""
        m = round(self.margin / self.resolution)
        return (slice(m, m + round(self.width / self.resolution) + 1),
                slice(m, m + round(self.length / self.resolution) + 1))

    def _bumps(self, rows: int, cols: int, rng: np.random.Generator) -> np.ndarray:
        """Uniform heights averaged with their neighbours (bumps a foot can step on, not needles), stretched to
        [0, roughness] and rounded to `step`."""
        raw = rng.uniform(0.0, self.roughness, (rows, cols))
        padded = np.pad(raw, 1, mode="edge")
        smooth = sum(padded[1 + dy : rows + 1 + dy, 1 + dx : cols + 1 + dx]
                     for dy in (-1, 0, 1) for dx in (-1, 0, 1)) / 9.0
        smooth = (smooth - smooth.min()) / max(np.ptp(smooth), 1e-9) * self.roughness
        return np.round(smooth / self.step) * self.step

    @cached_property
    def heights(self) -> np.ndarray:
        """Grid of heights (rows along y, columns along x), metres."""
        rows, cols = self.shape
        if self.is_flat:
            return np.zeros((rows, cols))
        rows_core, cols_core = self.core
        heights = self._bumps(rows, cols, np.random.default_rng([self.seed, 1]))  # the margin's own stream
        core = self._bumps(rows_core.stop - rows_core.start, cols_core.stop - cols_core.start,
                           np.random.default_rng(self.seed))
        xs = self.x_min + self.resolution * np.arange(core.shape[1])  # the core's own coordinates, as they were
        ys = -self.width / 2 + self.resolution * np.arange(core.shape[0])  # computed before the margin (bit for bit)
        core[(xs[None, :] ** 2 + ys[:, None] ** 2) < self.flat_radius**2] = 0.0
        heights[rows_core, cols_core] = core
        return heights

    @cached_property
    def digest(self) -> str:
        """What a trial's ground was: "flat", or the rough grid's extent and heights hashed (stores record it, so a
        trial made on other ground runs again)."""
        if self.is_flat:
            return "flat"
        extent = np.array([*self.origin, self.resolution, *self.shape], dtype=float)
        return hashlib.sha256(extent.tobytes() + self.heights.tobytes()).hexdigest()[:16]

    @property
    def origin(self) -> tuple[float, float]:
        """(x, y) of the whole grid's first point, metres."""
        return self.x_min - self.margin, -self.width / 2 - self.margin

    @property
    def grid_x(self) -> np.ndarray:
        return self.origin[0] + self.resolution * np.arange(self.shape[1])

    @property
    def grid_y(self) -> np.ndarray:
        return self.origin[1] + self.resolution * np.arange(self.shape[0])

    @property
    def center(self) -> tuple[float, float]:
        return self.origin[0] + self.size[0] / 2, 0.0

    def height_at(self, x: float, y: float) -> float:
        """Bilinear height under (x, y); 0 outside the grid."""
        if self.is_flat:
            return 0.0
        x0, y0 = self.origin  # scalars: this runs every control step (falls, heights), no grid arrays built
        fx = (x - x0) / self.resolution
        fy = (y - y0) / self.resolution
        rows, cols = self.shape
        if not (0 <= fx <= cols - 1 and 0 <= fy <= rows - 1):
            return 0.0
        c0, r0 = min(int(fx), cols - 2), min(int(fy), rows - 2)
        tx, ty = fx - c0, fy - r0
        h = self.heights
        top = h[r0, c0] * (1 - tx) + h[r0, c0 + 1] * tx
        bottom = h[r0 + 1, c0] * (1 - tx) + h[r0 + 1, c0 + 1] * tx
        return float(top * (1 - ty) + bottom * ty)
