"""The shipped seed policies walk with a natural gait: near the default stance, left-right symmetric,
diagonal feet together (the examples an LLM learns from are these)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmark.trial.mlp import MlpActor
from benchmark.checks.gait import GaitConfig, contact_summary, joint_table, record, summary_row
from robots import available_robots, load_robot

# The posture targets of the README's "Seed policies": mean hip abduction within 0.25 rad of default,
# mirrored left/right joint means within 0.2 rad, a trot (diagonal feet together).
MAX_MIRROR_GAP = 0.2


FIXED_COMMAND_POLICIES = [r for r in available_robots() if MlpActor.load(load_robot(r).folder / "policy.npz").symmetric]


@pytest.mark.parametrize("robot_name, hold", [(r, r not in FIXED_COMMAND_POLICIES) for r in available_robots()])
def test_shipped_policy_trots_near_the_default_stance(robot_name, hold):
    """At the fixed command for policies trained for it (both shipped ones); a policy trained before the fixed
    command is held to the targets on its steered walk, as they were set."""
    robot, q, contacts, falls = record(GaitConfig(trials=2, duration=8.0, heading_hold=hold), robot_name)
    assert falls == [None, None]
    summary = summary_row(robot, q, contacts)
    assert summary["max_hip_offset"] <= 0.25, joint_table(robot, q)
    assert summary["max_mirror_gap"] <= MAX_MIRROR_GAP, joint_table(robot, q)
    assert summary["diagonal_sync"] > summary["lateral_sync"] + 0.1, summary
    assert 0.3 < summary["stance_fraction"] < 0.9, summary


def test_contact_summary_tells_a_trot_from_a_bound():
    trot = np.array([[1, 0, 0, 1], [0, 1, 1, 0]] * 10, dtype=bool)
    bound = np.array([[1, 1, 0, 0], [0, 0, 1, 1]] * 10, dtype=bool)
    assert contact_summary(trot)["diagonal_sync"] == 1.0 and contact_summary(trot)["lateral_sync"] == 0.0
    assert contact_summary(bound)["diagonal_sync"] == 0.0 and contact_summary(bound)["lateral_sync"] == 1.0
    table = joint_table(load_robot("a1"), np.tile(load_robot("a1").default_pose, (5, 1)))
    assert np.allclose(table.offset, 0) and np.allclose(table.mirror_gap, 0)  # the default pose is symmetric
