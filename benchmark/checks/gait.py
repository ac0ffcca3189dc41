"""Gait of a seed policy: joint means and ranges, left/right symmetry, and the foot contact pattern.

    bench gait                                  both shipped policies, MuJoCo, flat -> reports/gait.md
    bench gait --robot a1 --policy-file runs/train-a1/policy.npz --out /tmp/gait

The policy walks `trials` trials of `duration` s through the benchmark's own control loop, in an
engine stepped one physics step at a time (so feet are sampled at 200 Hz, not 10 Hz); statistics
cover the time after `skip_s`. Posture: each joint's mean angle against the default pose. Symmetry:
a left joint's mean against its mirrored right partner (hip abduction changes sign in the mirror).
Contact pattern: in a trot, diagonal feet (FR+RL, FL+RR) touch down together and lateral pairs
alternate; `diagonal_sync` and `lateral_sync` are the fractions of samples in which a pair agrees.
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
from benchmark.trial.resources import Resources
from benchmark.trial.trials import TrialHooks, run_cell
from robots import JOINT_ROLES, LEGS, Robot, available_robots, load_robot
from sims import ENGINES, make_sim
from sims.base import PhysicsConfig, RobotState
from sims.terrain import TERRAINS, Terrain

MIRROR_SIGN = {"hip": -1.0, "thigh": 1.0, "calf": 1.0}  # shipped URDFs: abduction about +x, pitch about +y
PAIRS = {"diagonal": ((0, 3), (1, 2)), "lateral": ((0, 1), (2, 3))}  # canonical FR, FL, RR, RL


@dataclass(frozen=True)
class GaitConfig:
    """What `bench gait` measures; its fields are the command's options."""

    robot: tuple[str, ...] = setting(tuple(available_robots()), "robots", choices=available_robots)
    sim: str = setting("mujoco", "engine", choices=lambda: tuple(ENGINES), noun="simulator")
    terrain: str = setting("flat", "terrain", choices=lambda: tuple(TERRAINS))
    policy_file: str | None = setting(None, "seed policy .npz (default: the robot's shipped policy; one robot)")
    trials: int = setting(3, "trials (seeds 0..N-1)", positive=True)
    duration: float = setting(10.0, "seconds per trial", positive=True)
    skip_s: float = setting(2.0, "seconds left out at the start (the gait settles)", minimum=0)
    heading_hold: bool = setting(False, "steer through the yaw-rate command (off: the paper's fixed command)")
    out: str = setting("reports", "folder for gait.md; figures go to OUT/figures")


class SubstepTrace:
    """An engine stepped one physics step at a time, presenting the usual control period and
    keeping every substep's joint angles and foot contacts."""

    def __init__(self, inner, substeps: int) -> None:
        self.inner, self.substeps, self.name = inner, substeps, inner.name
        self.physics = PhysicsConfig(dt=inner.physics.dt, substeps=substeps)
        self.joint_pos: list[np.ndarray] = []
        self.contacts: list[np.ndarray] = []

    def reset(self, seed: int = 0) -> RobotState:
        return self.inner.reset(seed)

    def step(self, joint_targets: np.ndarray) -> RobotState:
        for _ in range(self.substeps):
            state = self.inner.step(joint_targets)
            self.joint_pos.append(state.joint_pos.copy())
            self.contacts.append(np.asarray(state.foot_contact, dtype=bool).copy())
        return state

    def __getattr__(self, name: str):
        return getattr(self.inner, name)


class TrialMarks(TrialHooks):
    """Where each trial starts in the trace."""

    def __init__(self, trace: SubstepTrace) -> None:
        self.trace, self.starts = trace, []

    def start(self, seed, sim, policy, episode):
        self.starts.append(len(self.trace.joint_pos))


def record(config: GaitConfig, robot_name: str) -> tuple[Robot, np.ndarray, np.ndarray, list]:
    """(robot, joint angles (n, 12), foot contacts (n, 4), fall times) after `skip_s` of every trial."""
    values = {"sim": config.sim, "robot": robot_name, "terrain": config.terrain, "policy": "rl",
              "duration": config.duration, "heading_hold": config.heading_hold}
    if config.policy_file:
        values["policy_file"] = config.policy_file
    cell = make_cell(values, where="bench gait")
    robot, physics = load_robot(robot_name), PhysicsConfig()
    trace = SubstepTrace(make_sim(config.sim, robot, Terrain(config.terrain), PhysicsConfig(substeps=1),
                                  options=cell.engine_options), physics.substeps)
    resources = Resources()
    resources.use_sim(cell, trace)
    marks = TrialMarks(trace)
    try:
        results = run_cell(cell, range(config.trials), resources, [marks])
    finally:
        resources.close()
    skip = int(round(config.skip_s / physics.dt))
    ends = marks.starts[1:] + [len(trace.joint_pos)]
    keep = np.concatenate([np.arange(a + skip, b) for a, b in zip(marks.starts, ends)])
    return robot, np.array(trace.joint_pos)[keep], np.array(trace.contacts)[keep], [r.fall_time for r in results]


