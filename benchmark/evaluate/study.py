"""The probe stage of an experiment: every combination of its `[probe]` grid (models x prompt strategies)
scored on the probe set, one row each in the experiment's own results store, beside its closed-loop trials.

    bench sweep prompting --stage probe       the probe for every (model, strategy), resumable
    bench sweep prompting                     the probe stage, then the closed-loop trials
    bench report results/prompting            both, with the same-prompt trivial answers and diagnostics

A row holds the model's skill with its interval, its prompt's own trivial answers (`hold`: the last
example line; `knn`: the nearest example's output) scored on the same items, the gain over the better
of them with a paired interval, the cost, and the per-item errors. A probe run of hours saves each
finished walk (`partial/`), so a stopped stage resumes inside a run as well as between runs.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from benchmark.common.settings import build
from benchmark.common.store import ResultStore
from benchmark.evaluate.probe import (
    DEFAULT_PROBE,
    ProbeProgress,
    ProbeRun,
    answer_walks,
    load_probe_set,
    probe_history_mode,
    same_prompt_gain,
    subset,
    summarize_answers,
)
from benchmark.experiments.experiment import Experiment, ExperimentError
from benchmark.experiments.sweep import run_metadata
from benchmark.llm.controller import LLMSettings, strategy_label
from benchmark.llm.models import require_models
from benchmark.trial.resources import Runtime


# LLM settings added after probe rows were stored: left out of a probe run's id at their default, so stored rows
# keep their ids (the closed loop's trial ids do the same for every `added_later` setting)
PROBE_ID_LATER = {"tell_disturbance": False}


@dataclass(frozen=True)
class ProbeJob:
    """One (model, prompt settings) of an experiment's probe grid, on one probe set."""

    experiment: str
    llm: LLMSettings
    labels: dict
    window: str
    cells: tuple[str, ...] | None
    items: int | None
    probe_digest: str
    index: int  # position in the probe grid, for tables
    probe_path: str | None = field(default=None, compare=False)  # the set it scores on (None: the stage's)

    @property
    def id(self) -> str:
        llm = {k: v for k, v in dataclasses.asdict(self.llm).items()
               if not (k in PROBE_ID_LATER and v == PROBE_ID_LATER[k])}
        key = json.dumps([self.experiment, "probe", llm, self.window, self.cells, self.items, self.probe_digest],
                         sort_keys=True)
        return hashlib.sha256(key.encode()).hexdigest()[:16]

    def label(self) -> str:
        """The model and prompt, and the grid's other labels (an ablation's variant, the probe set's engine)."""
        rest = [f"{k}={v}" for k, v in self.labels.items() if k not in ("model", "prompt_strategy")]
        return f"{self.llm.model} / {strategy_label(self.llm)}" + (f" [{', '.join(rest)}]" if rest else "")


def probe_jobs(experiment: Experiment, probe_digest: str | None = None, overrides: dict | None = None,
               only: dict | None = None) -> list[ProbeJob]:
    """The probe stage's runs (empty when the experiment has no `[probe]` table). Each scores on its probe set (the
    engine's, where the table keys them by engine), whose digest is part of its identity; `probe_digest` gives one
    digest for every run instead of reading the sets."""
    table = experiment.probe
    if not table:
        return []
    fields = {f.name for f in dataclasses.fields(LLMSettings)}
    jobs, every = [], experiment.probe_settings(overrides)
    for settings, labels in experiment.probe_settings(overrides, only):
        index = every.index((settings, labels))  # the place in the whole grid, whatever `only` kept
        try:
            llm = build(LLMSettings, {k: v for k, v in settings.items() if k in fields}, f"{experiment.name} probe")
        except ValueError as err:
            raise ExperimentError(f"{experiment.name}: probe: {err}") from None
        cells, window = tuple(table["cells"]) if table.get("cells") else None, table.get("window", "grow")
        llm = dataclasses.replace(llm, history_mode=probe_history_mode(llm, window))  # the row keeps the mode that ran
        path = str(experiment.probe_set_for(labels) or DEFAULT_PROBE)
        digest = probe_digest if probe_digest is not None else _probe_set(path).digest
        jobs.append(ProbeJob(experiment.name, llm, labels, window, cells, table.get("items"), digest, index, path))
    return jobs


def _probe_set(path: str):
    """A probe set read once while its file is unchanged: the stage's runs name it for its digest, then score on it."""
    return _read_probe_set(path, Path(path).stat().st_mtime_ns if Path(path).is_file() else None)


