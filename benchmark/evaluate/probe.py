"""The imitation probe: how well does a model continue the seed policy's examples, under teacher forcing?

    bench probe --make                      write the probe set (seed-policy rollouts, as numbers)
    bench probe --llm knn                   score a model on every item
    bench probe --llm embedded --history 10 --items 5

The probe set holds, per cell (A1 and ANYmal, flat and rough, MuJoCo), a few seed-policy walks
under the paper's fixed command: the 33-dim LLM observation and the seed action of every control
step from the seed policy's start. A cell named ROBOT/TERRAIN/DISTURBANCE walks disturbed from the
takeover on (`benchmark.trial.disturbances`; the hard track): its items ask for the seed policy's
answer to a body or a shove the prompt's examples never showed. An *item* is one step after the
takeover (10 s): its history is the pairs before it, its input the current observation, its label the seed
policy's action. Items are numbers, not text, so any prompt setting renders them (history, encoding,
observation choice, description parts, layout). Every model answers through the closed loop's own path: the same
prompt, constraint, reply parsing and decoding; an unparseable reply counts as a parse failure and
as the `hold` answer, as in closed loop.

Teacher forcing: the robot walks the seed policy's trajectory whatever the model says, so every
model meets the same prompts and the comparison is paired. It measures imitation, not control: a
model that imitates well may still fall once its own errors feed back (closed loop, `bench run`).

Window `grow` (default, exact): the items of one walk share their prompt prefix, the history
growing by the true pair from `history` pairs at the first item to history + items - 1 at the last,
so llama.cpp's prefix cache re-reads only the new pair (no KV shifting). `slide` keeps exactly
`history` pairs (each item re-reads the window).

Scores, per cell and overall: error = mean absolute difference of the decoded reply from the
label written in the encoding (action units; what a perfect model can write, so `oracle` scores 0);
skill = 1 - error / error of `hold` (the newest action in the prompt): hold 0, oracle 1, below 0
worse than freezing; the fraction of replies within one encoding step on all 12 values; per-joint
error; parse failures, tokens and latency; 95% bootstrap intervals over items.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmark.common.settings import SettingError, setting
from benchmark.common.skill import item_resamples, skill, skill_difference
from benchmark.llm.controller import CONTROL_DT, LLMSettings, _new_model, told_condition
from benchmark.llm.encodings import get_encoding
from benchmark.llm.prompt import build_prompt, describe_robot
from benchmark.llm.reference import HoldModel, knn_answer
from benchmark.llm.replies import parse_reply, reply_constraint
from benchmark.trial.cell import make_cell
from benchmark.trial.disturbances import DISTURBANCES
from benchmark.trial.observation import llm_observation
from benchmark.trial.policies import seed_policy_path
from benchmark.trial.resources import Runtime
from benchmark.trial.trials import TrialHooks, run_cell
from robots import load_robot
from sims.terrain import TERRAINS

PROBE_VERSION = 1
DEFAULT_PROBE = Path(__file__).parent / "data" / f"probe-v{PROBE_VERSION}.npz"
WINDOWS = ("grow", "slide")


class ProbeError(ValueError):
    """A probe file that is missing, corrupt or of another version: one line for the user."""


@dataclass(frozen=True)
class ProbeSetConfig:
    """How the probe set is made (`bench probe --make`)."""

    cells: tuple[str, ...] = ("a1/flat", "a1/rough", "anymal/flat", "anymal/rough")  # ROBOT/TERRAIN[/DISTURBANCE]
    sim: str = "mujoco"
    rollouts: int = 3  # walks per cell (seeds 0, 1, ...)
    items: int = 10  # consecutive items per walk, from the takeover on
    seed_start: float = 1.0  # s: the seed policy starts walking (the paper's protocol)
    takeover: float = 10.0  # s: the first item (the LLM's takeover in the paper's protocol)

    def __post_init__(self) -> None:
        for name in self.cells:
            probe_cell(name)


def probe_cell(name: str) -> tuple[str, str, str]:
    """(robot, terrain, disturbance) of a probe cell's name, ROBOT/TERRAIN or ROBOT/TERRAIN/DISTURBANCE; a name
    that is neither, or names an unknown terrain or disturbance, is a ProbeError."""
    parts = name.split("/")
    if len(parts) not in (2, 3) or not all(parts):
        raise ProbeError(f"probe cell '{name}': expected ROBOT/TERRAIN or ROBOT/TERRAIN/DISTURBANCE, e.g. a1/flat or "
                         "a1/flat/weak_motors")
    robot, terrain, disturbance = (*parts, "none") if len(parts) == 2 else parts
    if terrain not in TERRAINS:
        raise ProbeError(f"probe cell '{name}': unknown terrain '{terrain}'; valid: {', '.join(TERRAINS)}")
    if disturbance not in DISTURBANCES:
        raise ProbeError(f"probe cell '{name}': unknown disturbance '{disturbance}'; valid: {', '.join(DISTURBANCES)}")
    return robot, terrain, disturbance


@dataclass(frozen=True)
class Walk:
    """One seed-policy walk: pairs from the seed policy's start; items start at `first_item`."""

    cell: str  # "robot/terrain"
    seed: int
    observations: np.ndarray  # (T, 33) LLM observations, the input before each action
    actions: np.ndarray  # (T, 12) seed-policy actions (normalized)
    first_item: int  # index of the first item's pair

    @property
    def robot(self) -> str:
        return self.cell.split("/")[0]


