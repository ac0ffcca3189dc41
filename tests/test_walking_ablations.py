"""The paper's four prompt ablations on the configuration that walks (`walking_*` experiments): every variant renders
the prompt its ablation names, in the closed loop and in the probe alike, read from the prompts themselves."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from benchmark.evaluate.probe import ProbeRun, answer_items, load_probe_set
from benchmark.evaluate.study import probe_jobs
from benchmark.experiments.experiment import load_experiment
from benchmark.llm.encodings import Encoding, get_encoding
from benchmark.llm.prompt import PARTS, split_prompt
from benchmark.llm.prompt_inputs import describe, select
from benchmark.llm.strategies import format_pair
from benchmark.trial.trials import KeepPolicy, run_cell
from conftest import RecordingHold

WALKING = ("walking_description", "walking_history", "walking_observation", "walking_normalization")
MODEL = "qwen15"  # the closed loop's model row; its trials run here on `hold` (the prompt is the model's)
PART_MARKS = {"task": "You control a", "io": "body frame (x forward", "joints": "Joint order:",
              "pipeline": "tracked by PD control", "illustration": "Reply with one line:"}


def _axis(experiment) -> str:
    return next(a for a in experiment.grid if a != "controller")


def closed_loop_prompt(cell) -> tuple[str, list[str], np.ndarray]:
    """The last prompt of a short trial of the cell on `hold` (seed phase 0.5-3 s, 1 s of queries), the example
    texts its retrieval could draw on, and the observation it asked about: (prompt, pool, observation)."""
    settings = dataclasses.replace(cell.settings, model="hold", seed_start=0.5, llm_after=3.0)
    keep = KeepPolicy()
    run_cell(dataclasses.replace(cell, duration=4.0, settings=settings), [0], hooks=[keep])
    policy, s = keep.policy, settings
    enc, idx = get_encoding(s.encoding), select(s.observation)
    shown = policy._trial.history[:-1]  # the history as the last query saw it (its own pair came after)
    pool = shown[-s.history:] if s.memory == "window" and s.history else ([] if s.memory == "window" else
                                                                          list(policy._trial.demonstrations))
    return policy.last_prompt, [format_pair(o, a, enc, idx) for o, a in pool], policy._trial.history[-1][0]


def probe_prompt(job) -> tuple[str, np.ndarray]:
    """The first prompt the probe stage's run asks, on `hold`, and the observation it asks about (the first item of
    the first walk in the run's cells)."""
    model = RecordingHold()
    probe = load_probe_set(load_experiment(job.experiment).probe_set)
    run = ProbeRun(llm=dataclasses.replace(job.llm, model="hold"), window=job.window, items=1, cells=job.cells)
    answer_items(probe, run, model=model)
    walk = next(w for w in probe.walks if w.cell in job.cells)
    return model.prompts[0], walk.observations[walk.first_item]


def examples(prompt: str) -> list[str]:
    """The example pairs above the current input, as written."""
    lines = prompt.splitlines()
    return [f"{a}\n{b}" for a, b in zip(lines, lines[1:]) if a.startswith("Input: [") and b.startswith("Output: [")]


def numbers_written_as(prompt: str, enc: Encoding) -> bool:
    """Every Input/Output list uses the encoding's separator, its decimals and its range, and nothing else."""
    shape = re.compile(r"-?\d+" + (rf"\.\d{{{enc.decimals}}}" if enc.decimals else ""))
    low, high = float(enc.encode_value(enc.low)), float(enc.encode_value(enc.high))
    lists = [line.split(": ", 1)[1] for line in prompt.splitlines() if re.match(r"(Input|Output): \[", line)]
    for text in lists:
        inner = text[1:-1]
        values = inner.split(enc.separator) if inner else []
        if any(not shape.fullmatch(v) or not low <= float(v) <= high for v in values):
            return False
    return bool(lists)


def check(name: str, value: str, llm, prompt: str, obs: np.ndarray) -> None:
    """The prompt is the one the ablation names for this value; its current input is the observation as the
    variant's encoding and observation choice write it."""
    enc = get_encoding(value if name == "walking_normalization" else "E5")
    idx = select(value if name == "walking_observation" else "O5")
    assert prompt.splitlines()[-2:] == [f"Input: {enc.encode(obs[idx])}", "Output:"]
    assert numbers_written_as(prompt, enc)
    if name == "walking_description":
        parts = PARTS[:int(value[1:])]  # E1 the task alone ... E5 all five, built up in the paper's order
        assert llm.prompt_parts == parts
        assert [p for p in PARTS if PART_MARKS[p] in prompt] == list(parts)
    elif name == "walking_observation":
        shown = len(idx)
        assert shown == {"O1": 0, "O2": 6, "O3": 24, "O4": 30, "O5": 33}[value]
        assert all(len(re.findall(r"\d+", e.splitlines()[0])) == shown for e in examples(prompt))
        assert ("; ".join(describe(value)) if shown else "nothing (outputs only)") in prompt
    elif name == "walking_normalization":
        assert llm.encoding == value and f"Numbers are {enc.title}:" in prompt
    elif name == "walking_history":
        expected = 0 if value == "window0" else 3 if value.startswith("window") else int(value[1:])
        assert len(examples(prompt)) == expected
        if value.startswith("window"):
            assert (llm.memory, llm.history) == ("window", int(value[len("window"):]))
        else:
            assert (llm.memory, llm.retrieve_k) == ("demonstrations", expected)


