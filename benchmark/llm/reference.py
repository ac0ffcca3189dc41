"""Reference models on the text channel: they read the same prompt an LLM reads and answer
through the same reply -> parse -> decode path, so they stand as rows beside real models.

    hold     repeats the last action in the prompt's history (a model that freezes)
    default  the default pose (normalized action 0), whatever the prompt says
    knn      the output paired with the history input nearest to the current input
    replay   continues the newest gait cycle in the history's outputs, open loop
    oracle   the seed policy's action for the current state, written in the encoding (the ceiling)

They are models, selected with `--llm NAME`; tokens are counted with GPT-4's tokenizer.
"""

from __future__ import annotations

import re
import time

import numpy as np

from benchmark.llm.models import Constraint, Reply, Sampling
from benchmark.llm.strategies import gait_period
from benchmark.llm.tokens import gpt4_tokens

OUTPUT_LINE = re.compile(r"^Output: (\[[^\]]*\])\s*$", re.MULTILINE)


def history_outputs(prompt: str) -> list[str]:
    """The bracketed action lists of the prompt's history, oldest first (the final `Output:` is empty)."""
    return OUTPUT_LINE.findall(prompt)


class _TextModel:
    """A deterministic model of the prompt text alone; subclasses answer `reply_to(prompt)`."""

    kind = ""
    cacheable = False  # answering is cheaper than a cache lookup
    obeys_constraint = False  # writes its answer itself: no server field to ignore, no violation to count
    reads_prompt = False  # answers at once: no long read to report

    def __init__(self) -> None:
        self.id = f"reference:{self.kind}"

    @classmethod
    def from_spec(cls, name: str | None, **_: object):
        return cls()

    def reply_to(self, prompt: str) -> str:
        raise NotImplementedError

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint, cold: bool = False) -> Reply:
        start = time.perf_counter()
        text = " " + self.reply_to(prompt)
        return Reply(text, gpt4_tokens(prompt), gpt4_tokens(text), time.perf_counter() - start)

    def close(self) -> None:
        pass


class HoldModel(_TextModel):
    """Repeats the newest action of the history; with no history, an empty list (which does not parse)."""

    kind = "hold"

    def reply_to(self, prompt: str) -> str:
        outputs = history_outputs(prompt)
        return outputs[-1] if outputs else "[]"


LINE_NUMBERS = re.compile(r"-?\d+(?:\.\d+)?")


def history_pairs(prompt: str) -> tuple[list[tuple[list[float], str]], list[float] | None]:
    """The history's (input numbers, output text) pairs and the current input's numbers, from the text alone.
    Malformed lines are skipped; a prompt without a current input gives None."""
    pairs, pending, current = [], None, None
    for line in prompt.splitlines():
        if line.startswith("Input: ["):
            pending = current = [float(v) for v in LINE_NUMBERS.findall(line[len("Input: "):])]
        elif line.startswith("Output: [") and pending is not None:
            pairs.append((pending, line[len("Output: "):].strip()))
            pending = current = None
    return pairs, current


def knn_answer(prompt: str) -> str:
    """The output paired with the history input nearest (Euclidean, on the written numbers) to the current one."""
    pairs, current = history_pairs(prompt)
    usable = [(x, out) for x, out in pairs if current is not None and len(x) == len(current)]
    if not usable:
        return history_outputs(prompt)[-1] if history_outputs(prompt) else "[]"
    distances = [float(np.sum((np.array(x) - np.array(current)) ** 2)) for x, _ in usable]
    return usable[int(np.argmin(distances))][1]  # ties: the oldest, deterministically


class KnnModel(_TextModel):
    """Nearest neighbour in the prompt's own history: copying its examples, nothing more."""

    kind = "knn"

    def reply_to(self, prompt: str) -> str:
        return knn_answer(prompt)


class ReplayModel(_TextModel):
    """Continues the newest gait cycle of the history's actions, open loop.

    The period P (2-20 steps) is the lag at which the last 2P actions best repeat themselves;
    the next action is the one P steps before it."""

    kind = "replay"

    def reply_to(self, prompt: str) -> str:
        outputs = history_outputs(prompt)
        actions = [[float(v) for v in LINE_NUMBERS.findall(o)] for o in outputs]
        actions = [a for a in actions if actions and len(a) == len(actions[-1])]
        if len(actions) < 4:
            return outputs[-1] if outputs else "[]"
        period = gait_period(np.array(actions))
        return outputs[len(outputs) - period]


class OracleModel(_TextModel):
    """The seed policy's action for the current state, written in the prompt's encoding: the ceiling of a
    model that imitates the seed policy through this text channel. The only reference model that sees
    more than the prompt (the controller hands it the seed policy's action)."""

    kind = "oracle"
    privileged = True

    def __init__(self) -> None:
        super().__init__()
        self.answer = "[]"

    def set_reference(self, seed_action: np.ndarray, encoding) -> None:
        self.answer = encoding.encode(seed_action)

    def reply_to(self, prompt: str) -> str:
        return self.answer


class DefaultPoseModel(OracleModel):
    """Always the default pose (normalized action 0) in the prompt's encoding: a model that answers without
    reading anything. It takes the encoding through the same hand-over as `oracle`, never the action."""

    kind = "default"

    def set_reference(self, seed_action: np.ndarray, encoding) -> None:
        self.answer = encoding.encode(np.zeros_like(seed_action))


REFERENCE_KINDS = tuple(m.kind for m in (HoldModel, KnnModel, ReplayModel, OracleModel, DefaultPoseModel))
TRIVIAL_ANSWERS = (HoldModel.kind, KnnModel.kind)  # a prompt's own trivial answers: its last example line, its nearest
