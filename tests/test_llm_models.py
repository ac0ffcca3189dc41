"""The real embedded model, a real OpenAI-compatible HTTP server on loopback, the reply cache,
and the LLM policy end to end."""

from __future__ import annotations

import contextlib
import io
import json
import os
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from benchmark.cli.main import main
from benchmark.llm.encodings import ENCODINGS
from benchmark.llm.models import CachedModel, Constraint, EmbeddedModel, LLMError, OpenAIModel, Sampling, make_model
from benchmark.llm.prompt import HISTORY_HEADER
from benchmark.llm.replies import gbnf_grammar, json_schema, parse_reply, reply_regex

PROMPT = ("Input: [100, 102, 98]\nOutput: [90, 110, 95, 105, 100, 100, 90, 110, 95, 105, 100, 100]\n"
          "Input: [101, 103, 97]\nOutput:")
GRAMMAR = Constraint(grammar=gbnf_grammar(ENCODINGS["E5"]))
SECRET = "sk-test-never-print-me-0123456789"


@pytest.fixture(scope="module")
def embedded():
    model = EmbeddedModel(threads=1, context=8192)
    yield model
    model.close()


class LoopbackServer:
    """An HTTP server on 127.0.0.1 in a thread; subclasses answer POSTs with `answer(path, body, headers)`."""

    def __init__(self) -> None:
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):  # noqa: N802
                body = self.rfile.read(int(self.headers["Content-Length"]))
                self._send(*outer.answer(self.path, body, self.headers))

            def do_GET(self):  # noqa: N802
                self._send(*outer.answer(self.path, None, self.headers))

            def _send(self, status, payload, headers=None):
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                for key, value in (headers or {}).items():
                    self.send_header(key, value)
                self.end_headers()
                self.wfile.write(payload)

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/v1"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def answer(self, path: str, body: bytes, headers) -> tuple[int, bytes]:
        raise NotImplementedError

    def close(self) -> None:
        self.server.shutdown()


class Proxy(LoopbackServer):
    """In front of the embedded model's own OpenAI-compatible server: forwards `budget` requests,
    then answers `status`; remembers the Authorization headers."""

    def __init__(self, upstream: str, budget: int, status: int = 503, fail_first: int = 0,
                 retry_after: str | None = None) -> None:
        self.upstream, self.budget, self.status, self.fail_first = upstream, budget, status, fail_first
        self.retry_after, self.seen, self.auth, self.bodies, self.times = retry_after, 0, [], [], []
        super().__init__()

    def answer(self, path: str, body: bytes | None, headers):
        if body is None:  # GET /models: the server's own answer (how `auto` identifies it)
            with urllib.request.urlopen(self.upstream + path.removeprefix("/v1"), timeout=30) as response:
                return 200, response.read()
        self.auth.append(headers.get("Authorization"))
        self.bodies.append(json.loads(body))
        self.times.append(time.monotonic())
        self.seen += 1
        if self.seen <= self.fail_first or self.seen > self.budget + self.fail_first:
            return self.status, b'{"error": "unavailable"}', ({"Retry-After": self.retry_after} if self.retry_after
                                                                else {})
        request = urllib.request.Request(self.upstream + path.removeprefix("/v1"), data=body,
                                         headers={"Content-Type": "application/json"}, method="POST")
        with urllib.request.urlopen(request, timeout=300) as response:
            return 200, response.read()


def test_embedded_model_answers_twelve_numbers_under_the_grammar(embedded):
    reply = embedded.complete(PROMPT, Sampling(), GRAMMAR)
    assert parse_reply(reply.text, ENCODINGS["E5"]) is not None, reply.text
    assert reply.prompt_tokens > 40 and reply.completion_tokens > 12 and reply.latency_s > 0


def test_cache_returns_the_identical_reply_without_asking_again(embedded, tmp_path):
    cached = CachedModel(embedded, tmp_path)
    first = cached.complete(PROMPT, Sampling(), GRAMMAR)
    second = cached.complete(PROMPT, Sampling(), GRAMMAR)
    assert not first.cached and second.cached and second.text == first.text
    other = cached.complete(PROMPT, Sampling(temperature=0.5), GRAMMAR)  # other settings: another entry
    assert not other.cached and len(list(tmp_path.rglob("*.json"))) == 2