@dataclass(frozen=True)
class ProbeSet:
    walks: tuple[Walk, ...]
    meta: dict
    digest: str

    @property
    def cells(self) -> list[str]:
        return list(dict.fromkeys(w.cell for w in self.walks))

    def items(self) -> int:
        return sum(len(w.actions) - w.first_item for w in self.walks)


class _Pairs(TrialHooks):
    """Records (LLM observation before the step, action of the step) from the seed policy's start."""

    def __init__(self, start_step: int) -> None:
        self.start_step, self.observations, self.actions = start_step, [], []

    def start(self, seed, sim, policy, episode):
        before = [None]

        def record(loop) -> None:
            if loop.steps > self.start_step and before[0] is not None:
                self.observations.append(llm_observation(before[0]))
                self.actions.append(loop.action.copy())
            before[0] = loop.obs.copy()
        return record


def make_probe_set(config: ProbeSetConfig = ProbeSetConfig(), progress: Callable[[str], None] = print) -> ProbeSet:
    """Walk the seed policy in every cell and keep the numbers of every step."""
    start_step = int(round(config.seed_start / CONTROL_DT))
    first_item = int(round(config.takeover / CONTROL_DT)) - start_step
    duration = config.takeover + config.items * CONTROL_DT
    walks, policies = [], {}
    for name in config.cells:
        robot, terrain, disturbance = probe_cell(name)
        path = seed_policy_path(load_robot(robot))
        policies[robot] = hashlib.sha256(path.read_bytes()).hexdigest()
        cell = make_cell({"sim": config.sim, "robot": robot, "terrain": terrain, "policy": "rl",
                          "seed_start": config.seed_start, "llm_after": config.takeover,
                          "disturbance": disturbance, "duration": duration})
        kept, seed = 0, 0
        while kept < config.rollouts:  # a walk that falls is skipped: items need a walking robot
            if seed >= 4 * config.rollouts:
                raise ProbeError(f"the seed policy fell in {seed - kept} of {seed} walks of {name}; "
                                 "a probe set needs walks that do not fall")
            pairs = _Pairs(start_step)
            result = run_cell(cell, [seed], hooks=[pairs])[0]
            if result.fall_time is None:
                walks.append(Walk(name, seed, np.array(pairs.observations), np.array(pairs.actions), first_item))
                kept += 1
            progress(f"probe set: {name} seed {seed}: "
                     + (f"{len(pairs.actions)} pairs" if result.fall_time is None else "fell, skipped"))
            seed += 1
    meta = {"version": PROBE_VERSION, "config": dataclasses.asdict(config), "seed_policy_sha256": policies}
    return ProbeSet(tuple(walks), meta, _digest(walks, meta))


