"""The LLM policy and the paper's protocol.

Episode (defaults): the robot stands for `seed_start` s, then the seed RL policy walks and
fills the history with (observation, action) pairs; at `llm_after` s the LLM takes over and
is queried every control step with the description, the last `history` pairs and the current
observation. Simulation time waits while the model thinks. A reply that does not parse is
counted, kept with its text, and handled by holding the last action.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from weakref import WeakKeyDictionary

import numpy as np

from benchmark.trial.cell import CellSpec
from benchmark.trial.resources import Resources, Runtime
from benchmark.trial.trials import KeepPolicy, run_cell
from benchmark.trial.disturbances import DISTURBANCES
from benchmark.trial.clock import CLOCKS, MEASURED, RealtimeClock, parse_latency
from benchmark.llm.encodings import DEFAULT_ENCODING, ENCODINGS, get_encoding
from benchmark.llm.models import (MODEL_FORMS, SERVER_KINDS, LanguageModel, Reply, Sampling,
                                   check_model_spec, make_model)
from benchmark.llm.progress import PromptReading
from benchmark.llm.prompt import LAYOUTS, PARTS, PromptConfig, build_prompt, describe_robot
from benchmark.llm.prompt_inputs import DEFAULT_OBSERVATION, OBSERVATIONS
from benchmark.llm.reference import REFERENCE_KINDS, history_outputs, knn_answer
from benchmark.llm.strategies import DEFAULT_STRATEGY, DISTANCES, MEMORIES, STRATEGIES
from benchmark.llm.replies import parse_reply, reply_constraint
from benchmark.llm.tokens import gpt4_tokens
from benchmark.trial.observation import llm_observation
from benchmark.trial.policies import SeedPolicy
from benchmark.common.settings import SettingError, setting
from robots import Robot
from sims.base import PhysicsConfig, RobotState


HISTORY_MODES = ("auto", "sliding", "block", "shifted")
APPROXIMATE_MODES = ("shifted",)
SHIFT_CHUNK = 64  # tokens: llama.cpp's n_cache_reuse, the smallest cached chunk it moves instead of recomputing
CONTROL_DT = PhysicsConfig().control_dt  # s, the 10 Hz control period every engine runs
STRATEGY_FIELDS = ("prompt_strategy", "retrieve_k", "memory", "distance")  # LLMSettings that shape the examples


def told_condition(settings: LLMSettings, disturbance: str) -> str:
    """What the description says about the disturbance: its `told` sentence with `tell_disturbance`, else nothing."""
    return DISTURBANCES[disturbance].told if settings.tell_disturbance else ""


def is_embedded(model: str) -> bool:
    """Whether a model spec runs in-process on llama.cpp: `embedded[:PATH]` or a ladder name."""
    from benchmark.llm.ladder import known

    return model.split(":")[0] == "embedded" or known(model) is not None


@dataclass(frozen=True)
class LLMSettings:
    """What an LLM cell measures: the model, its prompt and the protocol's timing."""

    model: str = setting("embedded", f"model: {', '.join(MODEL_FORMS)}", flag="--llm")
    url: str | None = setting(None, "OpenAI-compatible base URL, e.g. http://127.0.0.1:8080/v1 (or "
                                    "PROMPTWALK_LLM_URL); the key comes from PROMPTWALK_LLM_API_KEY or "
                                    "OPENAI_API_KEY and is never printed", flag="--llm-url")
    layout: str = setting("completions", "prompt layout: completions (one text) or chat (the description as the "
                                         "system message, history and current input as the user message, as in the "
                                         "paper's code)", choices=LAYOUTS, flag="--llm-layout")
    server: str = setting("auto", "serving stack, for its own constraint field: openai (response_format), vllm "
                                  "(structured_outputs), sglang (regex), llamacpp (grammar), or auto (asks the server)",
                          choices=SERVER_KINDS, flag="--llm-server")
    history: int = setting(50, "observation/action pairs in the prompt", minimum=0)
    history_mode: str = setting("auto", "sliding: exact sliding window (the paper's; re-reads the whole prompt "
                                        "every query); block: exact, grows then cuts 10 pairs at once (prefix cache "
                                        "stays valid between cuts); shifted: sliding window with llama.cpp KV-cache "
                                        "shifting, APPROXIMATE (cached keys/values keep the dropped pair in "
                                        "context), embedded models only; auto: shifted for embedded models on a "
                                        "prompt with a chronological window, sliding for the others (a window-less "
                                        "prompt such as nearest-only has no window to shift)",
                                choices=HISTORY_MODES)
    prompt_strategy: str = setting(DEFAULT_STRATEGY, "which examples the prompt shows above the current input: "
                                   + "; ".join(f"{s.name}: {s.help}" for s in STRATEGIES.values()),
                                   choices=tuple(STRATEGIES), flag="--prompt-strategy", noun="prompt strategy",
                                   added_later=True)
    retrieve_k: int = setting(3, "pairs a retrieving strategy (nearest, nearest-only) shows", positive=True,
                              added_later=True)
    memory: str = setting("demonstrations", "what retrieval reads: demonstrations (every seed-policy pair before the "
                                            "takeover, fixed for the trial), window (the pairs shown) or both",
                          choices=MEMORIES, added_later=True)
    distance: str = setting("l2", "retrieval's distance on the written inputs: l2 (squared Euclidean, as knn) or l1",
                            choices=DISTANCES, added_later=True)
    prompt_parts: tuple[str, ...] = setting(PARTS, "description parts", choices=PARTS)
    encoding: str = setting(DEFAULT_ENCODING, "numbers: " + "; ".join(f"{k} {e.label}" for k, e in ENCODINGS.items()),
                            choices=tuple(ENCODINGS))
    observation: str = setting(DEFAULT_OBSERVATION, "prompt inputs: "
                               + "; ".join(f"{k} {v[0]}" for k, v in OBSERVATIONS.items()), choices=tuple(OBSERVATIONS))
    tell_disturbance: bool = setting(False, "the description says what the cell's disturbance does (e.g. every motor "
                                            "at 60% of its torque; nothing under disturbance none): copying cannot "
                                            "read a sentence, a language model might", added_later=True)
    constrained: bool = setting(True, "grammar/schema on the reply (--no-constrained: the paper's setting)")
    temperature: float = setting(0.0, "sampling temperature", minimum=0)
    llm_after: float = setting(10.0, "s: the LLM takes over and metrics start (with --policy rl: metrics start, "
                                     "default 0)", minimum=0)
    seed_start: float = setting(1.0, "s: the seed policy starts walking and filling the history (with --policy rl: "
                                     "default 0)", minimum=0)
    clock: str = setting("paused", "paused: simulated time waits for every answer (the paper's protocol); realtime: "
                                   "the robot holds its last targets while a query is in flight, an answer applies "
                                   "at the first control step after it arrives, the next query starts at once",
                         choices=CLOCKS)
    latency: str = setting(MEASURED, "realtime clock: 'measured' (each query's wall time) or fixed seconds, simulated "
                                     "(reproducible, any model)")
    block: int = 10  # pairs cut at once in block mode

    eval_start_setting = "llm_after"  # the setting that starts the evaluated phase

    @property
    def eval_start(self) -> float:
        return self.llm_after

    @property
    def prompt(self) -> PromptConfig:
        return PromptConfig(parts=self.prompt_parts, history=self.history, encoding=self.encoding,
                            observation=self.observation, strategy=self.prompt_strategy, k=self.retrieve_k,
                            memory=self.memory, distance=self.distance)

    @property
    def sampling(self) -> Sampling:
        return Sampling(temperature=self.temperature)

    def __post_init__(self) -> None:
        if self.history_mode == "auto":  # resolved here, so every row records the mode that ran
            strategy = STRATEGIES.get(self.prompt_strategy)  # an unknown name is validate()'s to report
            mode = "shifted" if is_embedded(self.model) and (strategy is None or strategy.window) else "sliding"
            object.__setattr__(self, "history_mode", mode)

    @property
    def approximate(self) -> bool:
        return self.history_mode in APPROXIMATE_MODES

    def validate(self) -> None:
        check_model_spec(self.model, require_file=False)  # assembled? asked when a trial runs it
        if self.history_mode == "shifted" and self.model.split(":")[0] == "openai":
            raise SettingError("history_mode 'shifted' needs the embedded model (llama.cpp's KV-cache shifting); "
                               "use sliding or block with a server")
        if not self.seed_start <= self.llm_after:
            raise SettingError(f"seed_start ({self.seed_start:g} s) must not be after llm_after ({self.llm_after:g} s)")
        if self.block < 1:
            raise SettingError(f"block must be >= 1 pair, got {self.block}")
        latency = parse_latency(self.latency)
        if self.clock == "paused" and latency is not None:
            raise SettingError("latency applies to the realtime clock: add --clock realtime")
        if self.clock == "realtime" and latency is None and self.model.split(":")[0] in REFERENCE_KINDS:
            raise SettingError(f"reference model '{self.model}' answers in microseconds: its measured latency says "
                               "nothing; give a fixed --latency SECONDS")


