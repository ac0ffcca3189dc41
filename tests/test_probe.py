"""The imitation probe, the ladder and the scorecards: what they score, and what they refuse."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from benchmark.llm.controller import LLMSettings
from benchmark.llm.models import Reply, make_model
from benchmark.evaluate.probe import (DEFAULT_PROBE, ProbeError, ProbeRun, ProbeSet, ProbeSetConfig, answer_items,
                             answer_walks, load_probe_set, make_probe_set, paired_comparison, save_probe_set, skill,
                             summarize_answers)

BENCH = [sys.executable, "-m", "benchmark.cli"]


@pytest.fixture(scope="module")
def probe() -> ProbeSet:
    return load_probe_set(DEFAULT_PROBE)


def _run(history: int = 10, items: int | None = 4) -> ProbeRun:
    return ProbeRun(llm=LLMSettings(model="hold", history=history), items=items)


@pytest.mark.parametrize("model, expected", [("hold", 0.0), ("oracle", 1.0)])
def test_hold_scores_0_and_oracle_1_on_every_cell_by_construction(probe, model, expected):
    answers = answer_items(probe, _run(items=None), model=make_model(model, cache=False))
    summary = summarize_answers(answers)
    assert len(summary["cells"]) == 4 and summary["items"] == probe.items()
    for cell, c in summary["cells"].items():
        assert c["skill"] == pytest.approx(expected, abs=1e-12), cell
    assert summary["parse_failures"] == 0


class NoisyLabels:
    """Answers the seed policy's action plus Gaussian noise of `sigma` action units, written in the encoding."""

    privileged = True
    obeys_constraint = False
    reads_prompt = False

    def __init__(self, sigma: float) -> None:
        self.id, self.sigma, self.rng, self.answer = f"test:noisy{sigma}", sigma, np.random.default_rng(0), "[]"

    def set_reference(self, action, encoding) -> None:
        self.answer = encoding.encode(action + self.rng.normal(0.0, self.sigma, len(action)))

    def complete(self, prompt, sampling, constraint, cold=False) -> Reply:
        return Reply(" " + self.answer, 10, 10)

    def close(self) -> None:
        pass


def test_labels_plus_noise_score_between_hold_and_oracle_monotone_in_the_noise(probe):
    skills = [summarize_answers(answer_items(probe, _run(), model=NoisyLabels(s)))["skill"] for s in (0.1, 0.4, 0.8)]
    assert 1.0 > skills[0] > skills[1] > skills[2], skills
    assert skills[1] > 0.0  # noise of a third of hold's error still beats freezing


def test_paired_comparison_and_bootstrap_interval(probe):
    good = answer_items(probe, _run(), model=NoisyLabels(0.2))
    bad = answer_items(probe, _run(), model=NoisyLabels(0.6))
    assert paired_comparison(good, bad) > 0.975 and paired_comparison(bad, good) < 0.025
    summary = summarize_answers(good)
    assert summary["skill_low"] <= summary["skill"] <= summary["skill_high"]
    assert skill(good.hold_errors, good.hold_errors, np.array(good.cells)) == 0.0


def test_grow_window_shares_the_prefix_and_slide_keeps_the_length(probe):
    seen = []

    class Recorder(NoisyLabels):
        def complete(self, prompt, sampling, constraint, cold=False):
            seen.append((prompt, cold))
            return super().complete(prompt, sampling, constraint, cold)

    answer_items(probe, dataclasses.replace(_run(items=3), cells=("a1/flat",)), model=Recorder(0.0))
    first, second = seen[0][0], seen[1][0]
    assert second.startswith(first[:first.rindex("Input:")]) and seen[0][1] and not seen[1][1]
    assert second.count("\nOutput: [") == first.count("\nOutput: [") + 1  # one true pair more
    seen.clear()
    answer_items(probe, dataclasses.replace(_run(items=3), window="slide", cells=("a1/flat",)), model=Recorder(0.0))
    assert seen[0][0].count("\nOutput: [") == seen[1][0].count("\nOutput: [") == 10


