"""Speed of the framework against the raw engine loop, on the same model, in the same run.

    bench perf --sim mujoco --robot a1
    bench perf --sim newton --worlds 64

Alternating rounds of the engine's bare stepping loop (`Simulator.raw_loop`) and of the
framework's `step` (PD, state, contacts); the best round of each is kept, in physics steps/s
summed over worlds, and their ratio is printed.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from tqdm import tqdm

from benchmark.trial.cell import CellSpec
from robots import load_robot
from sims import make_sim, make_worlds
from sims.terrain import Terrain


def time_loops(stepper, targets, steps: int, rounds: int, physics_steps: int, reset) -> tuple[float, float]:
    """Best-of-`rounds` physics steps/s of the raw engine loop and of the framework's step."""
    raw, framework = [], []
    for _ in tqdm(range(rounds), desc="perf rounds", file=sys.stderr, disable=None, leave=False):
        reset()
        start = time.perf_counter()
        stepper.raw_loop(targets, steps)
        raw.append(physics_steps / (time.perf_counter() - start))
        reset()
        start = time.perf_counter()
        for _ in range(steps):
            stepper.step(targets)
        framework.append(physics_steps / (time.perf_counter() - start))
    return max(raw), max(framework)


class BatchStepper:
    """Adapts a batched engine to time_loops: a framework step also builds every world's state."""

    def __init__(self, worlds) -> None:
        self.worlds = worlds

    def raw_loop(self, targets, steps: int) -> None:
        self.worlds.raw_loop(targets, steps)

    def step(self, targets) -> None:
        self.worlds.step(targets)
        self.worlds.states()


def measure(cell: CellSpec, steps: int, rounds: int, worlds: int | None = None) -> dict:
    """Rows of raw and framework steps/s for 1 world (and `worlds` worlds on batched engines)."""
    robot, terrain = load_robot(cell.robot), Terrain(cell.terrain, seed=cell.terrain_seed)
    rows = []
    sim = make_sim(cell.sim, robot, terrain, options=cell.engine_options)
    try:
        physics = steps * sim.physics.substeps
        raw, framework = time_loops(sim, robot.default_pose, steps, rounds, physics, lambda: sim.reset(0))
        rows.append({"worlds": 1, "raw_steps_per_s": raw, "framework_steps_per_s": framework})
    finally:
        sim.close()
    if worlds is not None and worlds > 1:
        many = make_worlds(cell.sim, robot, terrain, worlds, options=cell.engine_options)
        targets = np.tile(robot.default_pose, (worlds, 1))
        physics = steps * many.physics.substeps * worlds  # env-steps: physics steps summed over worlds
        raw, framework = time_loops(BatchStepper(many), targets, steps, rounds, physics,
                                    lambda: many.reset(range(worlds)))
        rows.append({"worlds": worlds, "raw_steps_per_s": raw, "framework_steps_per_s": framework})
    for row in rows:
        row["ratio"] = row["framework_steps_per_s"] / row["raw_steps_per_s"]
    return {"sim": cell.sim, "robot": cell.robot, "terrain": cell.terrain, "control_steps": steps,
            "rounds": rounds, **rows[0], "by_worlds": rows}


def print_table(result: dict) -> None:
    print(f"{result['sim']} / {result['robot']} / {result['terrain']}: physics steps per second, summed over "
          f"worlds (best of {result['rounds']} rounds of {result['control_steps']} control steps)")
    print(f"{'worlds':>7} {'raw engine':>12} {'promptwalk':>12} {'ratio':>7}")
    for row in result["by_worlds"]:
        print(f"{row['worlds']:>7} {row['raw_steps_per_s']:>12,.0f} {row['framework_steps_per_s']:>12,.0f} "
              f"{row['ratio']:>7.3f}")
