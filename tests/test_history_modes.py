"""History modes: which one runs, with which llama.cpp settings, and the drift report of the approximation."""

from __future__ import annotations

import pytest

from benchmark.trial.cell import CellSpec, make_cell
from benchmark.trial.resources import Resources, Runtime
from benchmark.llm.controller import LLMPolicy, LLMSettings
from benchmark.common.settings import SettingError
from robots import load_robot


def test_auto_resolves_per_model_and_rows_record_the_mode_that_ran():
    assert LLMSettings().history_mode == "shifted" and LLMSettings().approximate
    assert LLMSettings(model="openai:gpt-4o").history_mode == "sliding"
    assert LLMSettings(model="knn").history_mode == "sliding"
    # a window-less prompt has no window to shift: it is read exactly; a windowed retrieval prompt still shifts
    assert LLMSettings(prompt_strategy="nearest-only").history_mode == "sliding"
    assert not LLMSettings(model="qwen2.5-coder-0.5b", prompt_strategy="nearest-only").approximate
    assert LLMSettings(prompt_strategy="nearest").history_mode == "shifted"
    assert LLMSettings(prompt_strategy="nearest-only", history_mode="shifted").history_mode == "shifted"
    cell = make_cell({"policy": "llm"})
    assert cell.params()["history_mode"] == "shifted"
    with pytest.raises(SettingError, match="history_mode 'shifted' needs the embedded model"):
        make_cell({"policy": "llm", "model": "openai:gpt-4o", "history_mode": "shifted"})


@pytest.mark.parametrize("mode, reuse", [("shifted", 64), ("sliding", 0), ("block", 0)])
def test_each_mode_gets_the_llamacpp_settings_it_needs(mode, reuse):
    resources = Resources(Runtime(threads=1))
    try:
        cell = CellSpec(policy="llm", settings=LLMSettings(history_mode=mode))
        policy = LLMPolicy.from_cell(cell, load_robot("a1"), resources)
        embedded = policy.model.inner  # under the reply cache
        assert embedded.cache_reuse == reuse and ("kv-shift" in embedded.id) == (reuse > 0)
        assert embedded.threads == 1 and embedded.id.endswith(":ngram-draft")  # n-gram drafting by default
    finally:
        resources.close()


@pytest.mark.slow
def test_the_drift_report_compares_every_reply_with_a_cold_recompute(capsys):
    from benchmark.llm.latency import measure

    rows = measure("embedded", [5], ["sliding", "shifted"], queries=2)
    assert "bench: latency cell 2/2 (history 5, shifted, draft ngram)" in capsys.readouterr().err  # not a terminal
    sliding, shifted = rows
    assert (sliding["mode"], shifted["mode"]) == ("sliding", "shifted") and shifted["approximate"]
    for row in rows:
        assert row["queries"] == 2 and 0.0 <= row["identical_to_cold"] <= 1.0
        assert row["action_diff_vs_cold"] is None or row["action_diff_vs_cold"] >= 0.0
    assert "outcome_changed" in shifted and "outcome_changed" not in sliding


@pytest.mark.slow
def test_ngram_drafting_is_measured_against_decoding_without_it():
    from benchmark.llm.latency import measure

    drafted, plain = measure("embedded", [5], ["shifted"], queries=2, drift=False, drafts=("ngram", "none"))
    assert (drafted["draft"], plain["draft"]) == ("ngram", "none") and "same_as_no_draft" not in plain
    assert drafted["same_as_no_draft"] >= 1 / 2  # greedy drafting keeps the reply (batch effects aside)


@pytest.mark.slow
def test_a_trial_answers_the_same_after_another_trial_as_alone():
    """A sweep worker keeps one model for many trials; each trial's first query reuses nothing cached, so
    the previous trial's keys and values cannot flip its replies. (Without that, this trial reused the
    previous one's 457-token description and its first reply differed.)"""
    import dataclasses

    from benchmark.trial.trials import KeepPolicy, run_cell

    cell = make_cell({"policy": "llm", "history": 10, "llm_after": 2.0, "duration": 2.2})  # shifted, 2 queries
    one_query = dataclasses.replace(cell, duration=2.1)
    runtime = Runtime(cache=False)

    def replies(before: bool) -> list:
        resources, watch = Resources(runtime), KeepPolicy()
        try:
            if before:
                run_cell(one_query, [0], resources)
            run_cell(cell, [1], resources, hooks=[watch])
            return [q.reply for q in watch.policy.queries]
        finally:
            resources.close()

    after_another, alone = replies(before=True), replies(before=False)
    assert len(alone) == 2 and [r.text for r in after_another] == [r.text for r in alone]
    assert after_another[0].cached_tokens == 0  # nothing of trial 0 was reused
    assert after_another[1].cached_tokens > 0  # within a trial the cache still works
