"""Prompt strategies: one renderer for probe and closed loop, what each gives away, and the closed-loop diagnostics."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmark.evaluate.probe import ProbeRun, ProbeSetConfig, _prompts, answer_items, make_probe_set
from benchmark.llm.controller import LLMSettings, takeover_prompt
from benchmark.llm.encodings import get_encoding
from benchmark.llm.prompt import PromptConfig, build_prompt
from benchmark.llm.reference import HoldModel
from benchmark.llm.strategies import NEAREST_HEADER, STRATEGIES, gait_period, nearest_last, retrieval_pool
from benchmark.trial.cell import make_cell
from benchmark.trial.trials import KeepPolicy, run_cell

ROOT = Path(__file__).parents[1]
ENC = get_encoding("E5")
IDX = np.arange(33)


@pytest.fixture(scope="module")
def walk():
    """A seed-policy walk of A1 on flat ground, made with the shipped policy, as the probe set holds one."""
    probe = make_probe_set(ProbeSetConfig(cells=("a1/flat",), rollouts=1, items=3),
                           progress=lambda line: None)
    return probe


def _cell(strategy: str, model: str = "hold", **extra):
    return make_cell({"model": model, "prompt_strategy": strategy, "history": 10, "duration": 10.3, **extra})


@pytest.mark.parametrize("strategy", list(STRATEGIES))
def test_each_strategy_renders_the_same_text_in_probe_and_closed_loop(strategy, walk):
    """At the takeover the closed loop's prompt and the probe's first item come from the same seed-policy walk:
    the one renderer must write them identically (window, demonstration memory, order, headers)."""
    cell = make_cell({"model": "hold", "prompt_strategy": strategy, "history": 10})
    closed = takeover_prompt(cell)  # the prompt at 1 s + 10 pairs, read from a real rollout
    settings = dataclasses.replace(cell.settings, llm_after=10.0)
    run = ProbeRun(llm=settings, window="slide")
    probe_walk = walk.walks[0]
    # the probe's item at the same step as takeover_prompt's query: 10 pairs after the seed policy's start
    k = 10
    history = list(zip(probe_walk.observations[k - 10:k], probe_walk.actions[k - 10:k]))
    demonstrations = tuple(zip(probe_walk.observations[:k], probe_walk.actions[:k]))
    from benchmark.llm.controller import CONTROL_DT
    from benchmark.llm.prompt import describe_robot
    from robots import load_robot

    description = describe_robot(load_robot("a1"), run.llm.prompt, control_hz=1.0 / CONTROL_DT)
    opened = build_prompt(description, history, probe_walk.observations[k], run.llm.prompt, demonstrations)
    assert opened == closed
    if strategy in ("nearest", "nearest-only"):
        assert NEAREST_HEADER in closed


def test_probe_items_carry_only_pairs_from_before_the_takeover_as_memory(walk):
    run = ProbeRun(llm=LLMSettings(history=10, prompt_strategy="nearest-only"))
    for w, k, history, demonstrations, obs, label in _prompts(walk, run):
        assert len(demonstrations) == w.first_item < k + 1
        assert all(np.array_equal(d[0], w.observations[i]) for i, d in enumerate(demonstrations))
        assert not any(np.array_equal(obs, d[0]) for d in demonstrations)


def test_closed_loop_memory_is_frozen_at_the_takeover():
    """The demonstration memory holds the seed policy's pairs up to the takeover and nothing the LLM made."""
    cell = make_cell({"model": "knn", "prompt_strategy": "nearest-only", "history": 10, "seed_start": 1.0,
                      "llm_after": 3.0, "duration": 4.0})
    watch = KeepPolicy()
    run_cell(cell, [0], hooks=[watch])
    policy = watch.policy
    memory = policy._trial.demonstrations
    assert len(memory) == 20  # 1 s to 3 s at 10 Hz
    takeover = len(memory)
    assert all(a is b for (_, a), (_, b) in zip(memory, policy._trial.history[:takeover]))
    llm_actions = [a for _, a in policy._trial.history[takeover:]]
    assert len(llm_actions) == 10 and not any(any(a is m for _, m in memory) for a in llm_actions)


