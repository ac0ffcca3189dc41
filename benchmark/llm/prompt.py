"""The text prompt: a description part of five switchable components and a history part.

Components (the paper's ablation units): `task` (what to do, at what rate), `io` (meaning
of inputs and outputs), `joints` (joint order), `pipeline` (how outputs become motion) and
`illustration` (how numbers are written, and the answer format). Robot facts come from
`robot.toml`; the wording is this project's own.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from benchmark.llm.encodings import DEFAULT_ENCODING, Encoding, get_encoding
from benchmark.llm.prompt_inputs import DEFAULT_OBSERVATION, describe, select
from benchmark.llm.strategies import (
    DEFAULT_STRATEGY,
    DISTANCES,
    EXAMPLE_HEADERS,
    HISTORY_HEADER,  # noqa: F401  (the chronological header, imported from here)
    MEMORIES,
    STRATEGIES,
    Pair,
    render_history,
)
from robots import LEGS, Robot, UnknownNameError

PARTS = ("task", "io", "joints", "pipeline", "illustration")
LAYOUTS = ("completions", "chat")  # one text; or the description as the system message (the paper's code)
ROLE_NAMES = ("hip abduction", "thigh", "calf")


@dataclass(frozen=True)
class PromptConfig:
    parts: tuple[str, ...] = PARTS
    history: int = 50  # observation/action pairs shown
    encoding: str = DEFAULT_ENCODING
    observation: str = DEFAULT_OBSERVATION
    strategy: str = DEFAULT_STRATEGY  # benchmark.llm.strategies
    k: int = 3  # retrieved pairs (strategies that retrieve)
    memory: str = "demonstrations"  # what retrieval reads: demonstrations, window or both
    distance: str = "l2"  # on the written inputs: l2 (squared Euclidean) or l1

    def __post_init__(self) -> None:
        unknown = [p for p in self.parts if p not in PARTS]
        if unknown:
            raise ValueError(f"unknown prompt part '{unknown[0]}'; valid: {', '.join(PARTS)}")
        if self.history < 0:
            raise ValueError(f"history must be >= 0 pairs, got {self.history}")
        get_encoding(self.encoding)
        select(self.observation)
        if self.strategy not in STRATEGIES:
            raise UnknownNameError("prompt strategy", self.strategy, list(STRATEGIES))
        if self.memory not in MEMORIES:
            raise UnknownNameError("memory", self.memory, list(MEMORIES))
        if self.distance not in DISTANCES:
            raise UnknownNameError("distance", self.distance, list(DISTANCES))
        if self.k < 1:
            raise ValueError(f"retrieve_k must be >= 1 pair, got {self.k}")


def describe_robot(robot: Robot, config: PromptConfig, control_hz: float = 10.0, condition: str = "") -> str:
    """The description part: the selected components, one paragraph each, then `condition` (what changed since the
    examples were recorded, a disturbance's `told` sentence) as a paragraph of its own when given."""
    enc = get_encoding(config.encoding)
    n_obs = len(select(config.observation))
    texts = {
        "task": (f"You control a {robot.title} quadruped at {control_hz:g} Hz: read its state, output 12 joint "
                 f"targets. Goal: walk straight forward at {robot.command[0]:g} m/s without falling."),
        "io": ("Input: " + ("; ".join(describe(config.observation)) if n_obs else "nothing (outputs only)")
               + ", body frame (x forward, y left, z up). Output: 12 joint targets, offsets from the standing pose."),
        "joints": ("Joint order: " + ", ".join(LEGS) + " legs (front/rear, right/left), each "
                   + ", ".join(ROLE_NAMES) + "."),
        "pipeline": (f"Target angle = default + {robot.action_scale:g} * output (rad), tracked by PD control "
                     f"(Kp {robot.kp:g}, Kd {robot.kd:g}) at 200 Hz. Walking is a steady trot of diagonal leg pairs, "
                     f"as in the examples."),
        "illustration": _illustration(enc),
    }
    return "\n\n".join([*(texts[p] for p in PARTS if p in config.parts), *([condition] if condition else [])])


def _illustration(enc: Encoding) -> str:
    examples = ", ".join(f"{x:g} -> {enc.encode_value(x)}" for x in (-1.2, 0.0, 0.53))
    rounding = "rounded" if enc.decimals == 0 else f"{enc.decimals} decimals"
    return (f"Numbers are {enc.title}: v is written (v + {enc.offset:g}) * {enc.scale:g}, {rounding} "
            f"({examples}). Reply with one line: Output: [n1{enc.separator}...{enc.separator}n12]")


def build_prompt(description: str, history: Sequence[Pair], obs: np.ndarray, config: PromptConfig,
                 demonstrations: Sequence[Pair] = ()) -> str:
    """Description, the examples the prompt strategy picks from the history window (oldest first) and the
    demonstration memory, and the current input awaiting its output."""
    enc, idx = get_encoding(config.encoding), select(config.observation)
    lines = [description, ""] if description else []
    lines += render_history(config.strategy, history, demonstrations, obs, enc, idx, config.k, config.memory,
                            config.distance)
    lines.append(f"Input: {enc.encode(obs[idx])}")
    lines.append("Output:")
    return "\n".join(lines)


def split_prompt(prompt: str) -> tuple[str, str]:
    """(description, history and current input): the chat layout's system and user messages, as the
    paper's code sent them."""
    first_list = re.search(r"^Input: \[", prompt, flags=re.MULTILINE)  # not the io paragraph's "Input: base ..."
    starts = [i for i in (*(prompt.find(h) for h in EXAMPLE_HEADERS), first_list.start() if first_list else -1)
              if i >= 0]
    cut = min(starts) if starts else len(prompt)
    return prompt[:cut].strip(), prompt[cut:]