@functools.lru_cache(maxsize=8)
def _read_probe_set(path: str, mtime_ns: int | None):
    return load_probe_set(path)


def run_probe_stage(jobs: list[ProbeJob], store: ResultStore, runtime: Runtime, probe_path: Path | str = DEFAULT_PROBE,
                    draft: str | None = None, command: str | None = None) -> tuple[int, int]:
    """Run the jobs not yet in `store`, one row each as it finishes, each on its own probe set (else `probe_path`):
    (ran, already stored)."""
    done = store.done_ids()
    todo = [j for j in jobs if j.id not in done]
    require_models(j.llm.model for j in todo)  # stored rows need none
    if draft is not None:
        runtime = dataclasses.replace(runtime, draft=draft)
    meta = run_metadata(command)
    for number, job in enumerate(todo, 1):
        probe = _probe_set(str(job.probe_path or probe_path))
        print(f"bench: probe {number}/{len(todo)}: {job.label()}, history {job.llm.history} ({job.window}), "
              f"{', '.join(job.cells or probe.cells)}", file=sys.stderr, flush=True)
        run = ProbeRun(llm=job.llm, window=job.window, items=job.items, cells=job.cells)
        started = time.perf_counter()
        answers = answer_walks(probe, run, runtime, partial=store.root / "partial" / f"{job.id}.json",
                               progress=ProbeProgress())
        store.write({**probe_row(job, summarize_answers(answers), answers), **meta,
                     "probe_seed_policies": json.dumps(probe.meta.get("seed_policy_sha256", {}), sort_keys=True),
                     "trial_wall_s": time.perf_counter() - started, "load_1m": os.getloadavg()[0]})
        (store.root / "partial" / f"{job.id}.json").unlink(missing_ok=True)
    if todo:
        store.snapshot()
    return len(todo), len(jobs) - len(todo)


def cell_gains(answers) -> dict:
    """Per probe cell: the model's skill minus the better of the same prompt's trivial answers, with its paired 95%
    interval, [gain, low, high]."""
    out = {}
    for cell in dict.fromkeys(answers.cells):
        g = same_prompt_gain(subset(answers, [cell]))
        out[cell] = [round(float(g["gain"]), 4), round(float(g["gain_low"]), 4), round(float(g["gain_high"]), 4)]
    return out


def probe_row(job: ProbeJob, summary: dict, answers) -> dict:
    """A probe run as one store row (kind "probe"); per-item errors kept for paired comparisons later."""
    same = summary.get("same_prompt", {})
    llm = dataclasses.asdict(job.llm)
    llm["prompt_parts"] = "+".join(llm["prompt_parts"])
    return {"experiment": job.experiment, "trial_id": job.id, "kind": "probe", "cell_index": job.index,
            "seed": 0, **llm, **job.labels, "axes": json.dumps(list(job.labels)), "strategy": strategy_label(job.llm),
            "window": job.window,
            "probe_cells": "+".join(job.cells) if job.cells else "all", "probe_digest": job.probe_digest,
            "cell_skills": json.dumps({cell: round(float(c["skill"]), 4) for cell, c in summary.get("cells", {}).items()}),
            "cell_gains": json.dumps(cell_gains(answers)),
            "items": summary["items"], "skill": summary["skill"], "skill_low": summary["skill_low"],
            "skill_high": summary["skill_high"], "error": summary["error"], "hold_error": summary["hold_error"],
            "within_step": summary["within_step"], "parse_failures": summary["parse_failures"],
            "latency_median_s": summary["latency_median_s"], "prompt_tokens": summary["prompt_tokens"],
            "completion_tokens": summary["completion_tokens"], "wall_s": summary["wall_s"],
            "cached_replies": summary.get("cached_replies"), "same_prompt_hold_skill": same.get("hold_skill"),
            "same_prompt_knn_skill": same.get("knn_skill"),
            "same_prompt_best": same.get("best"), "gain": same.get("gain"), "gain_low": same.get("gain_low"),
            "gain_high": same.get("gain_high"), "item_errors": answers.errors.round(6).tolist(),
            "item_hold_errors": answers.hold_errors.round(6).tolist(),
            "item_prompt_hold_errors": answers.prompt_hold_errors.round(6).tolist(),
            "item_prompt_knn_errors": answers.prompt_knn_errors.round(6).tolist()}
