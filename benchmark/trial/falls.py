"""When has a robot fallen? Trunk contact, base too low over the terrain, or too much tilt."""

from __future__ import annotations

import math

from robots import Robot
from sims.base import RobotState
from sims.terrain import Terrain

DIVERGED_SPEED = 50.0  # m/s: no legged robot moves its base this fast; the integration blew up


def fall_reason(state: RobotState, robot: Robot, terrain: Terrain) -> str | None:
    """A short reason if `state` is a fall, else None."""
    if not state.is_finite():
        return "simulation diverged: non-finite state"
    speed = math.hypot(*state.base_lin_vel.tolist())  # not np.linalg.norm: BLAS, CPU-dependent bits
    if speed > DIVERGED_SPEED:
        return f"simulation diverged: base speed {speed:.0f} m/s"
    if state.fall_contact:
        return "trunk touched the ground"
    x, y, z = state.base_pos
    clearance = z - terrain.height_at(x, y)
    if clearance < robot.fall.min_height:
        return f"base {clearance:.3f} m above ground (< {robot.fall.min_height} m)"
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, -float(state.projected_gravity[2])))))
    if tilt > robot.fall.max_tilt_deg:
        return f"tilted {tilt:.0f} deg (> {robot.fall.max_tilt_deg:.0f} deg)"
    return None
