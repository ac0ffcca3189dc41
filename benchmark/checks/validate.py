"""Joint validation: each engine's hung robot against a one-joint model of the same joint.

    bench validate                                 both robots, every engine -> reports/validation.md
    bench validate --robot a1 --sim mujoco pybullet --out /tmp/check

The robot hangs with its base fixed in the air (`PhysicsConfig.fixed_base`), every joint held at
the default pose by the 200 Hz PD law, sampled at 200 Hz (one physics step per control step).
After `settle_s`, one joint of each kind (front-right hip, thigh, calf) gets a step of `step_rad`;
in a second run, a sinusoid of `sine_rad` at `sine_hz`. The other joints keep their targets.

The reference is that joint alone:

    (I + armature) q'' = clip(Kp (q* - q) - Kd q', limit) - damping q' - friction sgn(q') + tau_g

I is the joint's own entry of the robot's mass matrix at the default pose (the other joints held
rigid) and tau_g the gravity torque there, both from the URDF through MuJoCo; it is integrated at
20 kHz with the PD torque held over each 5 ms step, as the engines apply it. Its linear part is a
second-order system, wn = sqrt(Kp / (I + armature)), zeta = (Kd + damping) / (2 sqrt(Kp (I + armature))).
A second reference drops the armature, to show what it changes. Bullet has no joint armature; PyBullet
emulates it with geared rotors (`sims.pybullet.with_rotors`) and is compared with the full reference.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.common.figures import save_figure
from benchmark.common.settings import setting
from benchmark.common.tables import to_markdown
from robots import JOINT_ROLES, Robot, available_robots, load_robot
from sims import ENGINES, make_sim
from sims.base import PhysicsConfig
from sims.terrain import Terrain

REFERENCE = "reference"  # the one-joint model with the robot's armature
NO_ARMATURE = "reference, no armature"


@dataclass(frozen=True)
class ValidateConfig:
    """What `bench validate` measures; its fields are the command's options."""

    robot: tuple[str, ...] = setting(tuple(available_robots()), "robots to hang", choices=available_robots)
    sim: tuple[str, ...] = setting(tuple(ENGINES), "engines to compare", choices=lambda: tuple(ENGINES), noun="simulator")
    step_rad: float = setting(0.2, "step added to the joint's default target, rad", positive=True)
    sine_rad: float = setting(0.1, "amplitude of the sinusoidal target, rad", positive=True)
    sine_hz: float = setting(2.0, "frequency of the sinusoidal target, Hz", positive=True)
    settle_s: float = setting(0.5, "seconds holding the default pose before the command", positive=True)
    duration_s: float = setting(1.0, "seconds recorded after the command starts", positive=True)
    out: str = setting("reports", "folder for validation.md; figures go to OUT/figures")


@dataclass(frozen=True)
class Joint:
    """One joint's facts for the reference model."""

    index: int  # canonical joint index
    inertia: float  # kg m^2, without armature
    gravity_torque: float  # N m at the default pose
    armature: float
    damping: float
    friction: float
    kp: float
    kd: float
    limit: float

    def natural(self, armature: float | None = None) -> tuple[float, float]:
        """(wn rad/s, zeta) of the linear part."""
        total = self.inertia + (self.armature if armature is None else armature)
        return math.sqrt(self.kp / total), (self.kd + self.damping) / (2 * math.sqrt(self.kp * total))


def joint_facts(robot: Robot) -> list[Joint]:
    """Each joint's inertia and gravity torque at the default pose (from the URDF via MuJoCo), with its
    armature, damping, friction, gains and torque limit: canonical order."""
    from sims.mujoco import hung_joint_inertia_and_gravity

    inertia, gravity = hung_joint_inertia_and_gravity(robot, robot.default_pose)
    jd = robot.joint_dynamics
    return [Joint(i, float(inertia[i]), float(gravity[i]), float(jd.armature[i]), float(jd.damping[i]),
                  float(jd.friction[i]), robot.kp, robot.kd, float(robot.torque_limit[i]))
            for i in range(robot.num_joints)]


def reference_response(joint: Joint, q0: float, targets: np.ndarray, dt: float, armature: float | None = None,
                       fine: int = 100) -> np.ndarray:
    """The one-joint model's angle after each control step of `targets` (held for `dt` each)."""
    inertia = joint.inertia + (joint.armature if armature is None else armature)
    h = dt / fine
    q, v, out = q0, 0.0, np.empty(len(targets))
    for k, target in enumerate(targets):
        tau_pd = float(np.clip(joint.kp * (target - q) - joint.kd * v, -joint.limit, joint.limit))
        for _ in range(fine):
            drive = tau_pd + joint.gravity_torque - joint.damping * v
            if v == 0.0 and abs(drive) <= joint.friction:  # static friction holds the joint
                continue
            v_next = v + h * (drive - joint.friction * math.copysign(1.0, v if v != 0.0 else drive)) / inertia
            v = 0.0 if v != 0.0 and v_next * v < 0.0 else v_next  # kinetic friction stops, never reverses, it
            q += h * v
        out[k] = q
    return out