E5 = ENCODINGS["E5"]
ALL = Constraint(grammar=gbnf_grammar(E5), schema=json_schema(E5), regex=reply_regex(E5))
DESCRIBED = "You control a robot.\n\nNumbers are integers.\n\n" + HISTORY_HEADER + "\n" + PROMPT


@pytest.mark.parametrize("layout", ["completions", "chat"])
def test_both_layouts_against_the_real_llamacpp_server_on_loopback(embedded, layout):
    proxy = Proxy(embedded.url, budget=10)
    try:
        model = OpenAIModel("gemma-3-270m", url=proxy.url, api_key=SECRET, layout=layout)
        assert model.server == "llamacpp"  # `auto` asked the server (its /models says owned_by llamacpp)
        reply = model.complete(DESCRIBED, Sampling(), ALL)
        assert parse_reply(reply.text, E5) is not None and not ALL.violated_by(reply.text), reply.text
        assert proxy.auth[-1] == f"Bearer {SECRET}" and SECRET not in repr(model)
        body = proxy.bodies[-1]
        assert body["grammar"] == ALL.grammar and "regex" not in body and "structured_outputs" not in body
        if layout == "chat":  # the paper's layout: the description as the system message
            assert [m["role"] for m in body["messages"]] == ["system", "user"]
            assert body["messages"][0]["content"] == "You control a robot.\n\nNumbers are integers."
            assert body["messages"][1]["content"].startswith(HISTORY_HEADER)
        else:
            assert body["prompt"] == DESCRIBED
    finally:
        proxy.close()


def test_cached_tokens_come_from_llamacpps_own_figures(embedded):
    model = OpenAIModel("gemma-3-270m", url=embedded.url, server="llamacpp")
    model.complete(DESCRIBED, Sampling(), ALL)
    again = model.complete(DESCRIBED + " [100, 100, 100]\nInput: [1, 2, 3]\nOutput:", Sampling(), ALL)
    assert again.cached_tokens > 40 and again.cached_tokens < again.prompt_tokens
    cold = model.complete(DESCRIBED + " [100, 100, 100]\nInput: [1, 2, 3]\nOutput:", Sampling(), ALL, cold=True)
    assert cold.cached_tokens == 0 and cold.prompt_tokens == again.prompt_tokens


def test_a_retrieval_block_above_the_query_still_reuses_the_cached_prefix_on_gemma(embedded):
    """The `nearest` prompt changes ~1000 tokens before its end (the retrieved pairs), further back than Gemma 3's
    sliding-window layers keep by default (measured: every such query read whole, 0 tokens cached): with the full
    cache for those layers the window above the block is read from the cache."""
    from benchmark.evaluate.probe import DEFAULT_PROBE, ProbeRun, _prompts, load_probe_set
    from benchmark.llm.controller import LLMSettings
    from benchmark.llm.prompt import build_prompt, describe_robot
    from robots import load_robot

    llm = LLMSettings(history=20, prompt_strategy="nearest")
    items = _prompts(load_probe_set(DEFAULT_PROBE), ProbeRun(llm=llm, cells=("a1/flat",), items=2))
    description = describe_robot(load_robot("a1"), llm.prompt)
    prompts = [build_prompt(description, h, obs, llm.prompt, demo) for _, _, h, demo, obs, _ in list(items)[:2]]
    first = embedded.complete(prompts[0], Sampling(), GRAMMAR, cold=True)
    second = embedded.complete(prompts[1], Sampling(), GRAMMAR)
    changed = second.prompt_tokens - second.cached_tokens
    assert first.prompt_tokens > 4000 and 500 < changed < 2000, (first.prompt_tokens, second.cached_tokens)


def test_429_with_retry_after_waits_and_latency_excludes_the_wait(embedded):
    proxy = Proxy(embedded.url, budget=10, status=429, fail_first=1, retry_after="1")
    try:
        model = OpenAIModel("gemma-3-270m", url=proxy.url, server="llamacpp")
        start = time.monotonic()
        reply = model.complete(PROMPT, Sampling(), GRAMMAR)
        took = time.monotonic() - start
        assert parse_reply(reply.text, E5) is not None and proxy.seen == 2 and reply.retries == 1
        assert proxy.times[1] - proxy.times[0] >= 1.0  # Retry-After honoured
        assert reply.latency_s < took - 0.9  # the wait is not latency
    finally:
        proxy.close()


