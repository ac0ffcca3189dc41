"""What a sweep will cost on a paid API, before anything runs (`bench sweep ... --dry-run` with prices).

Per history mode, for every LLM trial of the grid: queries (an upper bound: no trial ends early),
input tokens of a real prompt of that shape (the takeover prompt of a seed-policy rollout,
counted with GPT-4's cl100k, offline), the part of them an API's prefix cache can serve, and
output tokens of an answer line. APIs cache a prompt's prefix from 1024 tokens on, in steps
of 128 (OpenAI's rule): a sliding window keeps only the description in place, while block
history keeps all but the newest pairs in place between cuts. This is an estimate, labelled so.
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np

from benchmark.trial.cell import CellSpec
from benchmark.llm.controller import CONTROL_DT, takeover_prompt
from benchmark.llm.encodings import get_encoding
from benchmark.llm.prompt import split_prompt
from benchmark.llm.tokens import gpt4_tokens

CACHE_MIN, CACHE_STEP = 1024, 128  # tokens: the smallest cached prefix and its granularity
MODES = ("sliding", "block")


def _cacheable(tokens: float) -> float:
    return float(np.floor(tokens / CACHE_STEP) * CACHE_STEP) if tokens >= CACHE_MIN else 0.0


@cache
def _shape(cell: CellSpec) -> tuple[int, int, int]:
    """(prompt, description, answer) tokens of a cell's prompts."""
    text = takeover_prompt(cell)
    system, _ = split_prompt(text)
    answer = " " + get_encoding(cell.settings.encoding).encode(np.zeros(12))
    return gpt4_tokens(text), gpt4_tokens(system), gpt4_tokens(answer)


def estimate(cells: list[CellSpec], trials_per_cell: list[int], mode: str, price_in: float, price_out: float,
             price_cached_in: float | None = None) -> dict:
    """Queries, input, cached and output tokens and USD of these LLM cells run in history mode `mode`."""
    queries = inputs = cached = outputs = 0.0
    for cell, trials in zip(cells, trials_per_cell):
        s = cell.settings
        n = round((cell.duration - s.llm_after) / CONTROL_DT) * trials
        prompt, description, answer = _shape(replace(cell, settings=replace(s, history_mode="sliding")))
        if mode == "block" and s.history:
            pair = (prompt - description) / max(1, s.history)
            between_cuts = _cacheable(prompt - 2 * pair)  # all but the newest pair and the current input
            per_query = ((s.block - 1) * between_cuts + _cacheable(description)) / s.block
        else:  # the window start moves every query: only the description stays in place
            per_query = _cacheable(description)
        queries, inputs, cached, outputs = queries + n, inputs + n * prompt, cached + n * per_query, outputs + n * answer
    cached_price = price_in if price_cached_in is None else price_cached_in
    usd = ((inputs - cached) * price_in + cached * cached_price + outputs * price_out) / 1e6
    return {"mode": mode, "queries": int(queries), "input_tokens": int(inputs), "cached_input_tokens": int(cached),
            "output_tokens": int(outputs), "usd": usd}
