"""Does a seed policy walk straight on its own? The paper's fixed command, no heading hold.

    bench straight                              both robots, every engine -> reports/straight.md
    bench straight --robot a1 --sim mujoco --policy-file runs/train-a1/policy.npz --out /tmp/straight

The seed policy walks flat ground at the robot's command (vx 1 m/s, yaw rate 0) from `seed_start`
to the end of the episode, with the heading hold off, as in an LLM cell's seed phase. Per engine:
the net yaw, the sideways offset y and the forward distance x from the start, against targets
(|yaw| <= 0.3 rad, |y| <= 1.5 m, x >= 15 m over 19 s of walking), and a figure of the paths.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.common.figures import save_figure
from benchmark.common.settings import setting
from benchmark.common.tables import to_markdown
from benchmark.trial.cell import make_cell
from benchmark.trial.trials import TrialHooks, run_cell
from robots import available_robots, load_robot
from sims import ENGINES

TARGETS = {"abs_yaw_rad": 0.3, "abs_y_m": 1.5, "x_m": 15.0}


@dataclass(frozen=True)
class StraightConfig:
    """What `bench straight` measures; its fields are the command's options."""

    robot: tuple[str, ...] = setting(tuple(available_robots()), "robots", choices=available_robots)
    sim: tuple[str, ...] = setting(tuple(ENGINES), "engines", choices=lambda: tuple(ENGINES), noun="simulator")
    policy_file: str | None = setting(None, "seed policy .npz (default: the robot's shipped policy; one robot)")
    trials: int = setting(3, "trials (seeds 0..N-1)", positive=True)
    duration: float = setting(20.0, "seconds per trial", positive=True)
    seed_start: float = setting(1.0, "s: the seed policy starts walking (the paper's protocol)", minimum=0)
    out: str = setting("reports", "folder for straight.md; the figure goes to OUT/figures")


class Path2D(TrialHooks):
    """The base's (x, y) every control step."""

    def start(self, seed, sim, policy, episode):
        self.points = []
        return lambda loop: self.points.append(loop.state.base_pos[:2].copy())


def measure(config: StraightConfig, progress=None) -> tuple[pd.DataFrame, dict]:
    rows, paths = [], {}
    for robot in config.robot:
        for sim in config.sim:
            values = {"sim": sim, "robot": robot, "terrain": "flat", "policy": "rl", "duration": config.duration,
                      "seed_start": config.seed_start, "heading_hold": False}
            if config.policy_file:
                values["policy_file"] = config.policy_file
            cell = make_cell(values)
            for seed in range(config.trials):
                trace = Path2D()
                result = run_cell(cell, [seed], hooks=[trace])[0]
                xy = np.array(trace.points)
                paths[(robot, sim, seed)] = xy
                rows.append({"robot": robot, "sim": sim, "seed": seed, "x_m": float(xy[-1, 0] - xy[0, 0]),
                             "y_m": float(xy[-1, 1] - xy[0, 1]), "yaw_rad": result.heading_change_rad,
                             "fell": result.fall_time is not None})
                if progress:
                    progress(f"{robot}/{sim} seed {seed}: x {rows[-1]['x_m']:.1f} m, y {rows[-1]['y_m']:.2f} m, "
                             f"yaw {rows[-1]['yaw_rad']:.2f} rad")
    return pd.DataFrame(rows), paths


def summary(frame: pd.DataFrame) -> pd.DataFrame:
    """Per robot and engine: ranges over seeds and whether every seed meets every target."""
    out = []
    for (robot, sim), g in frame.groupby(["robot", "sim"], sort=False):
        meets = ((g["yaw_rad"].abs() <= TARGETS["abs_yaw_rad"]) & (g["y_m"].abs() <= TARGETS["abs_y_m"])
                 & (g["x_m"] >= TARGETS["x_m"]) & ~g["fell"])
        out.append({"robot": robot, "engine": sim, "x (m)": f"{g['x_m'].min():.1f} to {g['x_m'].max():.1f}",
                    "y (m)": f"{g['y_m'].min():.2f} to {g['y_m'].max():.2f}",
                    "net yaw (rad)": f"{g['yaw_rad'].min():.2f} to {g['yaw_rad'].max():.2f}",
                    "falls": int(g["fell"].sum()), "meets targets": f"{int(meets.sum())}/{len(g)}"})
    return pd.DataFrame(out)


def plot(paths: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    robots = list(dict.fromkeys(k[0] for k in paths))
    fig, axes = plt.subplots(1, len(robots), figsize=(5.5 * len(robots), 3.6), squeeze=False)
    colors = {}
    for (robot, sim, seed), xy in paths.items():
        ax = axes[0, robots.index(robot)]
        color = colors.setdefault(sim, f"C{len(colors)}")
        ax.plot(xy[:, 0] - xy[0, 0], xy[:, 1] - xy[0, 1], color=color, lw=1, label=sim if seed == 0 else None)
    for robot, ax in zip(robots, axes[0]):
        ax.axhspan(-TARGETS["abs_y_m"], TARGETS["abs_y_m"], color="green", alpha=0.08, label="|y| <= 1.5 m")
        ax.axvline(TARGETS["x_m"], color="green", lw=0.8, ls=":")
        ax.set_title(f"{load_robot(robot).title}: fixed command, no heading hold", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=7)
    return save_figure(fig, path, dpi=110)


def main(config: StraightConfig, command: str = "bench straight") -> Path:
    frame, paths = measure(config, progress=lambda line: print(f"bench: {line}", file=sys.stderr, flush=True))
    out = Path(config.out)
    figure = plot(paths, out / "figures" / "straight_paths.png")
    lines = ["# Walking straight at the paper's fixed command", "", f"Regenerate: `{command}`", "",
             f"Flat ground, command fixed at the robot's (vx 1 m/s, no yaw rate), heading hold off; the seed policy "
             f"walks from {config.seed_start:g} s to {config.duration:g} s, {config.trials} seeds per engine. Offsets "
             f"are from the start. Targets: |net yaw| <= {TARGETS['abs_yaw_rad']} rad, |y| <= {TARGETS['abs_y_m']} m, "
             f"x >= {TARGETS['x_m']:g} m.", "", to_markdown(summary(frame)), "",
             f"![paths](figures/{figure.name})", "", "Every trial:", "", to_markdown(frame.round(3)), ""]
    path = out / "straight.md"
    path.write_text("\n".join(lines))
    return path
