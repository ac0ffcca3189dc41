"""A user's mistakes, as a table: each is one line on stderr, exit code 2, and nothing on stdout.

Every invocation stops before any trial runs, so the table takes seconds per row at most."""

from __future__ import annotations

import subprocess
import sys

import pytest

NOPE = "/tmp/promptwalk-no-such-file"
MISTAKES = [
    # unknown names
    (["run", "--sim", "gazebo"], "unknown simulator 'gazebo'"),
    (["run", "--robot", "spot"], "unknown robot 'spot'"),
    (["run", "--terrain", "stairs"], "unknown terrain 'stairs'"),
    (["run", "--policy", "gpt9"], "unknown policy 'gpt9'"),
    (["run", "--encoding", "E9"], "unknown encoding 'E9'"),
    (["run", "--observation", "O7"], "unknown observation 'O7'"),
    (["run", "--prompt-parts", "task", "jokes"], "unknown prompt parts 'jokes'"),
    (["run", "--history-mode", "rolling"], "unknown history mode 'rolling'"),
    (["run", "--llm", "gpt5"], "unknown model 'gpt5'"),
    (["run", "--llm-layout", "grpc"], "unknown layout 'grpc'"),
    (["run", "--llm-server", "tgi"], "unknown server 'tgi'"),
    (["run", "--sim", "newton", "--solver", "xpbd"], "unknown newton solver 'xpbd'"),
    (["run", "--sim", "newton", "--device", "tpu"], "unknown device 'tpu'"),
    (["run", "--sim", "newton", "--contacts", "physx"], "unknown newton contact pipeline 'physx'"),
    (["validate", "--sim", "gazebo"], "unknown simulator 'gazebo'"),
    (["validate", "--robot", "spot"], "unknown robot 'spot'"),
    (["gait", "--robot", "spot"], "unknown robot 'spot'"),
    (["gait", "--robot", "a1", "anymal", "--policy-file", "x.npz"], "--policy-file needs exactly one --robot"),
    (["perf", "--sim", "gazebo"], "unknown simulator 'gazebo'"),
    (["prompt", "--robot", "spot"], "unknown robot 'spot'"),
    (["ship", "x.npz", "--robot", "spot"], "unknown robot 'spot'"),
    (["sweep", "nope"], "no experiment file 'nope'"),
    (["sweep"], "name an experiment"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
    # bad types and values
    (["run", "--trials", "two"], "argument --trials: expected a int, got 'two'"),
    (["run", "--trials", "0"], "argument --trials: must be > 0, got 0"),
    (["run", "--duration", "-1"], "argument --duration: must be > 0, got -1"),
    (["run", "--history", "-3"], "history must be >= 0"),
    (["run", "--history", "ten"], "argument --history: expected a int, got 'ten'"),
    (["run", "--temperature", "-0.5"], "temperature must be >= 0"),
    (["run", "--duration", "5"], "llm_after (10 s) must be before the end of the episode (duration 5 s)"),
    (["run", "--seed-start", "12"], "seed_start (12 s) must not be after llm_after (10 s)"),
    (["run", "--price-in", "-1"], "price_in must be >= 0"),
    (["sweep", "history", "--workers", "0"], "argument --workers: must be > 0, got 0"),
    (["sweep", "cross_engine", "--set", "history=abc", "--dry-run"], "setting 'history' expects an integer"),
    (["sweep", "cross_engine", "--set", "constrained=maybe", "--dry-run"], "setting 'constrained' expects a boolean"),
    (["sweep", "cross_engine", "--set", "hsitory=10", "--dry-run"], "--set: unknown setting 'hsitory'; valid:"),
    (["sweep", "cross_engine", "--only", "controler=rl", "--dry-run"], "--only: unknown setting 'controler'; valid:"),
    (["sweep", "cross_engine", "--only", "controller", "--dry-run"], "--only expects KEY=VALUE, got 'controller'"),
    (["sweep", "cross_engine", "--set", "history", "--dry-run"], "--set expects KEY=VALUE, got 'history'"),
    (["train", "--reward", "speed=2"], "unknown reward term 'speed'"),
    (["train", "--ppo", "lr=1e-4"], "unknown PPO setting 'lr'"),
    (["train", "--reward", "forward=fast"], "--reward expects TERM=NUMBER, got 'forward=fast'"),
    (["train", "--rough-share", "1.5"], "--rough-share must be between 0 and 1, got 1.5"),
    (["train", "--steps", "-5"], "argument --steps: must be > 0, got -5"),
    (["train", "--sim", "gazebo"], "unknown simulator 'gazebo'"),
    (["latency", "--llm", "gpt5"], "unknown model 'gpt5'"),
    # options that do not apply
    (["run", "--policy", "rl", "--history", "10"], "'history' does not apply to policy 'rl'"),
    (["run", "--policy", "stand", "--llm", "hold"], "'model' does not apply to policy 'stand'"),
    (["run", "--device", "cpu"], "'device' does not apply to simulator 'mujoco'"),
    (["run", "--sim", "pybullet", "--solver", "mujoco"], "'solver' does not apply to simulator 'pybullet'"),
    (["run", "--llm", "openai:gpt-4o", "--history-mode", "shifted"], "history_mode 'shifted' needs the embedded"),
    # missing files and bad paths
    (["run", "--llm", f"embedded:{NOPE}.gguf"], f"model file '{NOPE}.gguf' not found"),
    (["run", "--policy", "rl", "--policy-file", f"{NOPE}.npz"], f"no seed policy for robot 'a1' at {NOPE}.npz"),
    (["train", "--init-from", f"{NOPE}.npz"], f"--init-from '{NOPE}.npz' not found"),
    (["ship", f"{NOPE}.npz", "--robot", "a1"], f"'{NOPE}.npz' not found"),
    (["view", f"{NOPE}.rrd"], f"recording '{NOPE}.rrd' not found"),
    (["report", NOPE], "no results at"),
    (["run", "--robot", NOPE], f"unknown robot '{NOPE}'"),
    (["sweep", f"{NOPE}.toml"], f"no experiment file '{NOPE}.toml'"),
]


def test_the_table_is_large():
    assert len(MISTAKES) >= 40


@pytest.mark.parametrize("args, message", MISTAKES, ids=[" ".join(a)[:60] for a, _ in MISTAKES])
def test_a_mistake_is_one_line_and_exit_2(args, message):
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", *args], capture_output=True, text=True, timeout=120)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2, out.stderr
    assert len(lines) == 1 and lines[0].startswith("bench: error: ") and message in lines[0], out.stderr
    assert out.stdout == ""


def test_a_results_path_that_is_a_file_is_refused_before_anything_runs(tmp_path):
    target = tmp_path / "copy.parquet"
    target.write_text("")
    for extra in (["--dry-run"], []):
        out = subprocess.run([sys.executable, "-m", "benchmark.cli", "sweep", "normalization", "--only", "policy=rl",
                              "--results", str(target), *extra], capture_output=True, text=True, timeout=120)
        assert out.returncode == 2 and "is a file; give a directory" in out.stderr, out.stderr
