"""One scorecard per model: a fixed suite run once, as one row of the leaderboard store.

    bench eval --llm knn                         the quick tier: the probe on all four cells (a minute)
    bench eval --llm embedded --tier full        the probe plus closed loop under the paper's protocol
    bench eval --llm qwen2.5-coder-1.5b --tier full --cells a1/flat

The suite is a file (`benchmark/evaluate/suites/standard.toml`): its tiers name the probe's prompt settings
and the closed-loop cells, so a new tier is data. A row is keyed by the model's identity, the
tier, the suite and the probe set's digest; a row already in the store is not run again, and a
full tier's closed-loop trials go to a sweep store of their own, so an interrupted evaluation
resumes where it stopped. Reference controllers (hold, knn, replay, oracle) get scorecards the same way.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmark.common.fingerprint import fingerprint_id, platform_fingerprint
from benchmark.common.settings import SettingError
from benchmark.common.store import ResultStore
from benchmark.common.tables import live_latency_mean, wilson
from benchmark.evaluate.probe import (
    DEFAULT_PROBE,
    ItemAnswers,
    ProbeProgress,
    ProbeRun,
    answer_walks,
    load_probe_set,
    paired_gain,
    subset,
    summarize_answers,
)
from benchmark.experiments.experiment import Trial
from benchmark.llm.controller import STRATEGY_FIELDS, LLMSettings, is_embedded, strategy_label
from benchmark.llm.models import check_model_spec
from benchmark.llm.reference import TRIVIAL_ANSWERS
from benchmark.llm.strategies import DEFAULT_STRATEGY, STRATEGIES
from benchmark.trial.cell import make_cell
from benchmark.trial.resources import Runtime

SUITES_DIR = Path(__file__).parent / "suites"
DEFAULT_SUITE = SUITES_DIR / "standard.toml"
DEFAULT_STORE = Path("reports") / "leaderboard"


@dataclass(frozen=True)
class Tier:
    name: str
    probe: dict  # LLMSettings / ProbeRun values for the probe
    closed_loop: dict | None  # {"cells": [...], "trials": n, **cell settings}; None: probe only


@dataclass(frozen=True)
class Suite:
    name: str
    version: int
    tiers: dict[str, Tier]


def load_suite(path: Path | str = DEFAULT_SUITE) -> Suite:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
        tiers = {name: Tier(name, dict(t.get("probe", {})), dict(t["closed_loop"]) if "closed_loop" in t else None)
                 for name, t in data["tiers"].items()}
        return Suite(data["name"], int(data["version"]), tiers)
    except (OSError, tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as err:
        raise SettingError(f"suite '{path}' is not a readable suite file ({type(err).__name__}: {err})") from None


def model_identity(spec: str, url: str | None = None) -> dict:
    """What the model is: its spec, its file's sha256 (local) or the server's model id, and its kind."""
    from benchmark.llm import ladder

    out = {"model": spec}
    if ladder.known(spec) and ladder.LADDER[spec].extra is not None:
        out.update(file_sha256=ladder.LADDER[spec].sha256, parameters=ladder.LADDER[spec].parameters)
    elif is_embedded(spec):
        name = spec.partition(":")[2]
        path = Path(name) if name else ladder.resolve(ladder.DEFAULT)
        out.update(file_sha256=_cached_sha256(path), parameters=ladder.LADDER[ladder.DEFAULT].parameters
                   if not name else None)
    elif spec.startswith("openai:"):
        out.update(server_model=spec.partition(":")[2], url=url)
    else:
        out.update(reference=True)
    out["kind"] = "reference" if out.get("reference") else ("embedded" if is_embedded(spec) else "server")
    return out


def _cached_sha256(path: Path) -> str:
    """A local file's sha256, remembered beside the reply cache by path, size and mtime."""
    from benchmark.llm import ladder

    stat = path.stat()
    memo = ladder.models_dir() / "sha256.json"
    known = json.loads(memo.read_text()) if memo.is_file() else {}
    key = f"{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}"
    if key not in known:
        known[key] = ladder.sha256_of(path)
        memo.parent.mkdir(parents=True, exist_ok=True)
        memo.write_text(json.dumps(known, indent=1))
    return known[key]