@pytest.mark.parametrize("name", WALKING)
def test_every_variant_renders_the_prompt_its_ablation_names(name):
    """Closed loop (the model row's cell, on `hold`, 1 s of queries in MuJoCo) and probe (its first item): each
    variant's prompt shows the description parts, observation values, number format or examples the variant names,
    the retrieved examples come from the memory it names, and the two stages write the same description."""
    experiment = load_experiment(name)
    axis = _axis(experiment)
    cells = {t.labels[axis]: t.cell for t in experiment.trials(only={"controller": MODEL})}
    jobs = {j.labels[axis]: j for j in probe_jobs(experiment, "") if j.llm.model == "qwen2.5-coder-1.5b"}
    assert list(cells) == list(jobs) == list(experiment.grid[axis])  # both stages run every variant
    for value, cell in cells.items():
        assert cell.settings.prompt_strategy == jobs[value].llm.prompt_strategy == "nearest-only"
        loop, pool, loop_obs = closed_loop_prompt(cell)
        probe, probe_obs = probe_prompt(jobs[value])
        for prompt, llm, obs in ((loop, cell.settings, loop_obs), (probe, jobs[value].llm, probe_obs)):
            check(name, value, llm, prompt, obs)
        assert set(examples(loop)) <= set(pool)
        assert split_prompt(loop)[0] == split_prompt(probe)[0]


def test_an_ablation_report_judges_the_papers_findings_on_the_model_row(tmp_path):
    """A tiny description ablation in MuJoCo (E1 and E5, 2 seeds, 2 s after the takeover) with `replay` in the
    model's place: it reads only the examples, so E1 and E5 walk alike and the paper's "full description walks best"
    is judged to fail here; the report carries the variant table, the judged finding and its figure."""
    from benchmark.common.store import ResultStore, load_results
    from benchmark.experiments.report import write_reports
    from benchmark.experiments.sweep import run_sweep

    path = tmp_path / "tiny_ablation.toml"
    path.write_text('name = "tiny_ablation"\nseeds = 2\n[fixed]\nduration = 12.0\nllm_after = 10.0\nseed_start = 1.0\n'
                    'prompt_strategy = "nearest-only"\n[grid]\ncontroller = ["knn", "hold", "oracle", "replay"]\n'
                    'description = ["E1", "E5"]\n[variants.description]\nE1 = { prompt_parts = ["task"] }\n'
                    'E5 = { prompt_parts = ["task", "io", "joints", "pipeline", "illustration"] }\n'
                    '[variants.controller]\nknn = { policy = "llm", model = "knn" }\nhold = { policy = "llm", model = '
                    '"hold" }\noracle = { policy = "llm", model = "oracle" }\nreplay = { policy = "llm", model = '
                    '"replay" }\n[paper]\naxis = "description"\nfindings = [{ better = "E5", worse = "E1", says = '
                    '"the full description walks best" }]\n')
    run_sweep(load_experiment(str(path)).trials(), ResultStore(tmp_path / "store"), workers=1,
              command=f"bench sweep {path} --results {tmp_path / 'store'}")  # the report finds the file by it
    frame = load_results(tmp_path / "store")
    write_reports(frame, tmp_path / "reports")
    text = (tmp_path / "reports" / "tiny_ablation.md").read_text()
    assert "## The ablation on a model that walks" in text
    replay = frame[frame["controller"] == "replay"].set_index(["description", "seed"])["success"]
    assert (replay.loc["E1"] == replay.loc["E5"]).all()  # the description cannot move a model of the examples
    finding = next(line for line in text.splitlines() if line.startswith("| the full description walks best"))
    walked = int(replay.loc["E5"].sum())
    assert f"| E5 > E1 | replay | {walked}/2 vs {walked}/2: +0.00 [+0.00, +0.00] |" in finding
    assert finding.endswith("| fails: both walk alike |" if walked else "| cannot tell: neither walks at n = 2 |")
    assert (tmp_path / "reports" / "figures" / "tiny_ablation_ablation.png").stat().st_size > 10_000


