"""How many closed-loop LLM trials an hour, and how close each query comes to what the model's speed allows.

    bench throughput --llm qwen2.5-coder-1.5b --prompt-strategy nearest-only --concurrency 1 2 4 --queries 10

**The floor.** A fresh model first reads a real takeover prompt cold (its prefill rate, tokens a second) and
decodes 64 tokens with no grammar and no draft (its decode rate). Every query of the trials that follow then
has a floor, the time those rates allow for what it did: tokens read anew / prefill rate + tokens decoded /
decode rate. Measured seconds over the floor say how much goes elsewhere (the grammar's sampling, the
harness) or, below 1, what the n-gram draft saves.

**Trials in lockstep.** For each N, a fresh model with N llama.cpp slots runs the same trials (seeds 0 to
T - 1, T the largest N) N at a time, as threads, each trial on engines of its own: their queries arrive
together and llama.cpp reads and decodes them in shared batches. Each trial is shortened to `queries` LLM
queries after the takeover (the paper's protocol otherwise: seed policy from 1 s, the model from 10 s);
"trials an hour" counts 100-query trials at the measured rate, an extrapolation, and says so. Batched
decoding can change logits slightly, so every reply is compared with the N = 1 reply for the same seed and
query: the fraction identical, and the first query where a trial's replies part (closed loop: after that
the prompts differ too).

**Drafts.** `--drafts ngram none` runs every level once per draft setting, in that order, all compared with
the first: speculative decoding keeps greedy replies in principle (a draft token is kept only where the
model would have chosen it), so the agreement column checks that, and the seconds a query say whether
checking drafts pays on this machine.

**Speed settings.** `--settings default fast` runs every level once per named setting (a number layout, a
draft and how many examples the prompt shows; `SPEED_SETTINGS` below), in one run on one machine, so the
"x first row" column is the speed-up of one setting over another measured side by side. A setting that writes
another prompt is compared only with rows on the same prompt: its replies cannot be identical to another
prompt's, and whether it walks as well is the closed loop's question (the `compact` experiment). With
`--drafts`, each setting runs once per draft given instead of with its own. `--queries 100` measures whole
trials: later queries find more of their prompt in llama.cpp's prompt cache (an example shown a gait cycle
before), so a short run's extrapolation can differ from a whole trial's rate.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

from benchmark.llm.controller import CONTROL_DT, LLMSettings, query_timings, takeover_prompt
from benchmark.llm.models import Constraint, Sampling
from benchmark.trial.cell import CellSpec
from benchmark.trial.resources import Resources, Runtime, SharedModels
from benchmark.trial.trials import TrialHooks, run_side_by_side

TRIAL_QUERIES = 100  # the paper's protocol: 10 s of model control at 10 Hz
DECODE_PROBE_TOKENS = 64


@dataclasses.dataclass(frozen=True)
class Setup:
    """What a query reads and how it decodes: the number layout, the draft and the examples shown."""

    encoding: str = LLMSettings.encoding
    draft: str = Runtime.draft
    retrieve_k: int = LLMSettings.retrieve_k
    name: str | None = None  # the named setting this comes from (`SPEED_SETTINGS`), if any

    @property
    def prompt(self) -> tuple[str, int]:
        """What decides the prompt's text (the draft does not)."""
        return self.encoding, self.retrieve_k

    def label(self) -> str:
        return f"{self.encoding}, draft {self.draft}, {self.retrieve_k} example{'s' * (self.retrieve_k != 1)}"


SPEED_SETTINGS: dict[str, tuple[Setup, str]] = {
    "default": (Setup(name="default"), "the paper's E5 layout, n-gram draft, 3 retrieved examples: every study's setting"),
    "compact": (Setup("E4c", "none", 3, "compact"), "E4c (0..100, no space after commas), no draft, 3 examples: the same "
                                         "examples in a third fewer tokens"),
    "fast": (Setup("E4c", "ngram", 1, "fast"), "E4c, n-gram draft, 1 example (the nearest): about half compact's "
                                               "tokens, and the reply copies that example, so the draft is kept"),
}


@dataclasses.dataclass(frozen=True)
class ThroughputRun:
    """What `bench throughput` measures."""

    model: str = "embedded"
    strategy: str = "nearest-only"
    concurrency: tuple[int, ...] = (1, 2, 4)
    queries: int = 10  # LLM queries a trial (a full trial has 100)
    threads: int | None = None
    setups: tuple[Setup, ...] = (Setup(),)  # one set of levels each, in order


class _Trials(TrialHooks):
    """Every trial's policy, by seed (trials run side by side)."""

    def __init__(self) -> None:
        self.policies: dict[int, object] = {}

    def start(self, seed, sim, policy, episode):
        self.policies[seed] = policy


