"""Plugins by entry point: another installed package registers an engine, a robot, a policy and a model, and
`bench` runs them without an edit to promptwalk. The package here is written into a folder with its own
`.dist-info` (what pip installs), put on PYTHONPATH, and found through `importlib.metadata`."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]

PLUGIN = '''
"""A tiny promptwalk plugin: an open-loop trot, a model that answers the oldest example, a copy of A1, MuJoCo again."""
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmark.common.settings import setting
from benchmark.llm.models import Reply
from benchmark.trial.registry import PolicyEntry
from sims import Engine

ROBOT_DIR = Path(__file__).parent / "a1copy"
ENGINE = Engine("mujoco-again", "MuJoCo (a plugin's record)", "sims.mujoco:MujocoSim", ("mujoco",))
POLICY = PolicyEntry("trot", "demo_plugin:TrotPolicy", "an open-loop sine trot (a plugin)",
                     settings="demo_plugin:TrotSettings")


@dataclass(frozen=True)
class TrotSettings:
    trot_amplitude: float = setting(0.3, "thigh and calf amplitude of the plugin trot (normalized)", minimum=0)


class TrotPolicy:
    name = "trot"

    def __init__(self, amplitude):
        self.amplitude, self.t = amplitude, 0

    @classmethod
    def from_cell(cls, cell, robot, resources):
        return cls(cell.settings.trot_amplitude)

    def reset(self, seed):
        self.t = 0

    def act(self, obs, state):
        self.t += 1
        phase = np.sin(2 * np.pi * self.t / 5)
        diagonal = np.array([1, -1, -1, 1]).repeat(3) * np.tile([0.0, 1.0, -1.0], 4)
        return self.amplitude * phase * diagonal

    def metrics(self):
        return {"trot_steps": self.t}

    def close(self):
        pass


class OldestModel:
    """Answers the oldest output line in the prompt."""

    id = "plugin:oldest"
    cacheable = False
    obeys_constraint = False
    reads_prompt = False

    @classmethod
    def from_spec(cls, name, **options):
        return cls()

    def complete(self, prompt, sampling, constraint, cold=False):
        lines = [line for line in prompt.splitlines() if line.startswith("Output: [")]
        return Reply(" " + (lines[0][len("Output: "):] if lines else "[]"), len(prompt.split()), 12, 0.0)

    def close(self):
        pass
'''

ENTRY_POINTS = '''
[promptwalk.engines]
mujoco-again = demo_plugin:ENGINE

[promptwalk.robots]
a1copy = demo_plugin:ROBOT_DIR

[promptwalk.policies]
trot = demo_plugin:POLICY

[promptwalk.models]
oldest = demo_plugin:OldestModel
'''


def _install(site: Path, entry_points: str = ENTRY_POINTS) -> dict:
    """Write the plugin as pip would install it into `site`; the environment for a `bench` that sees it."""
    (site / "demo_plugin").mkdir(parents=True)
    (site / "demo_plugin" / "__init__.py").write_text(textwrap.dedent(PLUGIN))
    robot = site / "demo_plugin" / "a1copy"
    shutil.copytree(ROOT / "robots" / "a1", robot, ignore=shutil.ignore_patterns("policy.*"))
    shutil.copy(ROOT / "robots" / "a1" / "policy.npz", robot / "policy.npz")
    info = site / "demo_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: demo-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(entry_points)
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}


def _bench(env: dict, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "benchmark.cli", *args], capture_output=True, text=True,
                          timeout=300, env=env, cwd=ROOT)


@pytest.fixture(scope="module")
def plugin_env(tmp_path_factory) -> dict:
    return _install(tmp_path_factory.mktemp("site"))


def test_bench_lists_and_explains_what_a_plugin_registers(plugin_env):
    listing = json.loads(_bench(plugin_env, "list", "--json").stdout)
    assert "mujoco-again" in listing["sims"] and "a1copy" in listing["robots"]
    assert "trot" in listing["policies"] and "oldest" in listing["models"]
    help_text = _bench(plugin_env, "run", "--help").stdout
    assert "--trot-amplitude" in help_text and "--policy trot: an open-loop sine trot" in help_text


def test_a_plugin_policy_runs_on_a_plugin_robot_and_engine(plugin_env):
    out = _bench(plugin_env, "run", "--policy", "trot", "--sim", "mujoco-again", "--robot", "a1copy", "--trials", "1",
                 "--duration", "2", "--trot-amplitude", "0.2", "--json")
    assert out.returncode == 0, out.stderr
    row = json.loads(out.stdout)
    assert (row["policy"], row["sim"], row["robot"], row["trot_amplitude"]) == ("trot", "mujoco-again", "a1copy", 0.2)
    assert row["trials"][0]["trot_steps"] == 20  # 2 s at 10 Hz: the plugin's own metric reached the row


def test_a_plugin_model_answers_through_the_llm_policy(plugin_env):
    out = _bench(plugin_env, "run", "--llm", "oldest", "--trials", "1", "--seed-start", "1", "--llm-after", "3",
                 "--history", "5", "--duration", "4", "--json")
    assert out.returncode == 0, out.stderr
    trial = json.loads(out.stdout)["trials"][0]
    assert trial["queries"] == 10 and trial["parse_failures"] == 0  # every reply was the oldest example, parsed


def test_a_broken_or_clashing_plugin_is_one_line(tmp_path):
    broken = _install(tmp_path / "a", ENTRY_POINTS.replace("trot = demo_plugin:POLICY", "trot = demo_plugin:NOT_THERE"))
    out = _bench(broken, "run", "--policy", "trot", "--duration", "1")
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "plugin policy 'trot' (demo_plugin:NOT_THERE" in out.stderr and len(out.stderr.strip().splitlines()) == 1
    clash = _install(tmp_path / "b", ENTRY_POINTS.replace("trot = demo_plugin:POLICY", "rl = demo_plugin:POLICY"))
    out = _bench(clash, "list")
    assert out.returncode == 2 and "takes the name of a built-in policy" in out.stderr