@dataclass
class Query:
    """One LLM call, kept for metrics and recordings."""

    @property
    def prompt_tail(self) -> str:
        """The newest history pair's input onwards: what changed since the last query."""
        return self.prompt[self.prompt.rfind("Input:", 0, self.prompt.rfind("Input:")):]

    time: float
    prompt: str
    reply: Reply
    parsed: bool
    gpt4_in: int
    gpt4_out: int
    action: np.ndarray | None = None  # the decoded reply (None: it did not parse)
    seed_action: np.ndarray | None = None  # the seed policy's action for the same state (never shown to the model)


@dataclass
class _Trial:
    history: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    demonstrations: tuple[tuple[np.ndarray, np.ndarray], ...] = ()  # the seed policy's pairs, frozen at the takeover
    window_start: int = 0
    queries: list[Query] = field(default_factory=list)
    last_action: np.ndarray | None = None
    clock: RealtimeClock | None = None  # realtime cells: the answer in flight and the held targets
    knn_agree: int = 0  # replies within one encoding step of the kNN answer on every value
    violations: int = 0  # replies that break the output constraint (a server that ignored it)
    warmup_s: float | None = None  # realtime, measured latency: the untimed read before the clock starts


_READINGS: WeakKeyDictionary = WeakKeyDictionary()