def _cell(run: ThroughputRun, setup: Setup) -> CellSpec:
    settings = LLMSettings(model=run.model, prompt_strategy=run.strategy, encoding=setup.encoding,
                           retrieve_k=setup.retrieve_k)
    return CellSpec(sim="mujoco", robot="a1", policy="llm", duration=settings.llm_after + CONTROL_DT * run.queries,
                    settings=settings)


def model_rates(run: ThroughputRun, cell: CellSpec) -> dict:
    """The model's prefill rate (a real takeover prompt, read cold) and decode rate (64 free tokens, greedy, no
    draft), on a fresh model with one slot."""
    from benchmark.llm.models import make_model

    prompt = takeover_prompt(cell)
    model = make_model(run.model, cache=False, threads=run.threads, draft="none")
    try:
        read = model.complete(prompt, Sampling(max_tokens=1), Constraint(), cold=True)
        free = model.complete("Count: 1, 2, 3, 4, 5,", Sampling(max_tokens=DECODE_PROBE_TOKENS), Constraint(), cold=True)
    finally:
        model.close()
    if read.read_tokens is None or free.decode_s is None:
        raise ValueError(f"'{run.model}' reports no timings (llama.cpp's): the floor needs an embedded model or a "
                         "llama.cpp server")
    return {"prompt_tokens": read.prompt_tokens, "prefill_tok_s": read.read_tokens / read.prefill_s,
            "decoded_tokens": free.completion_tokens, "decode_tok_s": free.completion_tokens / free.decode_s}


def run_level(run: ThroughputRun, cell: CellSpec, seeds: list[int], n: int, draft: str) -> dict:
    """The trials of `seeds`, `n` at a time on one fresh model with `n` slots: wall time and every reply."""
    runtime = Runtime(threads=run.threads, cache=False, draft=draft, slots=n)
    shared = SharedModels()
    resources = Resources(runtime, shared)
    watch = _Trials()
    started = time.perf_counter()
    try:
        run_side_by_side(cell, seeds, resources, [watch], concurrency=n)
    finally:
        wall = time.perf_counter() - started
        resources.close()
        shared.close()
    queries = {seed: list(p.queries) for seed, p in watch.policies.items()}
    return {"n": n, "wall_s": wall, "queries": queries}


def floor_of(replies, rates: dict) -> np.ndarray:
    """Per query: seconds the model's rates allow for the tokens it read anew and decoded."""
    return np.array([r.read_tokens / rates["prefill_tok_s"] + r.completion_tokens / rates["decode_tok_s"]
                     for r in replies])


def measure(run: ThroughputRun) -> dict:
    """The model's rates, then one row per setup and concurrency level (see the module's docstring)."""
    rates = model_rates(run, _cell(run, run.setups[0]))
    seeds = list(range(max(run.concurrency)))
    levels, first = [], {}  # first: per prompt, its first level's queries by seed, what its other levels are compared with
    for setup, n in [(u, n) for u in dict.fromkeys(run.setups) for n in sorted(set(run.concurrency))]:
        print(f"bench: throughput: {len(seeds)} trials of {run.queries} queries, {n} at a time, {setup.label()} ...",
              file=sys.stderr, flush=True)
        level = run_level(run, _cell(run, setup), seeds, n, setup.draft)
        by_seed = level["queries"]
        first.setdefault(setup.prompt, by_seed)
        queries = [q for qs in by_seed.values() for q in qs]
        replies = [q.reply for q in queries]
        row = {"n": n, "draft": setup.draft, "encoding": setup.encoding, "retrieve_k": setup.retrieve_k,
               "setting": setup.name,
               "trials": len(by_seed), "queries": len(queries), "wall_s": level["wall_s"],
               "queries_per_hour": 3600.0 * len(queries) / level["wall_s"],
               "parse_failures": sum(not q.parsed for q in queries),
               "latency_mean_s": float(np.mean([r.latency_s for r in replies])),
               "cached_tokens": float(np.mean([r.cached_tokens for r in replies])),
               "decoded_tokens": float(np.mean([r.completion_tokens for r in replies])),
               "floor_s": float(np.mean(floor_of(replies, rates))), **query_timings(queries),
               **_agreement(by_seed, first[setup.prompt])}
        row["trials_per_hour"] = row["queries_per_hour"] / TRIAL_QUERIES
        levels.append(row)
        print(f"bench: throughput: N = {n}, {setup.label()}: {row['trials_per_hour']:.2f} trials an hour "
              f"({len(queries)} queries in {level['wall_s']:.0f} s)", file=sys.stderr, flush=True)
    for row in levels:
        row["speedup"] = row["queries_per_hour"] / levels[0]["queries_per_hour"]
    return {"model": run.model, "strategy": run.strategy, "queries_per_trial": run.queries, "rates": rates,
            "levels": levels, "threads": run.threads, "setups": [dataclasses.asdict(u) for u in dict.fromkeys(run.setups)]}