def test_server_errors_and_a_dead_server_are_one_clear_line():
    proxy = Proxy("http://127.0.0.1:9", budget=0, status=500)
    try:
        with pytest.raises(LLMError, match=r"answered HTTP 500 after 3 attempt\(s\)"):
            OpenAIModel("m", url=proxy.url, retries=2, server="vllm").complete(PROMPT, Sampling(), GRAMMAR)
    finally:
        proxy.close()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        dead = s.getsockname()[1]
    with pytest.raises(LLMError, match="cannot reach .* is the server running"):
        OpenAIModel("m", url=f"http://127.0.0.1:{dead}/v1", retries=1).complete(
            PROMPT, Sampling(), GRAMMAR)


class CannedServer(LoopbackServer):
    """Answers every completion at once with the same text (twelve numbers by default), as a server of
    another kind would; remembers the requests and their arrival times."""

    def __init__(self, text: str = " [" + ", ".join(["100"] * 12) + "]", owned_by: str = "vllm") -> None:
        self.text, self.owned_by, self.arrivals, self.bodies = text, owned_by, [], []
        super().__init__()

    def answer(self, path: str, body: bytes | None, headers) -> tuple[int, bytes]:
        if body is None:
            return 200, json.dumps({"object": "list", "data": [{"id": "m", "object": "model",
                                                                "owned_by": self.owned_by}]}).encode()
        self.arrivals.append(time.monotonic())
        self.bodies.append(json.loads(body))
        usage = {"prompt_tokens": 40, "completion_tokens": 36, "prompt_tokens_details": {"cached_tokens": 32}}
        choice = ({"index": 0, "message": {"role": "assistant", "content": self.text}, "finish_reason": "stop"}
                  if path.endswith("/chat/completions") else {"index": 0, "text": self.text, "finish_reason": "stop"})
        return 200, json.dumps({"id": "x", "object": "text_completion", "created": 0, "model": "m",
                                "choices": [choice], "usage": usage}).encode()


@pytest.mark.parametrize("kind, layout, field, value", [
    ("vllm", "completions", "structured_outputs", {"regex": reply_regex(E5)}),
    ("vllm", "chat", "structured_outputs", {"regex": reply_regex(E5)}),
    ("sglang", "completions", "regex", reply_regex(E5)),
    ("openai", "chat", "response_format", {"type": "json_schema", "json_schema": json_schema(E5)}),
    ("llamacpp", "completions", "grammar", gbnf_grammar(E5)),
])
def test_each_server_kind_gets_its_own_documented_constraint(kind, layout, field, value):
    server = CannedServer(owned_by=kind)
    try:
        model = OpenAIModel("m", url=server.url, layout=layout)  # auto: identified from /models
        reply = model.complete(DESCRIBED, Sampling(), ALL)
        assert model.server == kind and server.bodies[-1][field] == value
        others = {"structured_outputs", "regex", "grammar", "response_format"} - {field}
        assert not others & set(server.bodies[-1])
        assert reply.cached_tokens == 32 and reply.prompt_tokens == 40
        model.complete(DESCRIBED, Sampling(), ALL, cold=True)  # a trial's first query: only llama.cpp has a switch
        assert server.bodies[-1].get("cache_prompt", True) is (kind != "llamacpp")
    finally:
        server.close()


def test_a_server_that_ignores_the_constraint_is_counted_and_warned_once(tmp_path, capsys):
    from benchmark.trial.cell import CellSpec
    from benchmark.trial.resources import Runtime, Resources
    from benchmark.trial.trials import run_cell
    from benchmark.llm.controller import LLMSettings

    server = CannedServer(text="Sure! Here are some numbers: 1, 2, 3", owned_by="sglang")
    try:
        cell = CellSpec(policy="llm", duration=2.3, settings=LLMSettings(
            model="openai:m", url=server.url, history=5, llm_after=2.0))
        trial = run_cell(cell, [0], Resources(Runtime(cache=False)))[0]
    finally:
        server.close()
    m = trial.policy_metrics
    assert m["constraint_violations"] == m["queries"] == 3 and m["parse_failures"] == 3
    assert m["server_kind"] == "sglang" and m["layout"] == "completions" and m["cached_input_tokens"] == 32
    assert capsys.readouterr().err.count("broke the output constraint") == 1