def _reading_for(model: LanguageModel) -> PromptReading:
    """One `PromptReading` per loaded model: the trials of a sweep that share a model share the reading rate it
    learnt and the last prompt it read, so the second trial's cold read comes with an estimate."""
    try:
        return _READINGS.setdefault(model, PromptReading())
    except TypeError:  # a model that cannot be weakly referenced or hashed: a reading of its own
        return PromptReading()


class LLMPolicy:
    name = "llm"

    def __init__(self, robot: Robot, settings: LLMSettings = LLMSettings(), runtime: Runtime | None = None,
                 model: LanguageModel | None = None, seed_policy=None, disturbance: str = "none") -> None:
        self.robot, self.settings, self.runtime = robot, settings, runtime or Runtime()
        self.seed_policy = seed_policy or SeedPolicy(robot)
        self._owns_model = model is None
        self.model = model or _new_model(settings, self.runtime)
        self.encoding = get_encoding(settings.encoding)
        self.description = describe_robot(robot, settings.prompt, control_hz=1.0 / CONTROL_DT,
                                          condition=told_condition(settings, disturbance))
        self.constraint = reply_constraint(self.encoding, robot.num_joints, settings.constrained)
        self.seed_action = np.zeros(robot.num_joints)  # what the seed policy would do now (for recordings)
        self.last_prompt = ""
        self.reading = _reading_for(self.model)  # lines on stderr while a long prompt is read
        self._trial = _Trial()

    @classmethod
    def from_cell(cls, cell: CellSpec, robot: Robot, resources: Resources) -> LLMPolicy:
        s, rt = cell.settings, resources.runtime
        key = (s.model, s.url, s.layout, s.server, rt.threads, rt.requests_per_minute, rt.cache, s.approximate,
               rt.slots)
        return cls(robot, s, rt, model=resources.model(key, lambda: _new_model(s, rt)), disturbance=cell.disturbance)

    def reset(self, seed: int) -> None:
        self.seed_policy.reset(seed)
        self._trial = _Trial(last_action=np.zeros(self.robot.num_joints))
        if self.settings.clock == "realtime":
            self._trial.clock = RealtimeClock(parse_latency(self.settings.latency))

    def _window(self) -> list[tuple[np.ndarray, np.ndarray]]:
        t, h = self._trial, self.settings.history
        if h == 0:
            return []
        if self.settings.history_mode != "block":  # sliding and shifted show the same window
            return t.history[-h:]
        while len(t.history) - t.window_start > h:  # cut whole blocks: the prompt prefix stays put between cuts
            t.window_start += self.settings.block
        return t.history[t.window_start:]

    def act(self, obs: np.ndarray, state: RobotState) -> np.ndarray:
        t, s = self._trial, self.settings
        self.seed_action = self.seed_policy.act(obs, state)
        llm_obs = llm_observation(obs)
        if state.time < s.seed_start - 1e-9:
            action = np.zeros(self.robot.num_joints)
        elif state.time < s.llm_after - 1e-9:
            if self._warms_up and state.time >= s.llm_after - CONTROL_DT - 1e-9:
                self._warm_up(llm_obs)
            action = self.seed_action
            t.history.append((llm_obs, action))
        elif t.clock is None:
            action = self._query(llm_obs, state.time)
            t.history.append((llm_obs, action))
        else:  # realtime: the history records the 10 Hz stream and the targets actually applied (holds too)
            if not t.clock.latencies:
                t.clock.reset(t.last_action)  # until the first answer arrives, the seed policy's last targets
            action = t.clock.step(state.time, lambda: (self._query(llm_obs, state.time),
                                                       t.queries[-1].reply.latency_s))
            t.history.append((llm_obs, action))
        t.last_action = action
        return action

    @property
    def _warms_up(self) -> bool:
        """Realtime with measured latency: the model reads the prompt once before the clock starts."""
        return self._trial.clock is not None and self._trial.clock.latency is None and \
            getattr(self.model, "reads_prompt", True)

    def _warm_up(self, llm_obs: np.ndarray) -> None:
        """Read the prompt of the last step before the takeover, untimed, and drop the reply: a deployed controller
        reads its description and history while the seed policy walks, so the first timed query, like every
        later one, reads only what is new (otherwise it would read the whole ~10k-token prompt cold)."""
        prompt = build_prompt(self.description, self._window(), llm_obs, self.settings.prompt, tuple(self._trial.history))
        self._trial.warmup_s = self._complete(prompt, cold=True).latency_s

    def _complete(self, prompt: str, cold: bool) -> Reply:
        """The model's reply; a model that reads its prompt reports long reads and teaches the reading rate."""
        if not getattr(self.model, "reads_prompt", True):
            return self.model.complete(prompt, self.settings.sampling, self.constraint, cold=cold)
        with self.reading.reading(prompt, cold, shifted=self.settings.history_mode == "shifted"):
            reply = self.model.complete(prompt, self.settings.sampling, self.constraint, cold=cold)
        if not reply.cached:
            self.reading.learn(prompt, reply.prompt_tokens, reply.prompt_tokens - reply.cached_tokens,
                               reply.latency_s)
        return reply

    def _query(self, llm_obs: np.ndarray, now: float) -> np.ndarray:
        t = self._trial
        if not t.queries:  # the takeover: what the seed policy demonstrated, and nothing after it
            t.demonstrations = tuple(t.history)
        prompt = build_prompt(self.description, self._window(), llm_obs, self.settings.prompt, t.demonstrations)
        self.last_prompt = prompt
        if getattr(self.model, "privileged", False):  # the oracle reference model: the seed policy's answer
            self.model.set_reference(self.seed_action, self.encoding)
        # a trial's first query reuses nothing cached: a trial that followed another in one process could reuse
        # its cached prefix, computed in one batch with another prompt, and a greedy near-tie then flipped
        reply = self._complete(prompt, cold=not t.queries and t.warmup_s is None)
        action = parse_reply(reply.text, self.encoding, self.robot.num_joints)
        if getattr(self.model, "obeys_constraint", True) and self.constraint.violated_by(reply.text):
            t.violations += 1
            _warn_once(self.model, reply.text)
        knn = parse_reply(knn_answer(prompt), self.encoding, self.robot.num_joints)
        t.knn_agree += int(action is not None and knn is not None
                           and bool(np.all(np.abs(action - knn) <= self.encoding.resolution + 1e-9)))
        t.queries.append(Query(now, prompt, reply, action is not None, gpt4_tokens(prompt), gpt4_tokens(reply.text),
                               action=action, seed_action=self.seed_action.copy()))
        return action if action is not None else t.last_action  # unparseable: hold the last action

    @property
    def queries(self) -> list[Query]:
        return self._trial.queries

    def metrics(self) -> dict:
        q = self._trial.queries
        if not q:
            return {"queries": 0, "parse_failures": 0}
        latency = np.array([x.reply.latency_s for x in q if not x.reply.cached] or [0.0])
        tokens_in = np.array([x.reply.prompt_tokens for x in q], dtype=float)
        cached_in = np.array([x.reply.cached_tokens for x in q if not x.reply.cached] or [0], dtype=float)
        tokens_out = np.array([x.reply.completion_tokens for x in q], dtype=float)
        out = {
            "queries": len(q),
            "parse_failures": sum(not x.parsed for x in q),
            "failed_replies": [x.reply.text for x in q if not x.parsed][:5],
            "input_tokens": float(tokens_in.mean()),
            "cached_input_tokens": float(cached_in.mean()),
            "retries": sum(x.reply.retries for x in q),
            "constraint_violations": self._trial.violations,
            "layout": self.settings.layout,
            "server_kind": getattr(getattr(self.model, "inner", self.model), "server", None),
            "output_tokens": float(tokens_out.mean()),
            "gpt4_input_tokens": float(np.mean([x.gpt4_in for x in q])),
            "gpt4_output_tokens": float(np.mean([x.gpt4_out for x in q])),
            "latency_mean_s": float(latency.mean()),
            # every reply's latency as measured when it was made (a cached reply keeps its first measurement): what
            # the trial would have cost live, where latency_mean_s covers the live replies only
            "latency_recorded_mean_s": float(np.mean([x.reply.latency_s for x in q])),
            "latency_p95_s": float(np.percentile(latency, 95)),
            "realtime_factor": float(CONTROL_DT / latency.mean()) if latency.mean() > 0 else None,
            "cache_hits": sum(x.reply.cached for x in q),
            "knn_agreement": self._trial.knn_agree / len(q),
            "approximate_history": self.settings.approximate,
            "clock": self.settings.clock,
            **closed_loop_diagnostics(q, self._trial.demonstrations, self.encoding),
            **query_timings(q),
        }
        if self._trial.clock is not None:
            out.update(self._trial.clock.metrics())
            out["warmup_s"] = self._trial.warmup_s
        rt = self.runtime
        if rt.price_in is not None and rt.price_out is not None:
            cached = float(sum(x.reply.cached_tokens for x in q))
            cached_price = rt.price_in if rt.price_cached_in is None else rt.price_cached_in
            out["cost_usd"] = float(((tokens_in.sum() - cached) * rt.price_in + cached * cached_price
                                     + tokens_out.sum() * rt.price_out) / 1e6)
        return out

    def close(self) -> None:
        if self._owns_model:
            self.model.close()