def test_a_stopped_probe_resumes_walk_by_walk_and_asks_nothing_twice(probe, tmp_path, monkeypatch):
    """A probe of hours (a big model) saves every finished walk; run again, it asks only the rest."""
    import benchmark.evaluate.probe as probe_module

    asked = []

    class Counting(NoisyLabels):
        def complete(self, prompt, sampling, constraint, cold=False):
            asked.append(prompt)
            if stop_after is not None and len(asked) > stop_after:
                raise KeyboardInterrupt
            return super().complete(prompt, sampling, constraint, cold)

    monkeypatch.setattr(probe_module, "probe_model", lambda run, runtime: Counting(0.3))
    run, partial = _run(items=2), tmp_path / "partial.json"
    stop_after = 5  # 2 items a walk: stopped inside the third walk
    with pytest.raises(KeyboardInterrupt):
        answer_walks(probe, run, partial=partial)
    assert len(json.loads(partial.read_text())["walks"]) == 2
    asked.clear()
    stop_after = None
    resumed = answer_walks(probe, run, partial=partial)
    assert len(asked) == 2 * (len(probe.walks) - 2) and len(resumed.errors) == 2 * len(probe.walks)
    fresh = answer_walks(probe, run, partial=None)
    np.testing.assert_array_equal(resumed.hold_errors, fresh.hold_errors)
    assert resumed.cells == fresh.cells and resumed.joint_errors.shape == (2 * len(probe.walks), 12)


def test_a_server_answering_garbage_is_parse_failures_not_a_crash(probe):
    from test_llm_models import CannedServer

    server = CannedServer(text="I am a language model and cannot walk.")
    try:
        run = dataclasses.replace(_run(items=2), llm=LLMSettings(model="openai:m", url=server.url, history=10),
                                  cells=("a1/flat",))
        from benchmark.trial.resources import Runtime

        summary = summarize_answers(answer_items(probe, run, Runtime(cache=False)))
    finally:
        server.close()
    assert summary["parse_failures"] == summary["items"] == 6
    assert summary["skill"] == pytest.approx(0.0)  # an unparseable reply holds the last action, as in closed loop


def test_replies_from_the_on_disk_cache_are_counted(probe, tmp_path, monkeypatch):
    """The second read of the same prompts comes from the reply cache, and the summary says how many did."""
    from test_llm_models import CannedServer

    monkeypatch.setenv("PROMPTWALK_CACHE", str(tmp_path))
    server = CannedServer(text=" [" + ", ".join(["50"] * 12) + "]")
    try:
        run = dataclasses.replace(_run(items=2), llm=LLMSettings(model="openai:m", url=server.url, history=10),
                                  cells=("a1/flat",))
        first, second = (summarize_answers(answer_items(probe, run)) for _ in range(2))
    finally:
        server.close()
    assert first["items"] == second["items"] == 6
    assert (first["cached_replies"], second["cached_replies"]) == (0, 6)


def test_a_probe_file_of_another_version_or_corrupt_is_one_line(tmp_path, probe):
    path = save_probe_set(probe, tmp_path / "probe.npz")
    assert load_probe_set(path).digest == probe.digest
    other = ProbeSet(probe.walks, {**probe.meta, "version": 99}, probe.digest)
    save_probe_set(other, tmp_path / "v99.npz")
    broken = tmp_path / "broken.npz"
    broken.write_bytes(path.read_bytes()[:5000])
    tampered = ProbeSet((dataclasses.replace(probe.walks[0], actions=probe.walks[0].actions + 1e-3),
                         *probe.walks[1:]), probe.meta, probe.digest)
    save_probe_set(tampered, tmp_path / "tampered.npz")
    for name, message in (("v99.npz", "version 99 probe set"), ("broken.npz", "not a probe set"),
                          ("tampered.npz", "is corrupt"), ("missing.npz", "no probe set")):
        with pytest.raises(ProbeError, match=message):
            load_probe_set(tmp_path / name)
        out = subprocess.run([*BENCH, "probe", "--llm", "hold", "--probe", str(tmp_path / name)], capture_output=True,
                             text=True, timeout=120)
        assert out.returncode == 2 and out.stderr.count("\n") == 1 and message in out.stderr, out.stderr


def test_the_probe_set_is_made_by_a_command_and_its_digest_is_stable(tmp_path):
    config = ProbeSetConfig(cells=("a1/flat",), rollouts=1, items=2)
    one, two = make_probe_set(config, progress=lambda _: None), make_probe_set(config, progress=lambda _: None)
    assert one.digest == two.digest and one.items() == 2
    assert one.walks[0].observations.shape == (92, 33) and one.walks[0].actions.shape == (92, 12)