def commands(config: ValidateConfig, dt: float) -> dict[str, np.ndarray]:
    """Target offsets after the settle phase: the step and the sinusoid."""
    t = np.arange(1, int(round(config.duration_s / dt)) + 1) * dt
    return {"step": np.full(len(t), config.step_rad), "sine": config.sine_rad * np.sin(2 * np.pi * config.sine_hz * t)}


def engine_response(sim, robot: Robot, index: int, offsets: np.ndarray, settle_steps: int) -> tuple[float, np.ndarray]:
    """(joint angle after settling, angle after each commanded step) in a hung engine."""
    sim.reset(0)
    targets = robot.default_pose.copy()
    for _ in range(settle_steps):
        state = sim.step(targets)
    q0 = float(state.joint_pos[index])
    out = np.empty(len(offsets))
    for k, offset in enumerate(offsets):
        targets[index] = robot.default_pose[index] + offset
        out[k] = sim.step(targets).joint_pos[index]
    return q0, out


def step_metrics(q0: float, q: np.ndarray, dt: float, commanded: float) -> dict:
    """Rise time (10-90% of the settled change), overshoot and steady-state error of a step."""
    final = float(q[-max(1, len(q) // 10):].mean())
    change = final - q0
    progress = (q - q0) / change if abs(change) > 1e-9 else np.zeros_like(q)
    return {"rise_ms": 1000 * dt * (crossing(progress, 0.9) - crossing(progress, 0.1)),
            "overshoot_pct": 100 * max(0.0, float(progress.max()) - 1.0), "ss_error_rad": commanded - change}


def crossing(progress: np.ndarray, level: float) -> float:
    """Sample index (fractional, linear between samples) where `progress` first reaches `level`;
    sample k is taken k + 1 steps after the command, and the command starts from 0."""
    above = np.flatnonzero(progress >= level)
    if len(above) == 0:
        return float(len(progress))
    k = int(above[0])
    before = progress[k - 1] if k > 0 else 0.0
    return k + (level - before) / (progress[k] - before) if progress[k] != before else float(k)


def sine_metrics(q0: float, q: np.ndarray, dt: float, hz: float, amplitude: float) -> dict:
    """Gain and phase lag of the response's fundamental over the last whole periods."""
    t = np.arange(1, len(q) + 1) * dt
    period = int(round(1 / (hz * dt)))
    keep = slice(len(q) - period * max(1, (len(q) // period) - 1), len(q))  # skip the first period's transient
    w = 2 * np.pi * hz
    basis = np.stack([np.sin(w * t[keep]), np.cos(w * t[keep]), np.ones(len(t[keep]))], axis=1)
    (a, b, _), *_ = np.linalg.lstsq(basis, q[keep] - q0, rcond=None)
    return {"gain": math.hypot(a, b) / amplitude, "lag_deg": -math.degrees(math.atan2(b, a))}


def validate(config: ValidateConfig, progress=None) -> tuple[pd.DataFrame, dict]:
    """Every robot x engine x joint kind x command: metrics (a table) and trajectories (for figures)."""
    physics = PhysicsConfig(fixed_base=True, substeps=1)
    dt, settle = physics.dt, int(round(config.settle_s / physics.dt))
    signals = commands(config, dt)
    rows, curves = [], {}
    for robot_name in config.robot:
        robot = load_robot(robot_name)
        facts = joint_facts(robot)
        joints = {role: facts[i] for i, role in enumerate(JOINT_ROLES)}  # the front-right leg
        for sim_name in config.sim:
            sim = make_sim(sim_name, robot, Terrain("flat"), physics)
            for role, joint in joints.items():
                for kind, offsets in signals.items():
                    q0, q = engine_response(sim, robot, joint.index, offsets, settle)
                    curves[(robot.name, role, kind, sim_name)] = (q0, q)
                    if progress:
                        progress()
            sim.close()
        for role, joint in joints.items():
            for kind, offsets in signals.items():  # the reference settles from the default pose too
                default = robot.default_pose[joint.index]
                targets = default + np.concatenate([np.zeros(settle), offsets])
                for source, armature in ((REFERENCE, None), (NO_ARMATURE, 0.0)):
                    q = reference_response(joint, default, targets, dt, armature)
                    curves[(robot.name, role, kind, source)] = (float(q[settle - 1]), q[settle:])
        for (name, role, kind, source), (q0, q) in curves.items():
            if name != robot.name:
                continue
            joint = joints[role]
            wn, zeta = joint.natural(0.0 if source == NO_ARMATURE else None)
            metrics = (step_metrics(q0, q, dt, config.step_rad) if kind == "step"
                       else sine_metrics(q0, q, dt, config.sine_hz, config.sine_rad))
            rows.append({"robot": name, "joint": role, "command": kind, "source": source, **metrics,
                         "inertia": joint.inertia, "armature": joint.armature if source != NO_ARMATURE else 0.0,
                         "wn": wn, "zeta": zeta})
    return pd.DataFrame(rows), curves


def agreement(table: pd.DataFrame, a: str, b: str, column: str = "rise_ms") -> pd.Series:
    """Relative difference |a - b| / b of one step metric, per robot and joint."""
    steps = table[table.command == "step"].set_index(["robot", "joint", "source"])[column]
    return ((steps.xs(a, level="source") - steps.xs(b, level="source")).abs() / steps.xs(b, level="source")).rename(
        f"{a} vs {b}")


def plot(curves: dict, robot: str, dt: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(JOINT_ROLES), 2, figsize=(11, 8), sharex=True)
    styles = {REFERENCE: dict(color="black", lw=1.2, ls="--"), NO_ARMATURE: dict(color="grey", lw=1.0, ls=":")}
    for (name, role, kind, source), (q0, q) in curves.items():
        if name != robot:
            continue
        ax = axes[JOINT_ROLES.index(role), 0 if kind == "step" else 1]
        t = np.arange(1, len(q) + 1) * dt
        if source not in styles:  # engines: each drawn thinner than the one before, so equal curves all show
            styles[source] = dict(lw=max(1.0, 4.0 - 1.3 * (len(styles) - 2)), alpha=0.8)
        ax.plot(t, q - q0, label=source, **styles[source])
        ax.set_title(f"{role}: {kind}", fontsize=10)
        ax.set_ylabel("rad from settled")
    for ax in axes[-1]:
        ax.set_xlabel("s after the command")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"{load_robot(robot).title}, base fixed: joint response per engine and one-joint reference")
    return save_figure(fig, path, dpi=110)


def write_report(table: pd.DataFrame, curves: dict, config: ValidateConfig, command: str) -> Path:
    out = Path(config.out)
    dt = PhysicsConfig().dt
    lines = ["# Joint validation: engines against a one-joint model", "",
             f"Regenerate: `{command}`", "",
             "Each robot hangs with its base fixed; the front-right hip, thigh and calf in turn get a "
             f"{config.step_rad} rad step and a {config.sine_rad} rad, {config.sine_hz} Hz sinusoid on top of the default "
             "pose, tracked by the 200 Hz PD law with the robot's armature, damping and Coulomb friction "
             "(`robot.toml`). The reference integrates that joint alone (`benchmark/checks/validate.py`). Bullet has no "
             "joint armature: PyBullet emulates it with a rotor on each joint's parent link, geared to the joint "
             "(`ROTOR_GEAR` in `sims/pybullet.py`) with inertia armature / gear^2 (an approximation: the rotor also "
             "turns with its parent, coupling armature / gear into the joint above), and is compared with the same "
             "reference.",
             ""]
    for robot in config.robot:
        name = load_robot(robot).name
        path = out / "figures" / f"validation_{name}.png"
        plot(curves, name, dt, path)
        lines += [f"## {load_robot(robot).title}", "", f"![{name} joint responses](figures/{path.name})", ""]
        part = table[table.robot == name]
        steps = part[part.command == "step"].set_index(["joint", "source"])[["rise_ms", "overshoot_pct", "ss_error_rad"]]
        sines = part[part.command == "sine"].set_index(["joint", "source"])[["gain", "lag_deg"]]
        joined = steps.join(sines).join(part[part.command == "step"].set_index(["joint", "source"])[["wn", "zeta"]])
        lines += [to_markdown(joined.round(3).reset_index()), ""]
    lines += ["## Agreement (step rise time, relative difference)", ""]
    pairs = [(a, b) for a, b in (("newton", "mujoco"), ("pybullet", "mujoco"), ("mujoco", REFERENCE),
                                 ("newton", REFERENCE), ("pybullet", REFERENCE)) if {a, b} <= set(table.source)]
    if pairs:
        lines += [to_markdown(pd.concat([agreement(table, a, b) for a, b in pairs], axis=1).round(3).reset_index()), ""]
    path = out / "validation.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
    return path


def main(config: ValidateConfig, command: str = "bench validate") -> Path:
    from tqdm import tqdm

    total = len(config.robot) * len(config.sim) * len(JOINT_ROLES) * 2
    with tqdm(total=total, desc="validate", unit="run", file=sys.stderr, disable=None) as bar:
        table, curves = validate(config, bar.update)
    return write_report(table, curves, config, command)