def _agreement(mine: dict, reference: dict) -> dict:
    """Each trial's replies against the reference level's for the same seed, query by query: the fraction identical,
    the first query where they part (None: never), and the mean |action difference| (action units) between replies
    to identical prompts, which is how far batching moves an answer apart from where the closed loop then goes."""
    same = total = 0
    parted, diffs = [], []
    for seed, queries in mine.items():
        pairs = list(zip(queries, reference.get(seed, [])))
        same += sum(a.reply.text == b.reply.text for a, b in pairs)
        total += len(pairs)
        parted.append(next((i for i, (a, b) in enumerate(pairs) if a.reply.text != b.reply.text), None))
        for a, b in pairs:
            if a.prompt != b.prompt:
                break
            if a.action is not None and b.action is not None:
                diffs.append(float(np.mean(np.abs(a.action - b.action))))
    return {"identical_to_first": same / total if total else None, "first_difference": parted,
            "action_diff_same_prompt": float(np.mean(diffs)) if diffs else None}


def table(result: dict) -> str:
    """The result as Markdown: the rates, then one row per setup and concurrency level, each against the first."""
    r = result["rates"]
    base = result["levels"][0]
    prompts = {(u["encoding"], u["retrieve_k"]) for u in result["setups"]}
    lines = [f"{result['model']} on `{result['strategy']}` (A1, flat, MuJoCo; the paper's protocol, "
             f"{result['queries_per_trial']} LLM queries a trial). Model rates, measured in this run on a fresh model: "
             f"prefill {r['prefill_tok_s']:.0f} tokens/s (a {r['prompt_tokens']}-token takeover prompt read cold), "
             f"decode {r['decode_tok_s']:.1f} tokens/s ({r['decoded_tokens']} free tokens, no grammar, no draft).", "",
             f"Per query in the first row: {base['read_tokens']:.0f} tokens read anew, {base['cached_tokens']:.0f} "
             f"from the prefix cache, {base['decoded_tokens']:.0f} decoded; llama.cpp's own time {base['prefill_s_mean']:.2f} s "
             f"reading + {base['decode_s_mean']:.2f} s decoding; floor {base['floor_s']:.2f} s; measured "
             f"{base['latency_mean_s']:.2f} s = **{base['latency_mean_s'] / base['floor_s']:.2f} x the floor**"
             + (f"; n-gram draft acceptance {base['draft_acceptance']:.2f}" if base.get("draft_acceptance") is not None
                else "") + ".", ""]
    if len(prompts) > 1:
        lines += ["Replies are compared with the first row on the same prompt (layout and examples shown); a setting "
                  "that writes another prompt starts its own comparison.", ""]
    per_hour = "trials an hour (100 queries" + (", extrapolated)" if result["queries_per_trial"] < TRIAL_QUERIES else ")")
    lines += ["| setting | layout | draft | examples | trials at a time (N) | trials | queries | wall (s) | read anew / "
              f"decoded a query | s a query | floor ratio | draft acceptance | queries an hour | {per_hour} | x first row "
              "| replies identical to the first row on this prompt | first differing query, per trial | mean abs action "
              "difference, same prompt |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in result["levels"]:
        same = "-" if row["identical_to_first"] is None else f"{row['identical_to_first']:.2f}"
        parted = ", ".join("none" if i is None else str(i) for i in row["first_difference"])
        diff = "-" if row["action_diff_same_prompt"] is None else f"{row['action_diff_same_prompt']:.3f}"
        lines.append(f"| {row.get('setting') or '-'} | {row['encoding']} | {row['draft']} | {row['retrieve_k']} | "
                     f"{row['n']} | {row['trials']} | {row['queries']} | {row['wall_s']:.0f} | "
                     f"{row['read_tokens']:.0f} / {row['decoded_tokens']:.0f} | {row['latency_mean_s']:.2f} | "
                     f"{row['latency_mean_s'] / row['floor_s']:.2f} | {_acceptance(row)} | "
                     f"{row['queries_per_hour']:.0f} | "
                     f"{row['trials_per_hour']:.2f} | {row['speedup']:.2f} | {same} | {parted} | {diff} |")
    return "\n".join(lines)


def _acceptance(row: dict) -> str:
    """The share of drafted tokens kept, or '-' where nothing was drafted."""
    return "-" if row.get("draft_acceptance") is None else f"{row['draft_acceptance']:.2f}"