def test_a_probe_set_is_one_engines_and_says_which(tmp_path):
    """The same cell walked in PyBullet is another probe set (other numbers, another digest), and it names its engine;
    `--sim` without `--make` is one line, since scoring reads the engine from the set."""
    config = ProbeSetConfig(cells=("a1/flat",), rollouts=1, items=2)
    mujoco = make_probe_set(config, progress=lambda _: None)
    bullet = make_probe_set(dataclasses.replace(config, sim="pybullet"), progress=lambda _: None)
    assert (mujoco.meta["config"]["sim"], bullet.meta["config"]["sim"]) == ("mujoco", "pybullet")
    assert bullet.digest != mujoco.digest and not np.allclose(bullet.walks[0].actions, mujoco.walks[0].actions)
    path = save_probe_set(bullet, tmp_path / "bullet.npz")
    out = subprocess.run([*BENCH, "probe", "--llm", "hold", "--probe", str(path)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and f"probe {bullet.digest} (pybullet)" in out.stdout, out.stderr
    wrong = subprocess.run([*BENCH, "probe", "--llm", "hold", "--sim", "pybullet"], capture_output=True, text=True,
                           timeout=120)
    assert wrong.returncode == 2 and wrong.stderr.count("\n") == 1 and "--sim goes with --make" in wrong.stderr


def test_bench_eval_quick_tier_prints_a_scorecard_and_does_not_rerun(tmp_path):
    store = tmp_path / "board"
    out = subprocess.run([*BENCH, "eval", "--llm", "knn", "--store", str(store)], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert "knn (reference), quick tier" in out.stdout and "skill" in out.stdout
    row = json.loads(next((store / "rows").glob("*.json")).read_text())
    assert row["probe_digest"] == load_probe_set().digest and row["fingerprint_id"] and row["versions"]["numpy"]
    assert 0.0 < row["probe"]["skill"] < 1.0 and set(row["probe"]["cells"]) == set(load_probe_set().cells)
    again = subprocess.run([*BENCH, "eval", "--llm", "knn", "--store", str(store)], capture_output=True, text=True,
                           timeout=300)
    assert again.returncode == 0 and "not run again" in again.stderr
    board = subprocess.run([*BENCH, "leaderboard", "--store", str(store), "--out", str(tmp_path)], capture_output=True,
                           text=True, timeout=120)
    assert board.returncode == 0 and "| knn | chronological | reference |" in (tmp_path / "leaderboard.md").read_text()


@pytest.mark.parametrize("argv, message", [
    (["eval", "--llm", "gpt-9"], "unknown model 'gpt-9'"),
    (["eval", "--llm", "knn", "--tier", "huge"], "unknown tier 'huge'"),
    (["eval", "--llm", "knn", "--cells", "a1/ice"], "unknown cell 'a1/ice'"),
    (["eval", "--llm", "qwen2.5-coder-1.5b"], "bench models --assemble qwen2.5-coder-1.5b"),
])
def test_bad_eval_input_is_one_line_and_exit_2(argv, message, tmp_path, monkeypatch):
    monkeypatch.setenv("PROMPTWALK_MODELS", str(tmp_path))
    out = subprocess.run([*BENCH, *argv, "--store", str(tmp_path / "board")], capture_output=True, text=True,
                         timeout=120, env={**__import__("os").environ, "PROMPTWALK_MODELS": str(tmp_path)})
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and message in out.stderr, out.stderr


def test_a_ladder_file_with_the_wrong_sha256_is_refused_naming_the_expected_one(tmp_path, monkeypatch):
    from benchmark.llm import ladder

    monkeypatch.setenv("PROMPTWALK_MODELS", str(tmp_path))
    fake = ladder.KnownModel("tiny", "tiny", "1", "none", "tiny.gguf", 8, "ab" * 32, "tiny")
    monkeypatch.setitem(ladder.LADDER, "tiny", fake)
    (tmp_path / "tiny.gguf").write_bytes(b"GGUF\x03\x00\x00\x00")
    with pytest.raises(ladder.LadderError, match=f"expected {'ab' * 32}"):
        ladder.resolve("tiny")
    (tmp_path / "tiny.gguf").write_bytes(b"GGUF")
    with pytest.raises(ladder.LadderError, match="truncated"):
        ladder.resolve("tiny")


def test_the_default_pose_reference_answers_action_zero_in_the_prompts_encoding(probe):
    from benchmark.llm.encodings import get_encoding

    run = dataclasses.replace(_run(items=2), cells=("a1/flat",))
    answers = answer_items(probe, run, model=make_model("default", cache=False))
    enc = get_encoding(run.llm.encoding)
    walk = probe.walks[0]
    labels = [enc.quantize(a) for a in walk.actions[walk.first_item:walk.first_item + 2]]
    expected = [np.abs(enc.quantize(np.zeros(12)) - label).mean() for label in labels]
    np.testing.assert_allclose(answers.errors[:2], expected)
    assert answers.parsed.all()


def test_a_full_tier_row_made_with_another_seed_policy_is_scored_again(tmp_path, monkeypatch, capsys):
    """A closed-loop row records the seed policy its trials ran; once another policy ships, `bench eval` runs
    its trials again (keeping the probe, which the probe set fixes) instead of answering 'already scored'."""
    import benchmark.experiments.sweep as sweep
    from benchmark.evaluate.scorecard import evaluate

    suite = tmp_path / "tiny.toml"
    suite.write_text('name = "tiny"\nversion = 1\n[tiers.t]\nprobe = { history = 10, items = 2 }\n'
                     'closed_loop = { cells = ["a1/flat"], trials = 1, sim = "mujoco", history = 10, duration = 11.0 }\n')
    store = tmp_path / "board"
    first = evaluate(LLMSettings(model="hold"), "t", suite, store)
    shipped = sweep.shipped_seed_policy_sha256("a1")
    assert first["seed_policy_sha256"] == {"a1": shipped} and first["closed_loop"]["a1/flat"]["trials"] == 1
    assert evaluate(LLMSettings(model="hold"), "t", suite, store)["made_at"] == first["made_at"]  # not run again
    assert "not run again" in capsys.readouterr().err

    monkeypatch.setattr(sweep, "shipped_seed_policy_sha256", lambda robot: "0123456789ab")
    from benchmark.evaluate.leaderboard import write_leaderboard

    board, _ = write_leaderboard(store, tmp_path / "out")
    assert "**Ran an earlier seed policy**" in board.read_text() and "hold (t: a1)" in board.read_text()
    again = evaluate(LLMSettings(model="hold"), "t", suite, store)
    assert "ran another seed policy (a1)" in capsys.readouterr().err
    assert again["seed_policy_sha256"] == {"a1": "0123456789ab"} and again["probe"] == first["probe"]
    assert json.loads(next((store / "rows").glob("*.json")).read_text())["seed_policy_sha256"] == again[
        "seed_policy_sha256"]


def test_eval_cells_restrict_the_probe_as_well_as_the_closed_loop(tmp_path):
    """`bench eval --cells a1/flat` (for a slow model) asks the probe's a1/flat items only."""
    from benchmark.evaluate.scorecard import evaluate

    suite = tmp_path / "tiny.toml"
    suite.write_text('name = "tiny"\nversion = 1\n[tiers.t]\nprobe = { history = 10, items = 2 }\n')
    row = evaluate(LLMSettings(model="hold"), "t", suite, tmp_path / "board", cells=("a1/flat",))
    assert set(row["probe"]["cells"]) == {"a1/flat"} and set(row["probe_items"]["cells"]) == {"a1/flat"}
    assert row["probe"]["items"] == 2 * sum(w.cell == "a1/flat" for w in load_probe_set().walks)
    # Beside rows of every cell, restricted rows are compared only with rows restricted the same way.
    from benchmark.evaluate.leaderboard import comparisons
    from benchmark.evaluate.scorecard import load_rows

    for model in ("knn", "replay"):
        evaluate(LLMSettings(model=model), "t", suite, tmp_path / "board")
        evaluate(LLMSettings(model=model), "t", suite, tmp_path / "board", cells=("a1/flat",))
    rows = [{**r, "kind": "server"} for r in load_rows(tmp_path / "board")]  # as if they were models
    tables = dict(comparisons(rows))
    assert {items: sorted(t["P(row > column)"]) for items, t in tables.items()} == {
        "the items of a1/flat": ["hold (a1/flat)", "knn (a1/flat)", "replay (a1/flat)"],
        "all cells' items": ["knn", "replay"]}


def test_the_llms_correlation_is_a_direction_until_enough_models_have_a_closed_loop():
    """Probe skill against NWT over a few LLMs' cells is labelled a direction, not a measurement."""
    from benchmark.evaluate.leaderboard import FEW_MODELS, correlation_text

    def row(name, skill, nwt):
        return {"model": name, "kind": "embedded", "cells_filter": None,
                "probe": {"cells": {"a1/flat": {"skill": skill}}}, "closed_loop": {"a1/flat": {"nwt": nwt}}}

    few = [row(f"m{i}", 0.1 * i, 0.02 * i) for i in range(FEW_MODELS - 1)]
    assert "direction, not a measurement" in correlation_text(few) and ": 1.00" in correlation_text(few)
    enough = few + [row("big", 0.9, 0.5)]
    assert "direction" not in correlation_text(enough) and correlation_text(enough).endswith(": 1.00.")