def test_hold_on_a_nearest_last_prompt_equals_knn(walk):
    """Nearest last means the prompt's last example line is its nearest: copying it is knn, in probe and closed loop."""
    for memory in ("window", "both"):
        settings = LLMSettings(history=10, prompt_strategy="nearest", memory=memory)
        run = ProbeRun(llm=settings)
        hold, knn = answer_items(walk, run, model=HoldModel()), answer_items(walk, run, model=_knn())
        assert np.array_equal(hold.errors, knn.errors)
        assert np.array_equal(hold.prompt_hold_errors, hold.prompt_knn_errors)
    rows = {m: run_cell(_cell("nearest", m, memory="both", llm_after=2.0, seed_start=1.0, duration=4.0), [0])[0]
            for m in ("hold", "knn")}
    assert rows["hold"].distance_m == rows["knn"].distance_m


def test_nearest_by_time_shows_the_same_examples_in_the_order_they_happened(walk):
    """The K nearest of nearest-only, oldest first: knn answers the same, copying the last line no longer does."""
    pool = [(np.full(33, v), np.full(12, v)) for v in (0.5, 0.1, 0.3, 0.2)]
    prompt = build_prompt("", [], np.zeros(33), PromptConfig(history=0, strategy="nearest-by-time", k=3), tuple(pool))
    outputs = [line for line in prompt.splitlines() if line.startswith("Output: ")]
    assert outputs == ["Output: " + ENC.encode(pool[i][1]) for i in (1, 2, 3)]  # pool order, not nearest last
    near, by_time = (ProbeRun(llm=LLMSettings(history=10, prompt_strategy=strategy))
                     for strategy in ("nearest-only", "nearest-by-time"))
    knn_near, knn_time = answer_items(walk, near, model=_knn()), answer_items(walk, by_time, model=_knn())
    np.testing.assert_array_equal(knn_near.errors, knn_time.errors)
    hold_time = answer_items(walk, by_time, model=HoldModel())
    assert not np.array_equal(hold_time.errors, knn_time.errors)
    np.testing.assert_array_equal(hold_time.prompt_knn_errors, knn_time.errors)  # the same-prompt knn is the nearest


def _knn():
    from benchmark.llm.reference import KnnModel

    return KnnModel()


def test_retrieval_orders_nearest_last_and_breaks_ties_by_age():
    pool = [(np.full(33, v), np.full(12, v)) for v in (0.5, 0.1, 0.3, 0.1)]
    chosen = nearest_last(pool, np.zeros(33), ENC, IDX, "l2", k=3)
    assert [float(o[0]) for o, _ in chosen] == [0.3, 0.1, 0.1]
    assert chosen[-1] is pool[1]  # of the two at 0.1 the older is nearest
    assert retrieval_pool(pool[:2], pool[2:], "window") == pool[:2]
    assert retrieval_pool(pool[:2], pool[2:], "both") == pool[2:] + pool[:2]


def test_cycle_puts_one_period_ago_just_above_the_query():
    period = 6
    window = [(np.full(33, float(i % period) / 10), np.full(12, float(i % period) / 10)) for i in range(20)]
    assert gait_period(np.array([a for _, a in window])) == period
    prompt = build_prompt("", window, np.zeros(33), PromptConfig(history=20, strategy="cycle"))
    assert prompt.splitlines()[-3] == "Output: " + ENC.encode(window[20 - period][1])
    assert HoldModel().reply_to(prompt) == ENC.encode(window[20 - period][1])