def query_timings(queries: list[Query]) -> dict:
    """Where the live queries' time went, from the server's own timings (llama.cpp): tokens read anew and decoded,
    seconds evaluating and decoding, and the n-gram draft's acceptance. Empty where the server reports none."""
    timed = [x.reply for x in queries if not x.reply.cached and x.reply.read_tokens is not None]
    if not timed:
        return {}
    drafted = sum(r.draft_tokens for r in timed)
    return {"read_tokens": float(np.mean([r.read_tokens for r in timed])),
            "prefill_s_mean": float(np.mean([r.prefill_s for r in timed])),
            "decode_s_mean": float(np.mean([r.decode_s for r in timed])),
            "draft_tokens": drafted, "draft_acceptance": sum(r.draft_accepted for r in timed) / drafted if drafted else None}


def strategy_label(settings: LLMSettings) -> str:
    """The prompt strategy as reports name it: `nearest (K 3, demonstrations, l2)`; the paper's is `chronological`."""
    s = settings
    return strategy_text(s.prompt_strategy, s.retrieve_k, s.memory, s.distance)


def strategy_text(strategy: str, k: int, memory: str, distance: str) -> str:
    """`strategy_label` from a row's columns."""
    if not STRATEGIES[strategy].retrieves:
        return strategy
    return f"{strategy} (K {int(k)}, {memory}, {distance})"