def test_a_late_wake_up_does_not_let_the_next_request_follow_sooner(monkeypatch):
    """The rate limit counts from when a request leaves: one oversleep of 50 ms (a busy machine) must not
    shorten the gap to the next request below the limit's interval."""
    from benchmark.llm import models

    server = CannedServer()
    try:
        limited = OpenAIModel("m", url=server.url, requests_per_minute=300)  # one request per 0.2 s
    finally:
        server.close()
    real_sleep, sleeps, sent = time.sleep, [], []

    def oversleep_once(seconds: float) -> None:
        sleeps.append(seconds)
        real_sleep(seconds + (0.05 if len(sleeps) == 1 else 0.0))

    monkeypatch.setattr(models.time, "sleep", oversleep_once)
    for _ in range(3):
        limited._respect_rate_limit()
        sent.append(time.monotonic())
    gaps = [b - a for a, b in zip(sent, sent[1:])]
    assert len(sleeps) == 2 and min(gaps) >= 0.2, gaps


def test_rate_limit_spaces_requests_to_a_remote_server():
    server = CannedServer()
    try:
        free = OpenAIModel("m", url=server.url)
        for _ in range(4):
            assert parse_reply(free.complete(PROMPT, Sampling(), GRAMMAR).text, ENCODINGS["E5"]) is not None
        unlimited = server.arrivals[-1] - server.arrivals[0]
        server.arrivals.clear()
        limited = OpenAIModel("m", url=server.url, requests_per_minute=300)  # one request per 0.2 s
        for _ in range(4):
            limited.complete(PROMPT, Sampling(), GRAMMAR)
        gaps = [b - a for a, b in zip(server.arrivals, server.arrivals[1:])]
        # each request leaves >= 0.2 s after the last; arrivals may jitter by a few ms on a loaded machine
        assert unlimited < 0.15 and min(gaps) >= 0.15 and sum(gaps) >= 0.57, (unlimited, gaps)
    finally:
        server.close()
    with pytest.raises(ValueError, match="requests per minute must be > 0"):
        OpenAIModel("m", requests_per_minute=0)


def test_unknown_model_spec_is_clear():
    with pytest.raises(ValueError, match="unknown model 'gpt5'; valid: embedded, embedded:PATH.gguf, openai:MODEL"):
        make_model("gpt5")


