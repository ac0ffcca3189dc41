"""The realtime clock: the simulation does not wait for the model."""

from __future__ import annotations

import numpy as np
import pytest

from benchmark.trial.cell import make_cell
from benchmark.trial.trials import KeepPolicy, TrialHooks, run_cell
from benchmark.trial.clock import RealtimeClock, parse_latency
from benchmark.common.settings import SettingError

LLM_CELL = {"policy": "llm", "history": 10, "duration": 13.0, "llm_after": 10.0}
SAME = ("nwt", "success", "upright_fraction", "distance_m", "lateral_drift_m", "mean_vx", "heading_change_rad",
        "fall_time", "control_steps", "queries", "parse_failures")


@pytest.mark.parametrize("model", ["knn", "replay", "oracle"])
def test_realtime_at_latency_zero_equals_paused_trial_for_trial(model):
    paused = run_cell(make_cell({**LLM_CELL, "model": model}), [0, 1])
    realtime = run_cell(make_cell({**LLM_CELL, "model": model, "clock": "realtime", "latency": "0"}), [0, 1])
    for a, b in zip(paused, realtime):
        one, other = a.to_dict(), b.to_dict()
        assert {k: one[k] for k in SAME} == {k: other[k] for k in SAME}
        assert set(other["held_steps"]) == {1}


class Applied(TrialHooks):
    """The targets the robot actually got, every control step."""

    def start(self, seed, sim, policy, episode):
        self.actions = []
        return lambda loop: self.actions.append(loop.action.copy())


def test_a_fixed_latency_of_0_3_s_holds_each_reference_target_3_steps_and_the_history_is_what_happened():
    applied, kept = Applied(), KeepPolicy()
    cell = make_cell({**LLM_CELL, "model": "knn", "clock": "realtime", "latency": "0.3"})
    result = run_cell(cell, [0], hooks=[applied, kept])[0]
    held = result.policy_metrics["held_steps"]
    assert held[:-1] == [3] * (len(held) - 1) and 1 <= held[-1] <= 3, held
    assert result.policy_metrics["query_latencies_s"] == [0.3] * result.policy_metrics["queries"]
    history = kept.policy._trial.history
    # the history holds every step from the seed policy's start at 1 s (step 10): the targets applied
    np.testing.assert_array_equal(np.array([a for _, a in history]), np.array(applied.actions[10:]))
    llm_phase = np.array(applied.actions[100:])
    changes = np.flatnonzero(np.any(np.diff(llm_phase, axis=0) != 0, axis=1)) + 1
    assert all(c % 3 == 0 for c in changes), changes  # targets change only when an answer arrives


def test_the_seed_policys_action_delay_runs_on_the_same_clock():
    delayed = run_cell(make_cell({"policy": "rl", "duration": 3.0, "action_delay": 0.2}), [0])[0]
    assert set(delayed.policy_metrics["held_steps"][:-1]) == {2}
    assert run_cell(make_cell({"policy": "rl", "duration": 3.0}), [0])[0].policy_metrics == {}


def test_clock_and_latency_parsing():
    assert parse_latency("measured") is None and parse_latency("0.25") == 0.25
    for bad in ("-0.1", "fast", "nan"):
        with pytest.raises(SettingError, match="latency must be"):
            parse_latency(bad)
    clock = RealtimeClock(None)  # measured: each answer's own wall time
    clock.reset(np.zeros(2))
    answers = iter([(np.ones(2), 0.25), (2 * np.ones(2), 0.05)])
    out = [clock.step(t / 10, lambda: next(answers)).copy() for t in range(4)]
    assert [o[0] for o in out] == [0.0, 0.0, 0.0, 1.0]  # 0.25 s: arrives before the step at 0.3 s


def test_a_clock_that_was_never_asked_reports_no_lists():
    """A trial that falls before the takeover asks nothing: None, not [] (which a store would write as text and
    a snapshot could not mix with the other rows' numeric lists)."""
    clock = RealtimeClock(0.3)
    clock.reset(np.zeros(12))
    metrics = clock.metrics()
    assert metrics["query_latencies_s"] is None and metrics["held_steps"] is None


@pytest.mark.slow
def test_measured_latency_reads_the_prompt_once_before_the_clock_and_never_uses_the_reply_cache(tmp_path,
                                                                                               monkeypatch):
    """The embedded model on the real clock: an untimed read before the takeover, so the first timed query
    reuses it (reads only what is new); no reply (and its latency) comes from, or goes to, the reply cache."""
    from benchmark.trial.resources import Resources, Runtime
    from benchmark.llm.models import CACHE_ENV

    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    cell = make_cell({"policy": "llm", "history": 3, "duration": 2.6, "llm_after": 2.0, "clock": "realtime",
                      "latency": "measured"})
    kept, resources = KeepPolicy(), Resources(Runtime())
    try:
        result = run_cell(cell, [0], resources, hooks=[kept])[0]
    finally:
        resources.close()
    queries = kept.policy.queries
    assert result.policy_metrics["warmup_s"] > 0 and queries, result.policy_metrics
    assert queries[0].reply.cached_tokens > 0  # the warm-up's prefix, not a cold read
    assert not any(q.reply.cached for q in queries) and not any(tmp_path.rglob("*.json"))


def test_the_real_clock_section_reads_the_committed_realtime_store():
    """The committed embedded-model rows on the real clock: the report says when, how fast, and how far off."""
    from pathlib import Path

    import pandas as pd

    from benchmark.experiments.report_latency import realtime_section

    frame = pd.read_parquet(Path(__file__).parents[1] / "reports" / "data" / "realtime.parquet")
    text = "\n".join(realtime_section(frame))
    assert "## On the real clock (measured latency)" in text and "real-time factor" in text
    assert text.count("| a1 | flat |") == len(frame) and "faster" in text


@pytest.mark.parametrize(("budget", "says"), [(0.1, "budget here is 0.1 s"), (0.0, "budget here is 0 s: even one held"),
                                              (None, "has no latency budget")])
def test_a_budget_of_zero_seconds_is_a_budget_not_a_missing_one(budget, says, monkeypatch):
    from pathlib import Path

    import pandas as pd

    import benchmark.experiments.report_latency as report_latency

    monkeypatch.setattr(report_latency, "seed_policy_budget", lambda robot, terrain: budget)
    frame = pd.read_parquet(Path(__file__).parents[1] / "reports" / "data" / "realtime.parquet")
    assert says in "\n".join(report_latency.realtime_section(frame))