def closed_loop_diagnostics(queries: list[Query], demonstrations, enc) -> dict:
    """Whether a model freezes, copies or drifts: per trial, the fraction of replies that repeat the action
    before them or copy an example line of their prompt verbatim, and each reply's distance (mean absolute,
    action units, as written) from the nearest demonstration action and from the seed policy's action for the
    same state (the oracle, computed alongside). The per-query series (decoded replies, seed actions) are kept
    for figures. An unparsed reply counts as the held action it became."""
    demo = np.array([enc.quantize(a) for _, a in demonstrations]) if demonstrations else None
    previous = enc.quantize(demonstrations[-1][1]) if demonstrations else None
    repeats = copies = 0
    to_demo, to_seed, llm_series, seed_series = [], [], [], []
    for q in queries:
        answer = enc.quantize(q.action) if q.action is not None else previous
        seed = enc.quantize(q.seed_action)
        if previous is not None and answer is not None and np.allclose(answer, previous, atol=enc.resolution / 2):
            repeats += 1
        written = parse_reply_list(q.reply.text)
        copies += int(written is not None and written in {_normal(o) for o in history_outputs(q.prompt)})
        if answer is not None:
            if demo is not None:
                to_demo.append(float(np.abs(demo - answer).mean(axis=1).min()))
            to_seed.append(float(np.abs(answer - seed).mean()))
            llm_series.append([round(float(v), 4) for v in answer])
            seed_series.append([round(float(v), 4) for v in seed])
        previous = answer
    n = max(len(queries), 1)
    return {"repeat_fraction": repeats / n, "copy_fraction": copies / n,
            "demo_distance_mean": float(np.mean(to_demo)) if to_demo else None,
            "oracle_distance_mean": float(np.mean(to_seed)) if to_seed else None,
            "diag_llm_actions": llm_series, "diag_seed_actions": seed_series}


