"""The `bench` command as a user runs it: a real process, real engines."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "benchmark.cli", *args], capture_output=True, text=True, timeout=300)


def test_run_json_reports_trials_and_means():
    out = bench("run", "--sim", "pybullet", "--robot", "anymal", "--terrain", "rough", "--policy", "stand",
                "--trials", "2", "--duration", "2", "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert (result["sim"], result["robot"], result["terrain"], result["policy"]) == ("pybullet", "anymal", "rough", "stand")
    assert [t["seed"] for t in result["trials"]] == [0, 1]
    assert result["upright_fraction"] == 1.0 and result["success_rate"] == 0.0 and result["nwt"] <= 0.1
    assert {"nwt", "success", "upright_fraction", "distance_m", "mean_vx", "fall_time", "heading_change_rad",
            "walk_window_s"} <= set(result["trials"][0])


def test_run_table_is_readable():
    out = bench("run", "--policy", "stand", "--trials", "1", "--duration", "1")
    assert out.returncode == 0, out.stderr
    assert "mean NWT 0.000, success rate 0.00, upright 1.00" in out.stdout


def test_list_names_everything():
    from benchmark.llm.models import MODEL_FORMS
    from benchmark.trial.registry import available_policies
    from robots import available_robots
    from sims import available_sims

    listing = json.loads(bench("list", "--json").stdout)
    assert listing == {"sims": available_sims(), "robots": available_robots(), "terrains": ["flat", "rough"],
                       "policies": available_policies(), "models": list(MODEL_FORMS)}
    assert {"mujoco", "newton", "pybullet"} <= set(listing["sims"]) and {"a1", "anymal"} <= set(listing["robots"])


def test_perf_reports_both_loops_and_their_ratio():
    out = bench("perf", "--sim", "mujoco", "--robot", "a1", "--steps", "20", "--rounds", "1", "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["raw_steps_per_s"] > 0 and result["framework_steps_per_s"] > 0
    assert result["ratio"] == pytest.approx(result["framework_steps_per_s"] / result["raw_steps_per_s"])


@pytest.mark.parametrize("args,expected", [
    (["run", "--sim", "gazebo"], "unknown simulator 'gazebo'; valid: mujoco, newton, pybullet"),
    (["run", "--robot", "spot"], "unknown robot 'spot'; valid: a1, anymal"),
    (["run", "--terrain", "stairs"], "unknown terrain 'stairs'; valid: flat, rough"),
    (["run", "--policy", "gpt9"], "unknown policy 'gpt9'; valid: llm, rl, stand"),
    (["run", "--duration", "5"], "llm_after (10 s) must be before the end of the episode (duration 5 s)"),
    (["run", "--encoding", "E9"], "unknown encoding 'E9'; valid: E1, E2, E3, E4, E5"),
    (["run", "--llm", "gpt5"], "unknown model 'gpt5'; valid: embedded, embedded:PATH.gguf, openai:MODEL"),
    (["run", "--llm", "embedded:/tmp/nope.gguf"], "model file '/tmp/nope.gguf' not found"),
    (["run", "--policy", "rl", "--history", "10"], "'history' does not apply to policy 'rl'"),
    (["run", "--device", "cpu"], "'device' does not apply to simulator 'mujoco'"),
    (["sweep", "cross_engine", "--set", "history=abc", "--dry-run"], "setting 'history' expects an integer"),
    (["sweep", "cross_engine", "--only", "controler=rl", "--dry-run"], "--only: unknown setting 'controler'; valid:"),
    (["train", "--init-from", "/tmp/nope.npz"], "--init-from '/tmp/nope.npz' not found"),
    (["train", "--reward", "speed=2"], "unknown reward term 'speed'"),
    (["train", "--rough-share", "1.5"], "--rough-share must be between 0 and 1, got 1.5"),
    (["sweep", "normalization", "--set", "encoding=E9", "--dry-run"], "unknown encoding 'E9'"),
    (["sweep", "history", "--workers", "0"], "argument --workers: must be > 0, got 0"),
    (["run", "--duration", "-1"], "argument --duration: must be > 0, got -1"),
    (["run", "--trials", "two"], "argument --trials: expected a int, got 'two'"),
    (["perf", "--sim", "gazebo"], "unknown simulator 'gazebo'"),
])
def test_bad_input_is_one_clear_line_and_exit_2(args, expected):
    out = bench(*args)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], out.stderr
    assert out.stdout == ""