def test_a_finding_holds_fails_or_cannot_tell_by_its_paired_interval():
    """The verdict rule on made-up successes over 5 seeds (a unit test of the rule alone)."""
    import pandas as pd

    from benchmark.experiments.report_ablation import judge

    def trials(successes):
        return pd.DataFrame({"seed": range(len(successes)), "success": successes})

    rng = np.random.default_rng(0)
    assert judge(trials([1, 1, 1, 1, 1]), trials([0, 0, 0, 0, 0]), rng)[1] == "holds"
    assert judge(trials([0, 0, 0, 0, 0]), trials([1, 1, 1, 1, 1]), rng)[1] == "fails (reversed)"
    assert judge(trials([1, 1, 1, 1, 1]), trials([1, 1, 1, 1, 1]), rng)[1] == "fails: both walk alike"
    assert judge(trials([0, 0, 0, 0, 0]), trials([0, 0, 0, 0, 0]), rng)[1] == "cannot tell: neither walks at n = 5"
    assert judge(trials([1, 0, 1, 0, 1]), trials([0, 1, 1, 0, 1]), rng)[1] == "cannot tell at n = 5"
    assert judge(trials([1, 1]), trials([]), rng)[1] == "not run yet"


def test_the_papers_findings_are_read_teacher_forced_from_the_probe_rows():
    """The observation ablation's probe stage with `hold` in the model's place, 10 items of the committed set each:
    without inputs (O1) retrieval cannot find the examples that match, so "O5 > O1" holds teacher-forced for it and
    for the prompt's own `knn`, the figures are the rows' skills, and a finding with no O2 row is not run yet."""
    import pandas as pd

    from benchmark.evaluate.probe import summarize_answers
    from benchmark.evaluate.study import probe_row
    from benchmark.experiments.report_ablation import probe_findings_table

    experiment = load_experiment("walking_observation")
    jobs = {j.labels["observation"]: j for j in probe_jobs(experiment, "") if j.llm.model == "qwen2.5-coder-1.5b"}
    probe, rows = load_probe_set(experiment.probe_set), []
    for value in ("O1", "O5"):
        job = dataclasses.replace(jobs[value], llm=dataclasses.replace(jobs[value].llm, model="hold"), items=10,
                                  labels={**jobs[value].labels, "model": "hold"})
        answers = answer_items(probe, ProbeRun(llm=job.llm, window=job.window, items=10, cells=job.cells))
        rows.append(probe_row(job, summarize_answers(answers), answers))
    table = probe_findings_table(pd.DataFrame(rows), experiment).set_index(["compared", "answers"])
    verdicts, model = table["here"].to_dict(), "hold (the prompt's last example line)"
    assert verdicts[("O5 > O1", model)] == verdicts[("O5 > O1", "knn (the prompt's nearest example)")] == "holds"
    figures = table.loc[("O5 > O1", model), "probe skill: better vs worse, difference [95%]"]
    o5, o1 = (next(r["skill"] for r in rows if r["observation"] == v) for v in ("O5", "O1"))
    assert figures.startswith(f"{o5:.3f} vs {o1:.3f}: {o5 - o1:+.3f} [")
    assert verdicts[("O5 > O2", model)] == "not run yet"


def test_a_teacher_forced_finding_pairs_items_where_it_can():
    """The item rule on made-up errors (a unit test of the rule alone): rows over the same items are paired, each in
    its own units (another number format), identical answers fail, and rows over other items (a history length that
    moves the first item) are compared unpaired."""
    import pandas as pd

    from benchmark.experiments.report_ablation import judge_items

    def row(errors, hold, history=50):
        return pd.Series({"item_errors": np.array(errors, float), "item_hold_errors": np.array(hold, float),
                          "probe_cells": "a1/flat", "probe_digest": "d", "window": "grow", "history": history})

    hold = [1.0] * 20
    assert judge_items(row([0.2] * 20, hold), row([0.9] * 20, hold))[1] == "holds"
    assert judge_items(row([0.9] * 20, hold), row([0.2] * 20, hold))[1] == "fails (reversed)"
    assert judge_items(row([0.5] * 20, hold), row([0.5] * 20, hold))[1] == "fails: the same answers"
    assert judge_items(row([0.5] * 20, hold), row([5.0] * 20, [10.0] * 20))[1] == "fails: the same answers"
    noisy = [0.4, 0.6] * 10
    assert judge_items(row(noisy, hold), row(noisy[::-1], hold))[1] == "cannot tell at 20 items"
    figures, verdict = judge_items(row([0.2] * 20, hold), row([0.9] * 20, [2.0] * 20, history=0))
    assert verdict == "holds" and figures.endswith("(unpaired: other items)") and figures.startswith("0.800 vs 0.550")
    assert not judge_items(row([0.2] * 20, hold), row([0.9] * 20, [2.0] * 20))[0].endswith("(unpaired: other items)")
