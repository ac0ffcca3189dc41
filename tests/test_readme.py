"""Every command in the README and the docs runs as written (shortened where a flag allows), or says why not.

Commands are the indented code lines starting with `bench ` (or `$ bench `) in README.md and docs/*.md.
A command missing from ADAPT fails the test, so a new recipe cannot land untested."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
STORE = ROOT / "reports" / "data" / "cross_engine.parquet"
# README command -> (extra arguments appended, replacements of words, or a reason it is not run here)
ADAPT: dict[str, tuple[list[str], dict[str, str]] | str] = {
    "bench run --policy rl": (["--trials", "2", "--duration", "2"], {}),
    "bench run --duration 2.5 --llm-after 2 --trials 1": "runs in tests/test_llm_models.py (test_llm_run_end_to_end_on"
                                                         "_the_embedded_model: this command, with --record and --json)",
    "bench run --llm oracle --trials 2": ([], {}),
    "bench run --llm openai:gpt-4o --llm-layout chat --price-in 2.5 --price-out 10":
        "needs an OpenAI key and network; the HTTP path is tested on loopback in test_llm_models.py",
    "bench run --llm openai:m --llm-url http://127.0.0.1:8080/v1":
        "needs a server on port 8080; test_llm_models.py runs the same path against llama.cpp on loopback",
    "bench prompt --history 50 --tokenizer gpt-4": ([], {}),
    "bench latency --histories 10 50": (["--queries", "1", "--modes", "block", "--no-drift", "--drafts", "ngram"],
                                        {"10": "3", "50": "5"}),
    "bench list": ([], {}),
    "bench run --sim pybullet --robot anymal --terrain rough --policy rl": (["--trials", "1", "--duration", "2"], {}),
    "bench run --policy stand --duration 5 --json": (["--trials", "2"], {}),
    "bench run --sim newton --device cpu --policy rl": (["--trials", "1", "--duration", "0.5"], {}),
    "bench perf --sim mujoco --robot a1": (["--steps", "20", "--rounds", "1"], {}),
    "bench perf --sim newton --worlds 64": (["--steps", "2", "--rounds", "1"], {"64": "4"}),
    "bench train --robot a1 --steps 1000000": (["--eval-every", "2048"], {"1000000": "2048"}),
    "bench run --policy rl --policy-file runs/train-a1/policy.npz": (["--trials", "1", "--duration", "2"], {}),
    "bench sweep normalization --workers 2": (["--dry-run"], {}),
    "bench report results/normalization": ([], {"results/normalization": str(STORE)}),
    "bench run --policy rl --record walk.rrd": (["--trials", "2", "--duration", "1"], {}),
    "bench view walk.rrd": "opens a window; test_recorder.py reads the same file back and serves it with --web",
    "bench view walk.rrd --web": "serves until stopped; test_recorder.py runs it on loopback",
    "bench eval --llm knn": (["--store", "leaderboard"], {}),
    "bench probe --llm embedded --items 2": (["--cells", "a1/flat", "--history", "5"], {"2": "1"}),
    "bench models": ([], {}),
    "bench leaderboard": (["--store", "leaderboard", "--out", "reports"], {}),
    "bench run --llm knn --clock realtime --latency 0.3": (["--trials", "1", "--duration", "11"], {}),
    "bench run --policy rl --action-delay 0.2": (["--trials", "1", "--duration", "2"], {}),
    "bench sweep latency --workers 2": (["--dry-run"], {}),
    "bench straight": (["--sim", "mujoco", "--trials", "1", "--duration", "3", "--out", "straight"], {}),
    "bench sweep cross_engine --only controller=rl sim=mujoco --workers 2": (["--dry-run"], {}),
    "bench sweep cross_engine --only controller=rl sim=pybullet robot=a1 --workers 1": (["--dry-run"], {}),
    "bench sweep cross_engine --only controller=rl sim=pybullet robot=anymal --workers 1": (["--dry-run"], {}),
    "bench sweep cross_engine --only controller=rl sim=newton --seeds 5 --workers 2": (["--dry-run"], {}),
    "bench report results/cross_engine": (["--out", "cross"], {"results/cross_engine": str(STORE)}),
    "bench probe --llm knn --history 10": (["--items", "2"], {}),
    "bench run --sim gazebo": "an example of a mistake: exit code 2 is checked in test_mistakes.py",
    "bench report results/cross_engine --format html": (["--out", "html"], {"results/cross_engine": str(STORE)}),
    "bench sweep --list": ([], {}),
    "bench sweep matrix --workers 2 --only controller=oracle": (["--dry-run"], {}),
    "bench sweep hard_track --workers 2 --only controller=knn_nearest_only": (["--dry-run"], {}),
    "bench sweep matrix --only controller=qwen15_nearest_only --seeds 5": (["--dry-run"], {}),
    "bench sweep walking_normalization --dry-run": ([], {}),
    "bench sweep matrix --stage probe --threads 2": (["--dry-run"], {}),
    "bench sweep hard_track --stage probe --threads 2": (["--dry-run"], {}),
    "bench probe --make --sim mujoco --cells a1/flat/weak_motors anymal/flat/weaker_motors --out probe_hard_mujoco.npz":
        ([], {}),
    "bench probe --make --sim pybullet --out probe_pybullet.npz": "walks 12 seed-policy trials; tests/test_probe.py "
                                                                  "makes a one-walk PyBullet set and scores it",
    "bench probe --probe probe_pybullet.npz --llm qwen2.5-coder-1.5b --prompt-strategy nearest-only --history 50":
        "an optional model on the set the command above makes (~20 min a cell set)",
    "bench sweep walking_description --stage probe --threads 2": "scores two Qwen rungs on five variants (~40 min; "
                                                                 "optional models)",
    "bench sweep walking_description --stage closed-loop --only controller=qwen15 description=E1 --threads 2":
        (["--dry-run"], {}),
    "bench report reports/data/walking_history": (["--out", "walking"], {"reports/data/walking_history": str(
        ROOT / "reports/data/walking_history")}),
    "bench report reports/data/matrix": (["--out", "matrix"], {"reports/data/matrix": str(ROOT / "reports/data/matrix")}),
    "bench report reports/data/hard_track": (["--out", "hard"], {"reports/data/hard_track": str(ROOT / "reports/data/hard_track")}),
    "bench run --llm knn --prompt-strategy nearest-only --disturbance weak_motors": (["--trials", "1"], {}),
    "bench sweep cross_engine --only controller=rl --workers 2": (["--dry-run"], {}),
    "bench sweep history --executor ray --ray-address ray://head:10001": "needs a Ray cluster; test_sweep.py runs "
                                                                          "the ray executor on a local instance",
    "bench sweep history --set model=openai:gpt-4o layout=chat --rate-limit 60 --workers 8": (["--dry-run"], {}),
    "bench sweep normalization --dry-run": ([], {}),
    "bench run --llm qwen2.5-coder-0.5b --prompt-strategy nearest-only --trials 1":
        (["--duration", "10.5"], {"qwen2.5-coder-0.5b": "knn"}),  # the ladder's model is an optional extra
    "bench run --llm qwen2.5-coder-1.5b --prompt-strategy nearest-only --trials 1":
        "the 0.5B line above with a larger optional model (1.2 GB, 15 min a trial); the study ran it 10 times",
    "bench probe --llm knn --prompt-strategy nearest --cells a1/flat": (["--items", "2"], {}),
    "bench run": "the main job (500 queries of the embedded model); its path runs shortened as "
                 "'bench run --duration 2.5 --llm-after 2 --trials 1'",
    "bench eval --llm knn --prompt-strategy nearest-only": (["--store", "leaderboard"], {}),
    "bench run --llm qwen2.5-coder-1.5b --prompt-strategy nearest-only --trials 1 --record qwen15.rrd":
        (["--duration", "10.5"], {"qwen2.5-coder-1.5b": "knn"}),  # the ladder's model is an optional extra
    "bench render qwen15.rrd --out clip.gif --video-from 7 --video-to 17": ([], {}),  # the recording just above
    "bench run --llm knn --prompt-strategy nearest-only --trials 2 --video walk.gif": (["--duration", "10.5"], {}),
    "bench sweep prompting --dry-run": ([], {}),
    "bench report reports/data/prompting --out study": ([], {"reports/data/prompting": str(ROOT / "reports" / "data"
                                                                                          / "prompting")}),
    "bench render walk.rrd --out walk.mp4": ([], {}),  # the recording of `bench run --policy rl --record walk.rrd`
    "bench throughput --llm qwen2.5-coder-1.5b --concurrency 1 2 4 --queries 10":
        "runs in tests/test_lockstep.py on the embedded model (the ladder's are optional extras): N = 1 and 2, both "
        "draft settings",
    "bench throughput --llm qwen2.5-coder-1.5b --settings default fast --concurrency 1":
        "runs in tests/test_lockstep.py on the embedded model: the default and fast settings side by side",
    "bench throughput --llm qwen2.5-coder-1.5b --settings default fast --concurrency 1 --queries 100 --threads 2":
        "runs in tests/test_lockstep.py on the embedded model: the default and fast settings side by side",
}


def readme_commands() -> list[str]:
    """The commands shown in README.md and in the docs pages, in order, each once."""
    commands = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for line in page.read_text().splitlines():
            if line.startswith(("    bench ", "    $ bench ")):
                for part in line.split("#")[0].replace("$ ", "", 1).split("&&"):
                    commands.append(" ".join(part.split()))
    return list(dict.fromkeys(commands))


def test_the_readme_stays_short():
    """Results first, the rest in the docs: at most 200 lines."""
    assert len((ROOT / "README.md").read_text().splitlines()) <= 200


def test_every_readme_command_is_covered():
    missing = [c for c in readme_commands() if c not in ADAPT]
    assert not missing, f"README commands without a test entry: {missing}"
    assert len(readme_commands()) >= 15


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """One folder for the whole recipe, so training writes runs/train-a1 where the evaluation reads it."""
    return tmp_path_factory.mktemp("readme")


SLOW = ("bench latency", "bench run --duration 2.5", "bench probe --llm embedded", "bench run --sim newton",
        "bench perf --sim newton", "bench train", "bench throughput",  # over 30 s on 2 cores: `-m "not slow"` skips
        "bench run --policy rl --policy-file")  # evaluates what the slow `bench train` recipe wrote
RUNNABLE = [pytest.param(c, marks=[pytest.mark.slow] if c.startswith(SLOW) else [], id=c[6:50])
            for c in readme_commands() if isinstance(ADAPT.get(c), tuple)]


@pytest.mark.parametrize("command", RUNNABLE)
def test_readme_command_runs(command, workdir, monkeypatch):
    extra, replace = ADAPT[command]
    words = [replace.get(w, w) for w in shlex.split(command)[1:]] + extra
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", *words], cwd=workdir, capture_output=True,
                         text=True, timeout=600, env={**__import__("os").environ,
                                                      "PROMPTWALK_CACHE": str(workdir / "cache")})
    assert out.returncode == 0, f"{' '.join(words)}\n{out.stderr[-2000:]}"
    assert out.stdout.strip() or re.search(r"\S", out.stderr)
