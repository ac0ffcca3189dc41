"""No silence on long work: lines while a long prompt is read, and an ETA from the recent rate."""

from __future__ import annotations

import io
import re
import sys
import time

from benchmark.cli.trial_commands import _QueryBar
from benchmark.llm.controller import LLMPolicy, LLMSettings
from benchmark.llm.models import Reply
from benchmark.llm.progress import PromptReading, RecentRate
from benchmark.llm.reference import knn_answer
from benchmark.trial.runner import EpisodeConfig, run_trial
from robots import load_robot
from sims import make_sim
from sims.terrain import Terrain


class SleepyModel:
    """A model that takes `cold_s` over its first (cold) prompt and `warm_s` over each later one."""

    id = "test:sleepy"

    def __init__(self, cold_s: float, warm_s: float) -> None:
        self.cold_s, self.warm_s = cold_s, warm_s

    def complete(self, prompt, sampling, constraint, cold=False) -> Reply:
        seconds = self.cold_s if cold else self.warm_s
        time.sleep(seconds)
        tokens = len(prompt) // 2
        return Reply(knn_answer(prompt), tokens, 50, cached_tokens=0 if cold else tokens - 300, latency_s=seconds)

    def close(self) -> None:
        pass


def test_a_long_read_prints_a_line_then_one_every_few_seconds_with_an_estimate_once_known():
    out = io.StringIO()
    reading = PromptReading(min_tokens=100, every_s=0.2, stream=out)
    prompt = "Input: [1, 2, 3]\n" * 200
    with reading.reading(prompt, cold=True):
        time.sleep(0.7)
    lines = out.getvalue().splitlines()
    assert "reading a prompt of about" in lines[0] and "(cold)" in lines[0] and "no estimate yet" in lines[0]
    assert sum("still reading the prompt" in line for line in lines) >= 2, lines
    reading.learn(prompt, prompt_tokens=1500, new_tokens=1500, seconds=0.7)
    out.truncate(0)
    with reading.reading(prompt, cold=True):
        pass
    assert re.search(r"about 1,500 new tokens \(cold\); about 1 s at the 2143 tok/s", out.getvalue()), out.getvalue()
    out.truncate(0)
    with reading.reading(prompt + "Input: [4]\n", cold=False):  # only the new pair: short, no line
        pass
    assert out.getvalue().strip("\x00") == ""
    slid = "Input: [9, 9, 9]\n" + prompt[len("Input: [1, 2, 3]\n"):]  # the window moved: no common prefix
    with reading.reading(slid, cold=False):  # a model that rereads it: a long read
        pass
    assert "reading a prompt of about" in out.getvalue()
    out.truncate(0)
    out.seek(0)
    with reading.reading(prompt, cold=False, shifted=True):  # KV-cache shifting moves the window: no line
        pass
    assert out.getvalue() == ""


def test_recent_rate_forgets_a_slow_start():
    rate = RecentRate(window=3)
    for done, now in enumerate([100.0, 101.0, 102.0, 103.0, 104.0], start=1):
        rate.add(done, now)
    assert rate.eta(10) == 10.0


class _Lines(io.StringIO):
    def __init__(self) -> None:
        super().__init__()
        self.stamped: list[tuple[float, str]] = []

    def write(self, text: str) -> int:
        if text.strip():
            self.stamped.append((time.monotonic(), text.strip()))
        return len(text)

    def isatty(self) -> bool:
        return False


def test_the_eta_after_a_slow_cold_query_is_within_2x_of_the_truth(monkeypatch):
    """A 3 s cold query, then 0.1 s queries: the ETA printed after it must not carry the cold query."""
    stream = _Lines()
    monkeypatch.setattr(sys, "stderr", stream)
    robot, terrain = load_robot("a1"), Terrain("flat")
    sim = make_sim("mujoco", robot, terrain)
    settings = LLMSettings(model="hold", history=5, seed_start=0.0, llm_after=0.5)
    policy = LLMPolicy(robot, settings, model=SleepyModel(cold_s=3.0, warm_s=0.1))
    episode = EpisodeConfig(duration=3.0, eval_start=0.5)
    on_step = _QueryBar(every_s=0.0).start(0, sim, policy, episode)
    run_trial(sim, robot, terrain, policy, episode, seed=0, on_step=on_step)
    end = time.monotonic()
    sim.close()
    etas = [(t, float(m.group(1))) for t, line in stream.stamped if (m := re.search(r"ETA (\d+) s", line))]
    assert len(etas) > 10, stream.stamped[:5]
    for at, eta in etas[6:-3]:  # once the window holds warm queries only
        truth = end - at
        assert truth / 2 <= max(eta, 0.5) <= 2 * truth + 0.5, (eta, truth)


def test_probe_progress_eta_is_the_runs_mean_rate_and_counts_from_a_resumed_item(monkeypatch, capsys):
    """10 s an item from the start: at 10 of 30 the ETA is 20 items x 10 s; a run resumed at item 10 counts from
    there, not from 0."""
    from benchmark.evaluate import probe

    clock = [0.0]
    monkeypatch.setattr(probe.time, "monotonic", lambda: clock[0])
    for first in (1, 11):
        progress = probe.ProbeProgress(every=10)
        for done in range(first, 31):
            clock[0] += 10.0
            progress(done, 30)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "bench: probe: 10/30 items, ETA 3.3 min" and lines[2] == "bench: probe: 30/30 items"
    assert lines[3] == "bench: probe: 20/30 items, ETA 1.7 min"


def test_policies_that_share_a_loaded_model_share_its_reading_rate(capsys):
    """A sweep builds a policy per trial over one loaded model: the second trial's cold read gives an estimate."""
    robot, model = load_robot("a1"), SleepyModel(cold_s=0.0, warm_s=0.0)
    first, second = (LLMPolicy(robot, LLMSettings(model="hold"), model=model) for _ in range(2))
    assert first.reading is second.reading
    first.reading.learn("x" * 3000, prompt_tokens=3000, new_tokens=3000, seconds=10.0)
    with second.reading.reading("Input: [1]\n" * 400, cold=True):
        pass
    assert "at the 300 tok/s read before" in capsys.readouterr().err
    assert LLMPolicy(robot, LLMSettings(model="hold"), model=SleepyModel(0.0, 0.0)).reading is not first.reading