def _run_cli(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(args)
    return code, out.getvalue(), err.getvalue()


@pytest.mark.slow
def test_llm_run_end_to_end_on_the_embedded_model(tmp_path, monkeypatch):
    monkeypatch.setenv("PROMPTWALK_CACHE", str(tmp_path))
    record = tmp_path / "llm.rrd"
    code, out, err = _run_cli(["run", "--sim", "mujoco", "--robot", "a1", "--policy", "llm", "--duration", "2.5",
                               "--llm-after", "2", "--trials", "1", "--threads", "1", "--json", "--record", str(record)])
    assert code == 0, err
    trial = json.loads(out)["trials"][0]
    # The recording holds the dialogue and, beside the LLM's actions, the seed policy's.
    from test_recorder import _column, read_back

    entities = read_back(record)
    replies = [text for row in _column(entities["/llm/reply"], "TextLog:text") for text in row]
    assert len(replies) == trial["queries"] and all(r.strip().startswith("[") for r in replies)
    assert len(_column(entities["/joints/seed_policy_action"], "Scalars:scalars")) == trial["control_steps"]
    assert len(_column(entities["/llm/prompt"], "TextLog:text")) == trial["queries"]
    # One query per control step of the LLM phase (2.0-2.5 s), fewer only if the robot fell.
    expected = 5 if trial["fall_time"] is None else round((trial["fall_time"] - 2.0) / 0.1)
    assert trial["queries"] == expected >= 1 and trial["parse_failures"] == 0
    assert trial["input_tokens"] > trial["gpt4_input_tokens"] > 1000  # 10 pairs of history, Gemma counts more
    assert trial["output_tokens"] > 12 and trial["latency_p95_s"] >= trial["latency_mean_s"] > 0
    assert trial["realtime_factor"] == pytest.approx(0.1 / trial["latency_mean_s"])
    # Run again: every reply comes from the cache and the trial is bit-identical.
    code, again, _ = _run_cli(["run", "--sim", "mujoco", "--robot", "a1", "--policy", "llm", "--duration", "2.5",
                               "--llm-after", "2", "--trials", "1", "--threads", "1", "--json"])
    repeat = json.loads(again)["trials"][0]
    assert repeat["cache_hits"] == trial["queries"] and repeat["distance_m"] == trial["distance_m"]


@pytest.mark.slow
def test_server_dying_mid_run_keeps_finished_trials_and_never_prints_the_key(embedded, tmp_path, monkeypatch):
    monkeypatch.setenv("PROMPTWALK_CACHE", str(tmp_path))
    monkeypatch.setenv("PROMPTWALK_LLM_API_KEY", SECRET)
    proxy = Proxy(embedded.url, budget=3)  # trial 0 needs 3 queries; trial 1 finds the server failing
    try:
        code, out, err = _run_cli(["run", "--policy", "llm", "--llm", "openai:gemma-3-270m", "--llm-url", proxy.url,
                                   "--duration", "2.3", "--llm-after", "2", "--history", "5", "--trials", "2",
                                   "--json"])
    finally:
        proxy.close()
    assert code == 1
    result = json.loads(out)
    assert [t["seed"] for t in result["trials"]] == [0] and result["trials"][0]["queries"] == 3
    assert "answered HTTP 503" in err and "1 finished trial(s)" in err
    assert SECRET not in out + err and proxy.auth[0] == f"Bearer {SECRET}"


class SlowServer(CannedServer):
    """A remote server's situation: every answer takes `delay_s`, whatever else is in flight."""

    def __init__(self, delay_s: float) -> None:
        self.delay_s = delay_s
        super().__init__(owned_by="vllm")

    def answer(self, path, body, headers):
        if body is not None:
            time.sleep(self.delay_s)
        return super().answer(path, body, headers)


def _four_trials(tmp_path, url: str, name: str):
    from benchmark.experiments.experiment import load_experiment

    path = tmp_path / f"{name}.toml"
    path.write_text(f'name = "{name}"\nseeds = [0, 1, 2, 3]\n[fixed]\npolicy = "llm"\nmodel = "openai:m"\n'
                    f'url = "{url}"\nhistory = 5\nduration = 2.3\nllm_after = 2.0\n')
    return load_experiment(str(path)).trials()


def test_concurrency_keeps_trials_in_flight_and_the_rate_limit_holds_across_them(tmp_path, monkeypatch):
    """Four LLM trials (12 queries) against a server answering in 0.5 s: two in flight take about half the
    time (the wait dominates the trials' own compute even on a loaded machine); with a rate limit, requests stay
    spaced over both threads."""
    from benchmark.common.store import ResultStore
    from benchmark.experiments.sweep import run_sweep

    server = SlowServer(0.5)
    walls = {}
    try:
        for concurrency in (1, 2):
            monkeypatch.setenv("PROMPTWALK_CACHE", str(tmp_path / f"cache{concurrency}"))  # every reply live
            trials = _four_trials(tmp_path, server.url, f"four{concurrency}")
            outcome = run_sweep(trials, ResultStore(tmp_path / f"store{concurrency}"), concurrency=concurrency)
            assert outcome.ran == 4
            walls[concurrency] = outcome.wall_s
        assert walls[2] < 0.75 * walls[1], walls
        server.arrivals.clear()
        monkeypatch.setenv("PROMPTWALK_CACHE", str(tmp_path / "cache_limited"))
        run_sweep(_four_trials(tmp_path, server.url, "limited"), ResultStore(tmp_path / "limited"), concurrency=2,
                  requests_per_minute=300)  # one request per 0.2 s over both threads
        gaps = [b - a for a, b in zip(server.arrivals, server.arrivals[1:])]
        assert len(server.arrivals) == 12 and min(gaps) >= 0.15 and sum(gaps) >= 11 * 0.19, gaps
    finally:
        server.close()


def test_the_embedded_model_takes_a_thread_per_core_this_process_may_use():
    """`taskset` or a container that allows one core gets one llama.cpp thread (two would take turns on it), and
    `PROMPTWALK_THREADS` says otherwise; a value that is not a number of threads is refused in one line."""
    code = ("import os; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))});"
            "from benchmark.llm.models import default_threads; print(default_threads())")
    env = {k: v for k, v in os.environ.items() if k != "PROMPTWALK_THREADS"}

    def threads(**extra: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**env, **extra})

    assert threads().stdout == "1\n" and threads(PROMPTWALK_THREADS="3").stdout == "3\n"
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "run", "--llm", "embedded", "--trials", "1"],
                         capture_output=True, text=True, env={**env, "PROMPTWALK_THREADS": "two"})
    assert out.returncode != 0 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1] == (
        "bench: error: PROMPTWALK_THREADS='two' is not a number of threads; give a whole number >= 1"), out.stderr
