"""The LLM policy and the paper's protocol.

Episode (defaults): the robot stands for `seed_start` s, then the seed RL policy walks and
fills the history with (observation, action) pairs; at `llm_after` s the LLM takes over and
is queried every control step with the description, the last `history` pairs and the current
observation. Simulation time waits while the model thinks. A reply that does not parse is
counted, kept with its text, and handled by holding the last action.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from benchmark.llm.encodings import get_encoding
from benchmark.llm.models import Constraint, LanguageModel, Reply, Sampling, make_model
from benchmark.llm.prompt import PromptConfig, build_prompt, describe_robot
from benchmark.llm.replies import gbnf_grammar, json_schema, parse_reply
from benchmark.llm.tokens import gpt4_tokens
from benchmark.observation import llm_observation
from robots import Robot
from sims.base import RobotState

HISTORY_MODES = ("sliding", "block")


@dataclass(frozen=True)
class LLMConfig:
    model: str = "embedded"
    url: str | None = None
    api: str = "completions"
    prompt: PromptConfig = PromptConfig()
    seed_start: float = 1.0  # s: the seed policy starts walking and filling the history
    llm_after: float = 10.0  # s: the LLM takes over
    history_mode: str = "sliding"  # or "block": grow, then cut `block` pairs at once (prefix-cache friendly)
    block: int = 10
    constrained: bool = True
    sampling: Sampling = Sampling()
    price_in: float | None = None  # USD per 1M input tokens, for a cost estimate
    price_out: float | None = None
    cache: bool = True
    threads: int | None = None
    requests_per_minute: float | None = None  # remote servers only: at most this many queries a minute

    def __post_init__(self) -> None:
        if self.history_mode not in HISTORY_MODES:
            raise ValueError(f"unknown history mode '{self.history_mode}'; valid: {', '.join(HISTORY_MODES)}")
        if not 0 <= self.seed_start <= self.llm_after:
            raise ValueError(f"need 0 <= seed start ({self.seed_start}) <= llm takeover ({self.llm_after})")
        if self.block < 1:
            raise ValueError(f"block must be >= 1 pair, got {self.block}")


@dataclass
class Query:
    """One LLM call, kept for metrics and recordings."""

    time: float
    prompt_tail: str
    reply: Reply
    parsed: bool
    gpt4_in: int
    gpt4_out: int


@dataclass
class _Trial:
    history: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    window_start: int = 0
    queries: list[Query] = field(default_factory=list)
    last_action: np.ndarray | None = None


class LLMPolicy:
    name = "llm"

    def __init__(self, robot: Robot, config: LLMConfig = LLMConfig(), model: LanguageModel | None = None,
                 seed_policy=None) -> None:
        from benchmark.policies import RLPolicy

        self.robot, self.config = robot, config
        self.seed_policy = seed_policy or RLPolicy(robot)
        self.model = model or make_model(config.model, url=config.url, api=config.api, cache=config.cache,
                                         threads=config.threads,
                                         requests_per_minute=config.requests_per_minute)
        self.encoding = get_encoding(config.prompt.encoding)
        self.description = describe_robot(robot, config.prompt)
        self.constraint = Constraint()
        if config.constrained:
            self.constraint = (Constraint(schema=json_schema(self.encoding, robot.num_joints))
                               if config.api == "chat" and config.model.startswith("openai")
                               else Constraint(grammar=gbnf_grammar(self.encoding, robot.num_joints)))
        self.seed_action = np.zeros(robot.num_joints)  # what the seed policy would do now (for recordings)
        self._trial = _Trial()

    def reset(self, seed: int) -> None:
        self.seed_policy.reset(seed)
        self._trial = _Trial(last_action=np.zeros(self.robot.num_joints))

    def _window(self) -> list[tuple[np.ndarray, np.ndarray]]:
        t, h = self._trial, self.config.prompt.history
        if h == 0:
            return []
        if self.config.history_mode == "sliding":
            return t.history[-h:]
        while len(t.history) - t.window_start > h:  # cut whole blocks: the prompt prefix stays put between cuts
            t.window_start += self.config.block
        return t.history[t.window_start:]

    def act(self, obs: np.ndarray, state: RobotState) -> np.ndarray:
        t, cfg = self._trial, self.config
        self.seed_action = self.seed_policy.act(obs, state)
        llm_obs = llm_observation(obs)
        if state.time < cfg.seed_start - 1e-9:
            action = np.zeros(self.robot.num_joints)
        elif state.time < cfg.llm_after - 1e-9:
            action = self.seed_action
            t.history.append((llm_obs, action))
        else:
            action = self._query(llm_obs, state.time)
            t.history.append((llm_obs, action))
        t.last_action = action
        return action

    def _query(self, llm_obs: np.ndarray, now: float) -> np.ndarray:
        t = self._trial
        prompt = build_prompt(self.description, self._window(), llm_obs, self.config.prompt)
        reply = self.model.complete(prompt, self.config.sampling, self.constraint)
        action = parse_reply(reply.text, self.encoding, self.robot.num_joints)
        tail = prompt[prompt.rfind("Input:", 0, prompt.rfind("Input:")):]  # newest pair's input onwards
        t.queries.append(Query(now, tail, reply, action is not None, gpt4_tokens(prompt), gpt4_tokens(reply.text)))
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
        tokens_out = np.array([x.reply.completion_tokens for x in q], dtype=float)
        out = {
            "queries": len(q),
            "parse_failures": sum(not x.parsed for x in q),
            "failed_replies": [x.reply.text for x in q if not x.parsed][:5],
            "input_tokens": float(tokens_in.mean()),
            "output_tokens": float(tokens_out.mean()),
            "gpt4_input_tokens": float(np.mean([x.gpt4_in for x in q])),
            "gpt4_output_tokens": float(np.mean([x.gpt4_out for x in q])),
            "latency_mean_s": float(latency.mean()),
            "latency_p95_s": float(np.percentile(latency, 95)),
            "realtime_factor": float(0.1 / latency.mean()) if latency.mean() > 0 else None,
            "cache_hits": sum(x.reply.cached for x in q),
        }
        if self.config.price_in is not None and self.config.price_out is not None:
            out["cost_usd"] = float((tokens_in.sum() * self.config.price_in
                                     + tokens_out.sum() * self.config.price_out) / 1e6)
        return out
