"""Newton specifics: many worlds per call, devices, and agreement with MuJoCo."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from robots import load_robot
from sims import make_sim, make_worlds
from sims.base import PhysicsConfig
from sims.terrain import Terrain


def test_worlds_step_independently_with_their_own_seeds():
    robot = load_robot("a1")
    worlds = make_worlds("newton", robot, Terrain("flat"), worlds=3)
    worlds.reset([0, 1, 0])
    states = worlds.states()
    np.testing.assert_allclose(states[0].joint_pos, states[2].joint_pos, atol=1e-6)
    assert not np.allclose(states[0].joint_pos, states[1].joint_pos, atol=1e-3)
    targets = np.tile(robot.default_pose, (3, 1))
    targets[1, 1] += 0.4  # only world 1's FR thigh moves
    for _ in range(5):
        worlds.step(targets)
    after = worlds.states()
    assert after[1].joint_pos[1] - after[0].joint_pos[1] > 0.2
    np.testing.assert_allclose(after[0].joint_pos, after[2].joint_pos, atol=1e-4)
    assert all(s.foot_contact.all() and not s.fall_contact for s in (after[0], after[2]))


@pytest.mark.slow
def test_standing_matches_mujoco_within_3_cm(make):
    heights = {}
    for engine in ("mujoco", "newton"):
        sim = make(engine, "anymal", "rough")
        state = sim.reset(0)
        for _ in range(30):
            state = sim.step(sim.robot.default_pose)
        heights[engine] = state.base_pos[2]
    assert abs(heights["mujoco"] - heights["newton"]) < 0.03, heights


def test_devices_and_solvers_are_checked():
    robot, flat = load_robot("a1"), Terrain("flat")
    with pytest.raises(ValueError, match="option 'device' does not apply to simulator 'mujoco'"):
        make_sim("mujoco", robot, flat, options={"device": "cuda"})
    with pytest.raises(ValueError, match="unknown newton solver 'xpbd'; valid: featherstone, mujoco"):
        make_sim("newton", robot, flat, options={"solver": "xpbd"})
    with pytest.raises(ValueError, match="steps one world"):
        make_worlds("pybullet", robot, flat, worlds=2)


@pytest.mark.slow
def test_perf_reports_one_and_many_worlds():
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "perf", "--sim", "newton", "--worlds", "4",
                          "--steps", "3", "--rounds", "1", "--json"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert [row["worlds"] for row in result["by_worlds"]] == [1, 4]
    assert all(row["raw_steps_per_s"] > 0 and row["framework_steps_per_s"] > 0 for row in result["by_worlds"])


def test_an_odd_number_of_substeps_ends_in_the_state_it_began_in():
    """A control period swaps two state buffers per substep; with an odd count the result is
    copied back, so that a captured CUDA graph can be replayed. The physics must not notice."""
    robot = load_robot("a1")
    odd = make_worlds("newton", robot, Terrain("flat"), worlds=2, physics=PhysicsConfig(substeps=3))
    single = make_worlds("newton", robot, Terrain("flat"), worlds=2, physics=PhysicsConfig(substeps=1))
    targets = np.tile(robot.default_pose, (2, 1))
    targets[:, 1] += 0.3
    for worlds in (odd, single):
        worlds.reset([4, 5])
    buffer = odd._state
    for _ in range(4):
        odd.step(targets)
        for _ in range(3):
            single.step(targets)
    assert odd._state is buffer
    for a, b in zip(odd.states(), single.states()):
        np.testing.assert_allclose(a.joint_pos, b.joint_pos, atol=1e-6)
        np.testing.assert_allclose(a.base_pos, b.base_pos, atol=1e-6)


@pytest.mark.slow
def test_seed_policy_walks_rough_ground_on_newtons_own_contacts(capfd):
    """Newton's CollisionPipeline on the heightfield (the default): the shipped A1 policy walks, and the
    feet it reports on the ground come from Newton's contacts (mujoco_warp's own heightfield contacts
    dropped them and the robots tipped over: mujoco_warp issue #1083)."""
    from benchmark.trial.cell import CellSpec
    from benchmark.trial.resources import Resources
    from benchmark.trial.trials import run_cell
    from benchmark.checks.gait import SubstepTrace

    cell = CellSpec(sim="newton", robot="a1", terrain="rough", policy="rl", duration=6.0)
    inner = make_sim("newton", load_robot("a1"), Terrain("rough"), PhysicsConfig(substeps=1))
    assert inner.worlds.pipeline is not None
    trace = SubstepTrace(inner, PhysicsConfig().substeps)
    resources = Resources()
    resources.use_sim(cell, trace)
    trial = run_cell(cell, [0], resources)[0]
    assert trial.success and trial.fall_time is None and trial.distance_m > 3.0, trial
    stance = np.array(trace.contacts)[200:].mean(axis=0)  # after the first second
    assert np.all((stance > 0.1) & (stance < 0.95)), stance  # every foot steps: on the ground part of the time
    out, err = capfd.readouterr()
    assert "overflow" not in out + err  # no contact dropped for want of room (nor printed into --json output)