def _normal(text: str) -> str:
    return "".join(text.split())


def parse_reply_list(text: str) -> str | None:
    """The bracketed list a reply writes, without spaces (to compare with the prompt's example lines)."""
    start, end = text.find("["), text.find("]")
    return _normal(text[start:end + 1]) if 0 <= start < end else None


def _new_model(settings: LLMSettings, runtime: Runtime) -> LanguageModel:
    """The cell's model; a realtime cell with measured latency never reads the reply cache (a cached reply's
    latency is another run's)."""
    live = settings.clock == "realtime" and parse_latency(settings.latency) is None
    return make_model(settings.model, url=settings.url, layout=settings.layout, server=settings.server,
                      cache=runtime.cache and not live,
                      threads=runtime.threads, requests_per_minute=runtime.requests_per_minute,
                      cache_reuse=SHIFT_CHUNK if settings.approximate else 0, draft=runtime.draft,
                      parallel=runtime.slots)


def takeover_prompt(cell: CellSpec, seed: int = 0) -> str:
    """The prompt an LLM cell's model gets at its takeover, from a real rollout: the seed policy fills
    the history and a reference model that only echoes stands in, so nothing is queried."""
    s = cell.settings
    takeover = round(s.seed_start + CONTROL_DT * s.history, 6)
    probe = replace(cell, duration=takeover + CONTROL_DT, settings=replace(s, model="hold", llm_after=takeover))
    watch = KeepPolicy()
    run_cell(probe, [seed], hooks=[watch])
    return watch.policy.last_prompt


_WARNED: set[str] = set()


def _warn_once(model: LanguageModel, text: str) -> None:
    """One warning per model and run: a server that ignores the constraint field is visible at once."""
    if model.id in _WARNED:
        return
    _WARNED.add(model.id)
    print(f"bench: warning: a reply broke the output constraint ({text.strip()[:60]!r}); does the server read its "
          "constraint field? (--llm-server); counted in constraint_violations", file=sys.stderr)