def strategy_settings(llm: LLMSettings) -> dict:
    """The prompt strategy's settings of a row (the paper's chronological prompt reads no K, memory or distance)."""
    values = {name: getattr(llm, name) for name in STRATEGY_FIELDS}
    return values if STRATEGIES[llm.prompt_strategy].retrieves else {"prompt_strategy": llm.prompt_strategy}


def row_id(identity: dict, tier: Tier, suite: Suite, probe_digest: str, cells: tuple[str, ...] | None,
           strategy: dict | None = None) -> str:
    """A row's key; the paper's chronological prompt keeps the key rows had before strategies existed."""
    parts = [identity.get("model"), identity.get("file_sha256"), identity.get("server_model"), suite.name,
             suite.version, tier.name, tier.probe, tier.closed_loop, probe_digest, cells]
    if strategy and strategy.get("prompt_strategy", DEFAULT_STRATEGY) != DEFAULT_STRATEGY:
        parts.append(strategy)
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:16]


def _probe_run(tier: Tier, llm: LLMSettings, runtime: Runtime,
               cells: tuple[str, ...] | None = None) -> tuple[ProbeRun, Runtime]:
    """The tier's probe run on `cells` (None: all), and the runtime it needs (a tier may fix the decoding, `draft`)."""
    values = dict(tier.probe)
    window, items = values.pop("window", "grow"), values.pop("items", None)
    if "draft" in values:
        runtime = dataclasses.replace(runtime, draft=values.pop("draft"))
    return ProbeRun(llm=dataclasses.replace(llm, **values), window=window, items=items, cells=cells), runtime


def closed_loop_trials(tier: Tier, llm: LLMSettings, cells: tuple[str, ...] | None) -> list[Trial]:
    """The tier's closed-loop cells for this model, as sweep trials (resumable in their own store)."""
    spec = dict(tier.closed_loop)
    names, trials = spec.pop("cells"), int(spec.pop("trials"))
    chosen = [c for c in names if cells is None or c in cells]
    out = []
    for index, name in enumerate(chosen):
        robot, terrain = name.split("/")
        cell = make_cell({**spec, "robot": robot, "terrain": terrain, "policy": "llm", "model": llm.model,
                          **strategy_settings(llm), **({"url": llm.url} if llm.url else {})}, "suite closed_loop")
        out += [Trial("scorecard", cell, seed, {"cell": name}, index) for seed in range(trials)]
    return out


def summarize_closed_loop(frame) -> dict:
    """Per cell: NWT mean with a 95% t interval, success with its Wilson interval, distance, latency."""
    out = {}
    for (robot, terrain), g in frame.groupby(["robot", "terrain"], sort=False):
        n, nwt = len(g), g["nwt"].to_numpy(float)
        half = 2.776 * nwt.std(ddof=1) / np.sqrt(n) if n > 1 else float("nan")  # t(0.975, 4) for 5 trials
        wins, latency = int(g["success"].sum()), live_latency_mean(g)
        out[f"{robot}/{terrain}"] = {"trials": n, "nwt": float(nwt.mean()), "nwt_half_ci": float(half),
                                     "success": wins / n, "success_ci": wilson(wins, n),
                                     "distance_m": float(g["distance_m"].mean()),
                                     "latency_mean_s": None if np.isnan(latency) else latency}
    return out


def row_seed_policies(frame) -> dict[str, str]:
    """Robot -> the seed policy (sha256 prefix) its closed-loop trials ran, from their store."""
    if "seed_policy_sha256" not in frame:
        return {}
    return {robot: ", ".join(sorted(g["seed_policy_sha256"].dropna().unique())) for robot, g in frame.groupby("robot")}