def joint_table(robot: Robot, q: np.ndarray) -> pd.DataFrame:
    """Per joint: mean, 5-95% range, mean minus default, and the mirrored partner's mean."""
    mean = q.mean(axis=0)
    rows = []
    for leg_i, leg in enumerate(LEGS):
        partner = leg_i ^ 1  # FR<->FL, RR<->RL
        for role_i, role in enumerate(JOINT_ROLES):
            i, j = leg_i * 3 + role_i, partner * 3 + role_i
            rows.append({"joint": f"{leg}_{role}", "default": robot.default_pose[i], "mean": mean[i],
                         "offset": mean[i] - robot.default_pose[i], "p5": np.percentile(q[:, i], 5),
                         "p95": np.percentile(q[:, i], 95), "mirror_gap": abs(mean[i] - MIRROR_SIGN[role] * mean[j])})
    return pd.DataFrame(rows)


def contact_summary(contacts: np.ndarray) -> dict:
    out = {f"{name}_sync": float(np.mean([np.mean(contacts[:, a] == contacts[:, b]) for a, b in pairs]))
           for name, pairs in PAIRS.items()}
    out["stance_fraction"] = float(contacts.mean())
    return out


def plot(robot: Robot, q: np.ndarray, contacts: np.ndarray, dt: float, path: Path, window_s: float = 2.0) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = joint_table(robot, q)
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 4.2), gridspec_kw={"width_ratios": [1.3, 1]})
    x = np.arange(len(table))
    left.vlines(x, table.p5, table.p95, lw=6, alpha=0.35, label="5-95% range")
    left.plot(x, table["mean"], "o", label="mean")
    left.plot(x, table["default"], "k_", ms=14, mew=2, label="default pose")
    left.set_xticks(x, table.joint, rotation=60, fontsize=8)
    left.set_ylabel("rad")
    left.set_title("joint angles while walking")
    left.legend(fontsize=8)
    n = min(len(contacts), int(round(window_s / dt)))
    t = np.arange(n) * dt
    for leg in range(contacts.shape[1]):
        on = contacts[:n, leg]
        right.fill_between(t, leg - 0.4, leg + 0.4, where=on, step="mid", color="k")
    right.set_yticks(range(len(LEGS)), LEGS)
    right.invert_yaxis()
    right.set_xlabel("s")
    summary = contact_summary(contacts)
    right.set_title(f"foot contact (black), {window_s:.0f} s: diagonal sync {summary['diagonal_sync']:.2f}, "
                    f"lateral {summary['lateral_sync']:.2f}", fontsize=9)
    fig.suptitle(f"{robot.title}: seed policy gait")
    return save_figure(fig, path, dpi=110)


def summary_row(robot: Robot, q: np.ndarray, contacts: np.ndarray) -> dict:
    table = joint_table(robot, q)
    hips = table[table.joint.str.endswith("hip")]
    return {"robot": robot.name, "max_hip_offset": float(hips.offset.abs().max()),
            "max_mirror_gap": float(table.mirror_gap.max()), **contact_summary(contacts)}


def main(config: GaitConfig, command: str = "bench gait") -> Path:
    out = Path(config.out)
    dt = PhysicsConfig().dt
    lines = ["# Seed-policy gait", "", f"Regenerate: `{command}`", "",
             f"{config.trials} trials of {config.duration:g} s in {config.sim} on {config.terrain} ground, the first "
             f"{config.skip_s:g} s of each left out; joints and feet sampled at 200 Hz (`benchmark/checks/gait.py`). "
             "Targets: hip abduction within 0.25 rad of default, mirrored left/right means within 0.2 rad, and a "
             "diagonal contact pattern (diagonal sync well above lateral).", ""]
    summaries, header = [], len(lines)
    for name in config.robot:
        print(f"gait: {name}", file=sys.stderr)
        robot, q, contacts, falls = record(config, name)
        path = out / "figures" / f"gait_{robot.name}.png"
        plot(robot, q, contacts, dt, path)
        summaries.append(summary_row(robot, q, contacts) | {"falls": sum(f is not None for f in falls)})
        lines += [f"## {robot.title}", "", f"![{robot.name} gait](figures/{path.name})", "",
                  to_markdown(joint_table(robot, q).round(3)), ""]
    lines[header:header] = ["## Summary", "", to_markdown(pd.DataFrame(summaries).round(3)), ""]
    path = out / "gait.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
    return path