def test_bad_strategy_k_or_memory_is_one_line_and_exit_2():
    for args in (["--prompt-strategy", "best"], ["--retrieve-k", "0"], ["--memory", "everything"],
                 ["--distance", "cosine"]):
        out = subprocess.run([sys.executable, "-m", "benchmark.cli", "run", "--llm", "hold", *args],
                             capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, (args, out.stderr)
        assert "valid" in out.stderr or "> 0" in out.stderr


def test_diagnostics_of_reference_models_are_what_they_must_be():
    """`hold` repeats every action; `oracle` is 0 from the seed action; knn on the chronological prompt copies an
    example line on every reply."""
    def metrics(model: str) -> dict:
        return run_cell(_cell("chronological", model, seed_start=1.0, llm_after=3.0, duration=5.0), [0])[0].policy_metrics

    hold, oracle, knn = metrics("hold"), metrics("oracle"), metrics("knn")
    assert hold["repeat_fraction"] == 1.0 and hold["copy_fraction"] == 1.0
    assert oracle["oracle_distance_mean"] == 0.0 and oracle["repeat_fraction"] < 0.2
    assert knn["copy_fraction"] == 1.0 and 0 < knn["oracle_distance_mean"] < hold["oracle_distance_mean"]
    assert hold["demo_distance_mean"] == 0.0  # it repeats the last demonstration
    assert len(oracle["diag_llm_actions"]) == len(oracle["diag_seed_actions"]) == 20
    assert oracle["diag_llm_actions"] == oracle["diag_seed_actions"]
    json.dumps(oracle)  # a row's metrics stay JSON


def test_the_study_runs_its_probe_stage_and_closed_loop_into_one_store_and_reports_both(tmp_path):
    """`bench sweep` on an experiment with a [probe] table: probe rows and closed-loop trials in one store, resumed
    (nothing runs twice), and `bench report` writes the probe table, the diagnostics and their figures."""
    grid = tmp_path / "tiny_prompting.toml"
    grid.write_text('''
name = "tiny_prompting"
title = "tiny prompting study"
seeds = 1
[fixed]
robot = "a1"
duration = 11.0
seed_start = 1.0
llm_after = 10.0
history = 10
[grid]
controller = ["hold_nearest", "knn_nearest"]
[variants.controller]
hold_nearest = { policy = "llm", model = "hold", prompt_strategy = "nearest-only" }
knn_nearest = { policy = "llm", model = "knn", prompt_strategy = "nearest-only" }
[probe]
probe_set = "own_probe.npz"
cells = ["a1/flat"]
items = 2
grid = { model = ["hold", "knn"], prompt_strategy = ["chronological", "nearest-only"] }
''')
    store, bench = tmp_path / "store", [sys.executable, "-m", "benchmark.cli"]
    missing = subprocess.run([*bench, "sweep", str(grid), "--results", str(store), "--dry-run"], capture_output=True,
                             text=True, cwd=ROOT, timeout=300)
    assert missing.returncode == 2 and "probe.probe_set: no file" in missing.stderr
    assert "Traceback" not in missing.stderr and len(missing.stderr.strip().splitlines()) == 1
    made = subprocess.run([*bench, "probe", "--make", "--out", str(tmp_path / "own_probe.npz")], capture_output=True,
                          text=True, cwd=ROOT, timeout=300)
    assert made.returncode == 0, made.stderr
    digest = made.stdout.split("digest ")[1].split()[0]
    out = subprocess.run([*bench, "sweep", str(grid), "--results", str(store)], capture_output=True, text=True,
                         cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "4 run(s), 0 already stored" in out.stdout and "2 trial(s) run" in out.stdout
    again = subprocess.run([*bench, "sweep", str(grid), "--results", str(store), "--only", "prompt_strategy=chronological"],
                           capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert again.returncode == 0 and "0 run(s), 2 already stored" in again.stdout, again.stdout + again.stderr
    from benchmark.common.store import load_results

    frame = load_results(store)
    probes = frame[frame["kind"] == "probe"].set_index(["model", "prompt_strategy"])
    assert set(probes["probe_digest"]) == {digest}  # the experiment's own probe set, not the shipped one
    # hold on a nearest-last prompt is the prompt's own trivial answer: no gain; on the chronological one it is 0 skill
    assert probes.loc[("hold", "nearest-only"), "gain"] == 0.0
    assert probes.loc[("hold", "chronological"), "skill"] == 0.0
    knn = probes.loc[("knn", "chronological")]  # the knn model is the prompt's own knn answer, item by item
    assert knn["skill"] == knn["same_prompt_knn_skill"]
    assert knn["gain"] == pytest.approx(knn["skill"] - max(knn["same_prompt_hold_skill"], knn["skill"]))
    report = subprocess.run([*bench, "report", str(store), "--out", str(tmp_path / "reports")], capture_output=True,
                            text=True, cwd=ROOT, timeout=300)
    assert report.returncode == 0, report.stderr
    text = (tmp_path / "reports" / "tiny_prompting.md").read_text()
    assert "## Probe stage" in text and "## Closed-loop diagnostics" in text and "gain over the better" in text
    assert (tmp_path / "reports" / "figures" / "tiny_prompting_probe.png").is_file()
    assert "cached replies" in text  # reply-cache hits are counted beside the probe's s/query
    diagnostics = text.split("## Closed-loop diagnostics")[1]
    assert "| replies from the cache |" in diagnostics
    assert "| revisits (2-10 back) |" in diagnostics  # computed from the replies each trial stored
    # each trial stores the base's forward position per control step: the progress its walking test read
    for _, trial in frame[frame["kind"] != "probe"].iterrows():
        x = np.asarray(trial["traj_base_x"], dtype=float)
        takeover = int(round(trial["eval_start"] / trial["control_dt"])) - 1  # the state after the takeover's step
        assert len(x) == trial["control_steps"] and x[-1] - x[takeover] == pytest.approx(trial["distance_m"], abs=2e-4)
    assert (tmp_path / "reports" / "figures" / "tiny_prompting_progress.png").is_file()
    assert "![progress after the takeover](figures/tiny_prompting_progress.png)" in text
    assert "## The study" in text and "<!-- study table -->" in text
    hold_row = next(line for line in text.splitlines()
                    if line.startswith("| hold (the prompt's last example line) | nearest-only (K 3, demonstrations, l2) |"))
    assert f"| {probes.loc[('hold', 'nearest-only'), 'same_prompt_hold_skill']:.3f} |" in hold_row
    assert "| 1/1 [" in hold_row or "| 0/1 [" in hold_row


def test_a_probe_job_keeps_its_grid_place_and_the_mode_it_reads_with_under_only():
    """`--only` picks runs, not their place: a run's index (the report's row order) is its place in the whole grid;
    a growing window reads exactly, so the job (and its stored row) says sliding whatever `auto` resolves to."""
    from benchmark.evaluate.study import probe_jobs
    from benchmark.experiments.experiment import load_experiment

    experiment = load_experiment("prompting")
    every = probe_jobs(experiment, "digest")
    picked = probe_jobs(experiment, "digest", only={"model": "qwen2.5-coder-0.5b"})
    assert [j.index for j in picked] == [j.index for j in every if j.llm.model == "qwen2.5-coder-0.5b"]
    assert [j.id for j in picked] == [j.id for j in every if j.llm.model == "qwen2.5-coder-0.5b"]
    assert picked[0].index > 0 and {j.llm.history_mode for j in every} == {"sliding"}


def test_the_study_table_joins_probe_and_closed_loop_and_says_what_is_missing():
    """One row per model and prompt: the probe's skill and gain, the closed loop with its Wilson interval, the
    exact-history variant as its own row, planned rows 'not run yet' (or partial), probe-only strategies as such."""
    import pandas as pd

    from benchmark.experiments.report_prompting import study_table

    def trial(model, strategy, mode, success):
        return {"policy": "llm", "model": model, "prompt_strategy": strategy, "history_mode": mode, "success": success,
                "nwt": 1.0 if success else 0.5, "distance_m": 9.0, "latency_mean_s": 2.0, "repeat_fraction": 0.1,
                "copy_fraction": 0.7}

    trials = pd.DataFrame([trial("qwen2.5-coder-0.5b", "nearest-only", "shifted", True),
                           trial("qwen2.5-coder-0.5b", "nearest-only", "shifted", False),
                           trial("qwen2.5-coder-0.5b", "nearest-only", "sliding", True),
                           {**trial("hold", "nearest-only", "sliding", True), "latency_mean_s": 0.0}])
    probe = {"skill": 0.5, "skill_low": 0.4, "skill_high": 0.6, "gain": -0.1, "gain_low": -0.2, "gain_high": 0.0,
             "same_prompt_hold_skill": 0.61, "same_prompt_knn_skill": 0.62}
    near = "nearest-only (K 3, demonstrations, l2)"
    probes = pd.DataFrame([{"model": "qwen2.5-coder-0.5b", "strategy": near, **probe},
                           {"model": "qwen2.5-coder-0.5b", "strategy": "cycle", **probe}])
    planned = pd.DataFrame([{"policy": "llm", "model": "embedded", "prompt_strategy": "chronological",
                             "history_mode": "shifted", "trials": 10},
                            {"policy": "llm", "model": "qwen2.5-coder-0.5b", "prompt_strategy": "nearest-only",
                             "history_mode": "shifted", "trials": 2},
                            {"policy": "llm", "model": "qwen2.5-coder-0.5b", "prompt_strategy": "nearest-only",
                             "history_mode": "sliding", "trials": 10}])
    table = study_table(trials, probes, planned).set_index(["model", "prompt"])
    shifted = table.loc[("Qwen2.5-Coder 0.5B", near)]
    assert shifted["success [95%]"].startswith("1/2 [0.09,") and shifted["closed loop: NWT"] == "0.75"
    assert "partial" not in shifted["success [95%]"]  # all its planned trials are stored
    assert shifted["gain over the prompt's trivial answer [95%]"] == "-0.100 [-0.200, +0.000]"
    exact = table.loc[("Qwen2.5-Coder 0.5B", near + " (exact history)")]
    assert exact["success [95%]"].startswith("1/1") and exact["probe skill [95%]"] == "-"
    assert exact["success [95%]"].endswith("(partial: 1 of 10 trials)")
    assert table.loc[("Qwen2.5-Coder 0.5B", "cycle"), "closed loop: NWT"] == "probe only"
    assert table.loc[("Gemma 3 270M", "chronological"), "closed loop: NWT"] == "not run yet"
    hold = table.loc[("hold (the prompt's last example line)", near)]
    assert hold["probe skill [95%]"] == "0.610" and hold["s / query"] == "-"


def test_bench_latency_measures_each_prompt_strategy():
    """`bench latency --strategies` gives one row per strategy; nearest-only reads a shorter prompt than the paper's."""
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "latency", "--llm", "hold", "--histories", "10",
                          "--modes", "sliding", "--strategies", "chronological", "nearest-only", "--queries", "2",
                          "--no-drift", "--json"], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    rows = {r["strategy"]: r for r in json.loads(out.stdout)["rows"]}
    assert set(rows) == {"chronological", "nearest-only"} and all(r["queries"] == 2 for r in rows.values())
    assert rows["nearest-only"]["prompt_tokens"] < rows["chronological"]["prompt_tokens"]
    bad = subprocess.run([sys.executable, "-m", "benchmark.cli", "latency", "--strategies", "closest"],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert bad.returncode == 2 and "closest" in bad.stderr and "Traceback" not in bad.stderr


def test_the_diagnostics_table_counts_replies_read_back_from_the_cache():
    """A resumed trial's cached replies are counted per row (its s / query covers the live ones only); a row whose
    trials did not count them says so with "-"."""
    from benchmark.experiments.report_prompting import diagnostics_table

    trials = pd.DataFrame({"controller": ["a", "a", "b"], "success": [1.0, 1.0, 0.0], "nwt": [1.0, 1.0, 0.1],
                           "queries": [100, 100, 100], "cache_hits": [98, 0, None], "repeat_fraction": [0.0, 0.0, 1.0]})
    table = diagnostics_table(trials, "controller").set_index("controller")
    assert table.loc["a", "replies from the cache"] == "98/200" and table.loc["b", "replies from the cache"] == "0/100"
    assert diagnostics_table(trials.drop(columns="cache_hits"), "controller")["replies from the cache"].eq("-").all()


def test_revisits_tell_a_model_looping_its_own_lines_from_one_that_freezes_or_writes_new_actions():
    """A reply that returns to one of the model's own replies 2-10 queries back (not the last one) is a revisit: a
    3-line loop revisits nearly always, a frozen reply and a stream of new actions never do."""
    from benchmark.experiments.report_prompting import diagnostics_table, revisit_fraction

    a, b, c = [0.1] * 12, [0.2] * 12, [0.3] * 12
    assert revisit_fraction([a, b, c] * 10) == pytest.approx(27 / 30)  # every reply from the fourth on
    assert revisit_fraction([a] * 30) == 0.0  # freezing is a repeat, not a revisit
    assert revisit_fraction([[0.01 * i] * 12 for i in range(30)]) == 0.0
    far = [[0.01 * i] * 12 for i in range(11)]
    assert revisit_fraction(far + [far[0]]) == 0.0  # 11 back is beyond the window
    assert revisit_fraction(None) is None and revisit_fraction([]) is None
    trials = pd.DataFrame({"controller": ["loop", "loop", "freeze"], "success": [0.0] * 3, "nwt": [0.0] * 3,
                           "repeat_fraction": [0.0, 0.0, 1.0],
                           "diag_llm_actions": [[a, b] * 5, [a, b, c] * 10, [a] * 9]})
    table = diagnostics_table(trials, "controller").set_index("controller")
    assert table.loc["loop", "revisits (2-10 back)"] == pytest.approx(round((0.8 + 0.9) / 2, 3))
    assert table.loc["freeze", "revisits (2-10 back)"] == 0.0