def stale_seed_policies(row: dict, store: Path) -> list[str]:
    """Robots whose shipped seed policy is not the one a row's closed loop ran (empty for a probe-only row).
    A row made before rows recorded it is read from its trial store."""
    from benchmark.common.store import load_results
    from benchmark.experiments.sweep import shipped_seed_policy_sha256

    if not row.get("closed_loop"):
        return []
    ran = row.get("seed_policy_sha256")
    if ran is None:
        trials = store / "trials" / row["row_id"]
        ran = row_seed_policies(load_results(trials)) if trials.is_dir() else {}
    return [robot for robot, sha in ran.items() if sha != shipped_seed_policy_sha256(robot)]


SCORECARD_ITEM_FIELDS = ("cells", "errors", "hold_errors", "within_step", "parsed")  # what a row keeps per item


def evaluate(llm: LLMSettings, tier_name: str = "quick", suite_path: Path | str = DEFAULT_SUITE,
             store: Path | str = DEFAULT_STORE, probe_path: Path | str = DEFAULT_PROBE,
             cells: tuple[str, ...] | None = None, runtime: Runtime = Runtime(), command: str = "bench eval") -> dict:
    """Run (or find) the model's scorecard row for a tier and return it."""
    from benchmark.common.store import load_results
    from benchmark.experiments.sweep import run_metadata, run_sweep

    suite = load_suite(suite_path)
    if tier_name not in suite.tiers:
        raise SettingError(f"unknown tier '{tier_name}'; valid: {', '.join(suite.tiers)}")
    tier = suite.tiers[tier_name]
    check_model_spec(llm.model)
    probe = load_probe_set(probe_path)
    identity = model_identity(llm.model, llm.url)
    strategy = strategy_settings(llm)
    rid = row_id(identity, tier, suite, probe.digest, cells, strategy)
    rows = Path(store) / "rows"
    path, found = rows / f"{rid}.json", None
    if path.is_file():
        found = json.loads(path.read_text())
        changed = stale_seed_policies(found, Path(store))
        if not changed:
            print(f"bench: {llm.model} {tier_name} tier ({strategy_label(llm)}) already scored ({path}); not run again",
                  file=sys.stderr)
            return found
        print(f"bench: {llm.model} {tier_name} tier's closed loop ran another seed policy ({', '.join(changed)}); "
              "its trials run again with the shipped one", file=sys.stderr)
    started = time.perf_counter()
    partial = Path(store) / "partial" / f"{rid}.json"
    row = {"row_id": rid, "suite": suite.name, "suite_version": suite.version, "tier": tier_name, **identity,
           "probe_digest": probe.digest, "probe_settings": {**tier.probe}, "cells_filter": list(cells) if cells else None}
    if strategy["prompt_strategy"] != DEFAULT_STRATEGY:  # a row without it ran the paper's chronological prompt
        row.update(strategy=strategy_label(llm), strategy_settings=strategy)
    if found is not None:  # the probe set fixes the probe's items: only the closed loop depends on the shipped policy
        row.update(probe=found["probe"], probe_items=found["probe_items"])
    else:
        run, probe_runtime = _probe_run(tier, llm, runtime, cells)
        chosen = [w for w in probe.walks if cells is None or w.cell in cells]
        print(f"bench: probe {probe.digest}: {llm.model}, {dataclasses.replace(probe, walks=tuple(chosen)).items()} "
              "items", file=sys.stderr, flush=True)
        answers = answer_walks(probe, run, probe_runtime, partial=partial, progress=ProbeProgress())
        row.update(probe=summarize_answers(answers), probe_items=answers.to_json(SCORECARD_ITEM_FIELDS, digits=6))
    closed_wall = 0.0
    if tier.closed_loop is not None:
        trials = closed_loop_trials(tier, llm, cells)
        trial_store = ResultStore(Path(store) / "trials" / rid)
        run_sweep(trials, trial_store, command=command, threads=runtime.threads, runtime=runtime)
        frame = load_results(trial_store.root)
        row["closed_loop_settings"] = {**tier.closed_loop, "cells": [t.labels["cell"] for t in trials[::max(
            1, int(tier.closed_loop["trials"]))]]}
        row["closed_loop"] = summarize_closed_loop(frame)
        row["seed_policy_sha256"] = row_seed_policies(frame)
        # a trial stored before trials recorded their wall time counts as 0: an old store under-reports
        closed_wall = float(frame["trial_wall_s"].fillna(0).sum()) if "trial_wall_s" in frame else 0.0
    meta = run_metadata(command)
    # wall_s: compute time of the whole row over every resumed run (each probe walk's and trial's own time)
    row.update(wall_s=round(row["probe"]["wall_s"] + closed_wall, 1),
               wall_this_run_s=round(time.perf_counter() - started, 1), command=command,
               versions=json.loads(meta["versions"]),
               git_commit=meta["git_commit"], fingerprint_id=fingerprint_id(), fingerprint=platform_fingerprint(),
               made_at=time.strftime("%Y-%m-%d %H:%M:%S"),
               load_1m=os.getloadavg()[0])  # above the core count, other work shared the machine: times inflated
    rows.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(row, indent=1))
    tmp.replace(path)
    partial.unlink(missing_ok=True)
    return row


