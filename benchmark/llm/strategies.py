"""Prompt strategies: which examples the prompt shows above the current input, and in what order.

Every strategy renders the same description and the same `Input: [...]` / `Output: [...]` lines; they
differ only in the examples. `render_history` is the one renderer: the closed loop (`LLMPolicy`) and
the probe both call it through `build_prompt`, with the chronological window, the demonstration
memory and the current observation.

    chronological  the paper's: the last `history` pairs, oldest first. Re-reads per query: the newest
                   pair (the window's prefix stays cached; a sliding window shifts it, see history modes).
    nearest        the window, then the K pairs nearest the current input from the memory, nearest last,
                   just above the query (KATE's order; REGENT's retrieval). Re-reads per query: the K
                   retrieved pairs and the query (~K x 220 Gemma tokens at O5); the window stays cached.
    nearest-only   only the K nearest pairs, nearest last: a short prompt. Re-reads per query: everything
                   after the description (K pairs).
    nearest-by-time  only the K nearest pairs, in the order they happened: the nearest is anywhere among
                   them, so copying the last line is no longer `knn` and the model must find the nearest
                   example itself (its gain over `hold` measures that). Re-reads as nearest-only.
    sorted         the window's own pairs ordered farthest to nearest the current input (nearest last).
                   Re-reads per query: the whole window (no prefix survives a re-order).
    cycle          the window, then its last full gait cycle laid out so that the example just above the
                   query is one period before it (the period as `replay` finds it). Re-reads per query:
                   the cycle block (one period, 5-20 pairs) and the query.

The **demonstration memory** is every seed-policy pair before the takeover (closed loop: the history
the LLM inherits; probe: the walk's pairs before its first item), fixed for the trial: it never
holds a pair the LLM made or a pair from after the takeover. `memory` picks what retrieval reads:
`demonstrations`, `window` (the pairs shown) or `both`. Distance is on the numbers as written in the
prompt (the encoded inputs): squared Euclidean (`l2`, what `knn` uses) or `l1`.

Each strategy gives something away: on a `nearest` prompt, copying the last example line (`hold`)
is `knn`; on a `cycle` prompt it is `replay`. The probe and the study score those same-prompt
trivial answers beside the model, so walking that comes from the prompt shows as such.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from benchmark.llm.encodings import Encoding

Pair = tuple[np.ndarray, np.ndarray]  # (LLM observation, normalized action)

HISTORY_HEADER = "Recent inputs and the outputs that kept the robot walking:"
NEAREST_HEADER = "Examples whose inputs are nearest the current input (nearest last):"
BY_TIME_HEADER = "Examples whose inputs are nearest the current input, in the order they happened:"
SORTED_HEADER = "Inputs and the outputs that kept the robot walking, ordered by closeness to the current input " \
                "(nearest last):"
CYCLE_HEADER = "The last gait cycle ({period} steps), aligned: the example just above the current input is one " \
               "period before it:"

EXAMPLE_HEADERS = (HISTORY_HEADER, NEAREST_HEADER, BY_TIME_HEADER, SORTED_HEADER, CYCLE_HEADER.partition("(")[0])
MEMORIES = ("demonstrations", "window", "both")
DISTANCES = ("l2", "l1")
DEFAULT_STRATEGY = "chronological"
MIN_PERIOD, MAX_PERIOD = 2, 20  # control steps a gait cycle may take (0.2-2 s at 10 Hz)


@dataclass(frozen=True)
class Strategy:
    name: str
    help: str  # what it shows and what it re-reads per query
    window: bool  # shows the chronological window
    retrieves: bool  # reads K, memory and distance


STRATEGIES: dict[str, Strategy] = {s.name: s for s in (
    Strategy("chronological", "the paper's: the last HISTORY pairs, oldest first (re-reads the newest pair)",
             window=True, retrieves=False),
    Strategy("nearest", "the window, then the K pairs from the memory nearest the current input, nearest last "
                        "(re-reads K pairs)", window=True, retrieves=True),
    Strategy("nearest-only", "only the K nearest pairs from the memory, nearest last (a short prompt; re-reads "
                             "all but the description)", window=False, retrieves=True),
    Strategy("nearest-by-time", "only the K nearest pairs from the memory, in the order they happened (copying "
                                "the last line is not knn; re-reads all but the description)",
             window=False, retrieves=True),
    Strategy("sorted", "the window's pairs ordered farthest to nearest the current input (re-reads the window)",
             window=True, retrieves=False),
    Strategy("cycle", "the window, then its last gait cycle aligned so the line above the query is one period ago "
                      "(re-reads one period)", window=True, retrieves=False),
)}


def format_pair(obs: np.ndarray, action: np.ndarray, enc: Encoding, idx: np.ndarray) -> str:
    return f"Input: {enc.encode(obs[idx])}\nOutput: {enc.encode(action)}"


def written(obs: np.ndarray, enc: Encoding) -> np.ndarray:
    """Values as the prompt writes them (the encoded numbers), for distances on the text."""
    return np.array([float(enc.encode_value(v)) for v in np.asarray(obs, dtype=float)])


def distances(pool: Sequence[Pair], obs: np.ndarray, enc: Encoding, idx: np.ndarray, distance: str) -> np.ndarray:
    """Distance of each pool pair's written input from the current one's."""
    if not pool:
        return np.zeros(0)
    here = written(obs[idx], enc)
    there = np.array([written(o[idx], enc) for o, _ in pool])
    gap = there - here
    return np.abs(gap).sum(axis=1) if distance == "l1" else (gap * gap).sum(axis=1)


def nearest_indices(pool: Sequence[Pair], obs: np.ndarray, enc: Encoding, idx: np.ndarray, distance: str,
                    k: int | None = None) -> list[int]:
    """Indices of the k pool pairs nearest `obs` (all when k is None), farthest first; ties: the older is nearer."""
    order = np.argsort(distances(pool, obs, enc, idx, distance), kind="stable")
    chosen = order if k is None else order[:k]
    return [int(i) for i in chosen[::-1]]


def nearest_last(pool: Sequence[Pair], obs: np.ndarray, enc: Encoding, idx: np.ndarray, distance: str,
                 k: int | None = None) -> list[Pair]:
    """The k pairs nearest `obs` (all when k is None), ordered farthest to nearest; ties: the older is nearer."""
    return [pool[i] for i in nearest_indices(pool, obs, enc, idx, distance, k)]


def gait_period(actions: np.ndarray) -> int | None:
    """The lag (2-20 steps) at which the last 2P actions best repeat themselves, as `replay` reads it;
    None with fewer than 4 actions."""
    if len(actions) < 4:
        return None
    best, period = np.inf, None
    for p in range(MIN_PERIOD, min(MAX_PERIOD, len(actions) // 2) + 1):
        error = float(np.mean((actions[-p:] - actions[-2 * p:-p]) ** 2))
        if error < best:
            best, period = error, p
    return period


def retrieval_pool(window: Sequence[Pair], demonstrations: Sequence[Pair], memory: str) -> list[Pair]:
    if memory == "window":
        return list(window)
    if memory == "demonstrations":
        return list(demonstrations)
    return [*demonstrations, *window]


def render_history(strategy: str, window: Sequence[Pair], demonstrations: Sequence[Pair], obs: np.ndarray,
                   enc: Encoding, idx: np.ndarray, k: int, memory: str, distance: str) -> list[str]:
    """The example lines (headers and pairs) a strategy puts between the description and the current input."""
    def pairs(block: Sequence[Pair]) -> list[str]:
        return [format_pair(o, a, enc, idx) for o, a in block]

    lines: list[str] = []
    if strategy == "sorted":
        return [SORTED_HEADER, *pairs(nearest_last(window, obs, enc, idx, distance))] if window else []
    if STRATEGIES[strategy].window and window:
        lines += [HISTORY_HEADER, *pairs(window)]
    if STRATEGIES[strategy].retrieves:
        pool = retrieval_pool(window, demonstrations, memory)  # oldest first
        chosen = nearest_indices(pool, obs, enc, idx, distance, k)
        by_time = strategy == "nearest-by-time"
        if chosen:
            lines += [BY_TIME_HEADER if by_time else NEAREST_HEADER,
                      *pairs([pool[i] for i in (sorted(chosen) if by_time else chosen)])]
    elif strategy == "cycle":
        actions = np.array([enc.quantize(a) for _, a in window]) if window else np.zeros((0, 0))
        period = gait_period(actions)
        if period is not None and len(window) >= 2 * period:
            n = len(window)  # the query's index: the block ends at n - period
            lines += [CYCLE_HEADER.format(period=period), *pairs(window[n - 2 * period + 1:n - period + 1])]
    return lines