def _digest(walks, meta: dict) -> str:
    h = hashlib.sha256(json.dumps(meta, sort_keys=True).encode())
    for w in walks:
        h.update(f"{w.cell}/{w.seed}/{w.first_item}".encode())
        h.update(np.ascontiguousarray(w.observations, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(w.actions, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def save_probe_set(probe: ProbeSet, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for i, w in enumerate(probe.walks):
        arrays[f"obs{i}"], arrays[f"act{i}"] = w.observations, w.actions
    walks = [{"cell": w.cell, "seed": w.seed, "first_item": w.first_item} for w in probe.walks]
    np.savez_compressed(path, **arrays, meta=np.array(json.dumps({**probe.meta, "walks": walks,
                                                                  "digest": probe.digest})))
    return path


def load_probe_set(path: Path | str = DEFAULT_PROBE) -> ProbeSet:
    """The probe set at `path`, its digest checked; a missing, corrupt or other-version file is a ProbeError."""
    path = Path(path)
    if not path.is_file():
        raise ProbeError(f"no probe set at '{path}'; make one with 'bench probe --make --out {path}'")
    try:
        with np.load(path) as data:
            meta = json.loads(str(data["meta"]))
            walks = tuple(Walk(w["cell"], int(w["seed"]), data[f"obs{i}"].astype(np.float64),
                               data[f"act{i}"].astype(np.float64), int(w["first_item"]))
                          for i, w in enumerate(meta.pop("walks")))
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as err:
        raise ProbeError(f"'{path}' is not a probe set readable by this version ({type(err).__name__}); make one "
                         "with 'bench probe --make'") from None
    if meta.get("version") != PROBE_VERSION:
        raise ProbeError(f"'{path}' is a version {meta.get('version')} probe set; this promptwalk reads version "
                         f"{PROBE_VERSION}: make one with 'bench probe --make'")
    stated = meta.pop("digest", None)
    digest = _digest(walks, meta)
    if stated != digest:
        raise ProbeError(f"'{path}' is corrupt: its contents hash to {digest}, not the {stated} it states")
    return ProbeSet(walks, meta, digest)


@dataclass(frozen=True)
class ProbeRun:
    """What one probe run measures: the model and prompt (closed loop's own settings), the window, the items."""

    llm: LLMSettings = LLMSettings(history=10)
    window: str = setting("grow", "grow: the history grows by the true pair along a walk's items (exact, "
                                  "prefix-cached); slide: exactly --history pairs per item", choices=WINDOWS)
    items: int | None = setting(None, "items per walk (default: all the probe set holds)", positive=True)
    cells: tuple[str, ...] | None = None  # "robot/terrain" names; None: every cell of the probe set


OPTIONAL_FIELDS = ("prompt_hold_errors", "prompt_knn_errors", "cached")  # absent from records made before them
BOOL_FIELDS = ("within_step", "parsed", "cached")


@dataclass
class ItemAnswers:
    """Per-item results of one model on one probe run, in the probe's item order."""

    cells: list[str]
    errors: np.ndarray  # (N,) mean abs error against the encoded label, action units
    hold_errors: np.ndarray  # (N,) the same for `hold`
    joint_errors: np.ndarray  # (N, 12)
    within_step: np.ndarray  # (N,) bool: all 12 values within one encoding step
    parsed: np.ndarray  # (N,) bool
    prompt_tokens: np.ndarray
    completion_tokens: np.ndarray
    latency_s: np.ndarray
    wall_s: float = 0.0
    # the same prompt's trivial answers: its last example line (`hold` on this prompt) and `knn` on its examples
    prompt_hold_errors: np.ndarray | None = None
    prompt_knn_errors: np.ndarray | None = None
    cached: np.ndarray | None = None  # (N,) bool: from the on-disk reply cache (its latency is the first read's)

    def to_json(self, fields: tuple[str, ...] | None = None, digits: int | None = None) -> dict:
        """The named fields (default all) as JSON values, float arrays rounded to `digits` if given."""
        out = {}
        for f in dataclasses.fields(self):
            if fields is not None and f.name not in fields:
                continue
            value = getattr(self, f.name)
            if value is None:
                continue
            if isinstance(value, np.ndarray):
                value = (value.round(digits) if digits is not None and value.dtype.kind == "f" else value).tolist()
            out[f.name] = value
        return out

    @classmethod
    def from_json(cls, d: dict) -> ItemAnswers:
        """Answers from `to_json`; fields a compact record left out are zeros."""
        n = len(d["cells"])
        def absent(name: str) -> np.ndarray | None:
            return None if name in OPTIONAL_FIELDS else np.zeros((n, 12) if name == "joint_errors" else n)

        arrays = {f.name: np.array(d[f.name], dtype=bool if f.name in BOOL_FIELDS else float) if f.name in d
                  else absent(f.name) for f in dataclasses.fields(cls) if f.name not in ("cells", "wall_s")}
        arrays["joint_errors"] = arrays["joint_errors"].reshape(-1, 12)
        return cls(list(d["cells"]), wall_s=float(d.get("wall_s", 0.0)), **arrays)


def _prompts(probe: ProbeSet, run: ProbeRun):
    """(walk, item index, history pairs, demonstrations, current observation, label) for every item, walk by walk.
    The demonstrations are the walk's pairs before its first item (the takeover), as in closed loop."""
    h = run.llm.history
    for walk in probe.walks:
        if run.cells is not None and walk.cell not in run.cells:
            continue
        last = len(walk.actions) if run.items is None else min(len(walk.actions), walk.first_item + run.items)
        for k in range(walk.first_item, last):
            begin = (walk.first_item if run.window == "grow" else k) - h
            if begin < 0:
                raise SettingError(f"history {h} needs {h} pairs before the takeover; the probe set holds "
                                   f"{walk.first_item}")
            history = list(zip(walk.observations[begin:k], walk.actions[begin:k])) if h else []
            demonstrations = tuple(zip(walk.observations[:walk.first_item], walk.actions[:walk.first_item]))
            yield walk, k, history, demonstrations, walk.observations[k], walk.actions[k]


def probe_history_mode(llm: LLMSettings, window: str) -> str:
    """The history mode a probe run reads with: a sliding window of an approximate mode shifts the KV cache as closed
    loop does; every other read (a growing window above all) is exact."""
    return "shifted" if window == "slide" and llm.approximate else "sliding"


def probe_model(run: ProbeRun, runtime: Runtime = Runtime()):
    """The model a probe run queries, reading with `probe_history_mode`."""
    return _new_model(dataclasses.replace(run.llm, history_mode=probe_history_mode(run.llm, run.window)), runtime)


def answer_items(probe: ProbeSet, run: ProbeRun, runtime: Runtime = Runtime(), model=None,
                 progress: Callable[[int, int], None] | None = None) -> ItemAnswers:
    """Every item answered by the model, through the closed loop's prompt, constraint and parser."""
    s, enc = run.llm, get_encoding(run.llm.encoding)
    owned = model is None
    if owned:
        model = probe_model(run, runtime)
    total = sum(1 for _ in _prompts(probe, run))
    rows, started, described, last_walk = [], time.perf_counter(), {}, None
    try:
        for walk, k, history, demonstrations, obs, label in _prompts(probe, run):
            disturbance = probe_cell(walk.cell)[2]
            if (walk.robot, disturbance) not in described:  # description and constraint: once each, as in closed loop
                robot = load_robot(walk.robot)
                condition = told_condition(s, disturbance)
                described[walk.robot, disturbance] = (
                    describe_robot(robot, s.prompt, control_hz=1.0 / CONTROL_DT, condition=condition),
                    reply_constraint(enc, robot.num_joints, s.constrained), robot.num_joints)
            description, constraint, n = described[walk.robot, disturbance]
            prompt = build_prompt(description, history, obs, s.prompt, demonstrations)
            target = enc.quantize(label)
            held_q = enc.quantize(history[-1][1] if history else np.zeros(n))
            trivial = [_decoded_or(text, enc, n, held_q) for text in (HoldModel().reply_to(prompt), knn_answer(prompt))]
            if getattr(model, "privileged", False):
                model.set_reference(label, enc)
            reply = model.complete(prompt, s.sampling, constraint, cold=walk is not last_walk)
            last_walk = walk
            action = parse_reply(reply.text, enc, n)
            answer = action if action is not None else held_q
            diff = np.abs(answer - target)
            rows.append((walk.cell, diff.mean(), np.abs(held_q - target).mean(), diff,
                         bool(np.all(diff <= enc.resolution + 1e-9)), action is not None, reply.prompt_tokens,
                         reply.completion_tokens, reply.latency_s, *(np.abs(a - target).mean() for a in trivial),
                         reply.cached))
            if progress is not None:
                progress(len(rows), total)
    finally:
        if owned:
            model.close()
    cols = list(zip(*rows)) if rows else [[]] * 12
    return ItemAnswers(list(cols[0]), np.array(cols[1]), np.array(cols[2]), np.array(cols[3]).reshape(-1, 12),
                       np.array(cols[4], dtype=bool), np.array(cols[5], dtype=bool), np.array(cols[6], dtype=float),
                       np.array(cols[7], dtype=float), np.array(cols[8], dtype=float),
                       wall_s=time.perf_counter() - started, prompt_hold_errors=np.array(cols[9], dtype=float),
                       prompt_knn_errors=np.array(cols[10], dtype=float), cached=np.array(cols[11], dtype=bool))


def _decoded_or(text: str, enc, n: int, fallback: np.ndarray) -> np.ndarray:
    """A reference answer's text decoded, or `fallback` (the held action) when it does not parse."""
    action = parse_reply(text, enc, n)
    return action if action is not None else fallback


def concat_answers(parts: list[ItemAnswers]) -> ItemAnswers:
    """Several runs' answers, one after another (wall times add up)."""
    if not parts:
        return ItemAnswers([], *(np.zeros(0) for _ in range(2)), np.zeros((0, 12)), np.zeros(0, bool),
                           np.zeros(0, bool), *(np.zeros(0) for _ in range(3)))
    optional = {f: np.concatenate([getattr(a, f) for a in parts]) for f in OPTIONAL_FIELDS
                if all(getattr(a, f) is not None for a in parts)}
    return ItemAnswers(sum((a.cells for a in parts), []),
                       *(np.concatenate([getattr(a, f) for a in parts]) for f in
                         ("errors", "hold_errors", "joint_errors", "within_step", "parsed", "prompt_tokens",
                          "completion_tokens", "latency_s")), wall_s=sum(a.wall_s for a in parts), **optional)


def answer_walks(probe: ProbeSet, run: ProbeRun, runtime: Runtime = Runtime(), partial: Path | None = None,
                 progress: Callable[[int, int], None] | None = None) -> ItemAnswers:
    """`answer_items`, walk by walk: each finished walk is saved to `partial` (JSON), and walks already there
    are not asked again, so a probe of hours resumes where it was stopped. Every walk starts cold anyway."""
    walks = [w for w in probe.walks if run.cells is None or w.cell in run.cells]
    sizes = [sum(1 for _ in _prompts(dataclasses.replace(probe, walks=(w,)), run)) for w in walks]
    saved = json.loads(partial.read_text()) if partial is not None and partial.is_file() else {}
    if saved.get("digest") != probe.digest:
        saved = {"digest": probe.digest, "walks": {}}
    total, model, parts = sum(sizes), None, []
    done = sum(size for i, size in enumerate(sizes) if str(i) in saved["walks"])
    if done:
        print(f"bench: probe: {done} of {total} items already answered (in {partial}); resuming", file=sys.stderr)
    try:
        for i, (walk, size) in enumerate(zip(walks, sizes)):
            if str(i) in saved["walks"]:
                parts.append(ItemAnswers.from_json(saved["walks"][str(i)]))
                continue
            model = model or probe_model(run, runtime)
            offset = done
            answers = answer_items(dataclasses.replace(probe, walks=(walk,)), run, runtime, model=model,
                                   progress=None if progress is None else lambda k, _: progress(offset + k, total))
            parts.append(answers)
            done += size
            if partial is not None:
                saved["walks"][str(i)] = answers.to_json()
                partial.parent.mkdir(parents=True, exist_ok=True)
                partial.with_suffix(".tmp").write_text(json.dumps(saved))
                partial.with_suffix(".tmp").replace(partial)
    finally:
        if model is not None:
            model.close()
    return concat_answers(parts)


def bootstrap_skill(answers: ItemAnswers, seed: int = 0) -> tuple[float, float]:
    """95% percentile interval of the overall skill over items."""
    cells = np.array(answers.cells)
    draws = [skill(answers.errors[i], answers.hold_errors[i], cells[i]) for i in item_resamples(cells, seed)]
    low, high = np.percentile(draws, [2.5, 97.5])
    return float(low), float(high)


def paired_comparison(a: ItemAnswers, b: ItemAnswers, seed: int = 0) -> float:
    """P(skill of a > skill of b) over bootstrap resamples of the same items (a paired comparison)."""
    if a.cells != b.cells or not np.allclose(a.hold_errors, b.hold_errors):
        raise ValueError("a paired comparison needs two runs over the same items and prompt settings")
    cells = np.array(a.cells)
    wins = [skill(a.errors[i], a.hold_errors[i], cells[i]) > skill(b.errors[i], b.hold_errors[i], cells[i])
            for i in item_resamples(cells, seed)]
    return float(np.mean(wins))


def paired_gain(a: ItemAnswers, b: ItemAnswers, seed: int = 0) -> tuple[float, float, float]:
    """skill(a) - skill(b) over the same items, with its 95% paired bootstrap interval."""
    if a.cells != b.cells or not np.allclose(a.hold_errors, b.hold_errors):
        raise ValueError("a paired gain needs two runs over the same items and prompt settings")
    return skill_difference(a.errors, b.errors, a.hold_errors, np.array(a.cells), seed)


def subset(answers: ItemAnswers, cells: list[str] | tuple[str, ...]) -> ItemAnswers:
    """The items of these cells only, in their order."""
    keep = np.array([c in cells for c in answers.cells], dtype=bool)
    values = {f.name: (getattr(answers, f.name)[keep] if isinstance(getattr(answers, f.name), np.ndarray) else
                       getattr(answers, f.name)) for f in dataclasses.fields(answers) if f.name != "cells"}
    return ItemAnswers([c for c, k in zip(answers.cells, keep) if k], **values)


def summarize_answers(answers: ItemAnswers) -> dict:
    """Per cell and overall: error, skill with its interval, within one step, per joint, failures, cost."""
    cells = np.array(answers.cells)
    out: dict = {"items": len(cells), "skill": skill(answers.errors, answers.hold_errors, cells)}
    out["skill_low"], out["skill_high"] = bootstrap_skill(answers)
    out.update({"error": float(answers.errors.mean()), "hold_error": float(answers.hold_errors.mean()),
                "within_step": float(answers.within_step.mean()), "parse_failures": int((~answers.parsed).sum()),
                "joint_error": answers.joint_errors.mean(axis=0).round(4).tolist(),
                "prompt_tokens": float(answers.prompt_tokens.mean()),
                "completion_tokens": float(answers.completion_tokens.mean()),
                "latency_median_s": float(np.median(answers.latency_s)), "wall_s": answers.wall_s})
    if answers.cached is not None:
        out["cached_replies"] = int(answers.cached.sum())
    out["cells"] = {c: {"items": int((cells == c).sum()), "error": float(answers.errors[cells == c].mean()),
                        "skill": skill(answers.errors[cells == c], answers.hold_errors[cells == c], cells[cells == c]),
                        "within_step": float(answers.within_step[cells == c].mean())} for c in dict.fromkeys(cells)}
    if answers.prompt_hold_errors is not None and answers.prompt_knn_errors is not None:
        out["same_prompt"] = same_prompt_gain(answers)
    return out


def same_prompt_gain(answers: ItemAnswers, seed: int = 0) -> dict:
    """The prompt's own trivial answers (its last example line, `hold`; `knn` on its examples), scored as skill on
    the same items, and the model's gain over the better of the two with a paired 95% bootstrap interval. A gain
    at or below 0 says the prompt, not the model, carries the imitation."""
    cells = np.array(answers.cells)
    trivial = {"hold": answers.prompt_hold_errors, "knn": answers.prompt_knn_errors}
    skills = {name: skill(e, answers.hold_errors, cells) for name, e in trivial.items()}
    best = max(skills, key=lambda name: skills[name])
    gain, low, high = skill_difference(answers.errors, trivial[best], answers.hold_errors, cells, seed)
    return {"hold_skill": skills["hold"], "knn_skill": skills["knn"], "best": best,
            "gain": gain, "gain_low": low, "gain_high": high}


class ProbeProgress:
    """The `progress` of a probe run: a line every `every` items, with an ETA from the run's mean rate (each walk
    starts with a cold read of its prompt, so a recent rate would forget the walks still to come)."""

    def __init__(self, every: int = 10) -> None:
        self.every, self.created, self.start = every, time.monotonic(), None

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if self.start is None:  # the first answer of this run, timed from the start (a resumed run starts past 0)
            self.start = (self.created, done - 1)
        if done == total or done % self.every == 0:
            (t0, n0), tail = self.start, ""
            if done < total and done > n0 and now > t0:
                tail = f", ETA {(now - t0) / (done - n0) * (total - done) / 60:.1f} min"
            print(f"bench: probe: {done}/{total} items{tail}", file=sys.stderr, flush=True)