def on_some_cells(row: dict) -> bool:
    """Whether the row answered only some cells' probe items (`bench eval --cells`): not comparable overall."""
    return row.get("cells_filter") is not None


def row_label(row: dict) -> str:
    """The row's model name, with its cells in brackets when it was scored on some cells only, and its prompt
    strategy after a slash when it is not the paper's."""
    strategy = row_strategy(row)
    return row["model"] + (f" ({'+'.join(row['cells_filter'])})" if on_some_cells(row) else "") + \
        (f" / {strategy}" if strategy != DEFAULT_STRATEGY else "")


def row_strategy(row: dict) -> str:
    """The prompt strategy a row ran (rows made before strategies ran the paper's chronological prompt)."""
    return row.get("strategy", DEFAULT_STRATEGY)


def load_rows(store: Path | str = DEFAULT_STORE) -> list[dict]:
    rows = []
    for path in sorted((Path(store) / "rows").glob("*.json")):
        try:
            rows.append(json.loads(path.read_text()))
        except json.JSONDecodeError:
            raise SettingError(f"'{path}' is not a scorecard row (malformed JSON); delete it to re-run") from None
    return rows


def trivial_gain(row: dict, rows: list[dict]) -> tuple[str, float, float, float] | None:
    """A model row's probe skill minus the better of its own prompt's trivial answers, with a paired 95% interval:
    the `hold` and `knn` reference rows scored on the same probe set, settings and prompt strategy (their items
    narrowed to the row's cells). None for reference rows, or when those rows are not in the store."""
    if row.get("kind") == "reference":
        return None
    mine = ItemAnswers.from_json(row["probe_items"])
    best = None
    for ref in rows:
        if (ref.get("kind") != "reference" or ref["model"] not in TRIVIAL_ANSWERS or ref["probe_digest"] != row["probe_digest"]
                or ref["probe_settings"] != row["probe_settings"] or row_strategy(ref) != row_strategy(row)):
            continue
        theirs = subset(ItemAnswers.from_json(ref["probe_items"]), sorted(set(mine.cells)))
        if theirs.cells != mine.cells or not np.allclose(theirs.hold_errors, mine.hold_errors):
            continue
        gain = paired_gain(mine, theirs)
        if best is None or gain[0] < best[1]:  # the better trivial answer leaves the smaller gain
            best = (ref["model"], *gain)
    return best
