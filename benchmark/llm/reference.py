"""Reference models on the text channel: they read the same prompt an LLM reads and answer
through the same reply -> parse -> decode path, so they stand as rows beside real models.

    hold     repeats the last action in the prompt's history (a model that freezes)

They are models, selected with `--llm NAME`; tokens are counted with GPT-4's tokenizer.
"""

from __future__ import annotations

import re
import time

from benchmark.llm.models import Constraint, Reply, Sampling
from benchmark.llm.tokens import gpt4_tokens

OUTPUT_LINE = re.compile(r"^Output: (\[[^\]]*\])\s*$", re.MULTILINE)


def history_outputs(prompt: str) -> list[str]:
    """The bracketed action lists of the prompt's history, oldest first (the final `Output:` is empty)."""
    return OUTPUT_LINE.findall(prompt)


class _TextModel:
    """A deterministic model of the prompt text alone; subclasses answer `reply_to(prompt)`."""

    kind = ""
    cacheable = False  # answering is cheaper than a cache lookup

    def __init__(self) -> None:
        self.id = f"reference:{self.kind}"

    @classmethod
    def from_spec(cls, name: str | None, **_: object):
        return cls()

    def reply_to(self, prompt: str) -> str:
        raise NotImplementedError

    def complete(self, prompt: str, sampling: Sampling, constraint: Constraint) -> Reply:
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
