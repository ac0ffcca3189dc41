"""No silence on long work: lines while a long prompt is read, and ETAs from the recent rate.

A cold first query of a 1.5B model at history 50 reads ~11,000 tokens for minutes; without a
word, that looks like a hang. `PromptReading` prints a line when a long prompt starts (its
size, and how long it should take at the rate this model has read at before) and then one every
`every_s` while the model is still reading. `RecentRate` gives an ETA from the last few steps,
so one slow cold query does not inflate every later estimate.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from os.path import commonprefix

CHARS_PER_TOKEN_GUESS = 2.5  # before any reply: digits and separators are about one token each


class PromptReading:
    """Reports prompts of at least `min_tokens` new tokens while the model reads them."""

    def __init__(self, min_tokens: int = 2000, every_s: float = 30.0, stream=None) -> None:
        self.min_tokens, self.every_s, self.stream = min_tokens, every_s, stream
        self.chars_per_token: float | None = None  # learnt from the model's own token counts
        self.tokens_per_s: float | None = None  # learnt from earlier long reads
        self._last_prompt = ""

    def _print(self, text: str) -> None:
        print(f"bench: {text}", file=self.stream or sys.stderr, flush=True)

    @contextmanager
    def reading(self, prompt: str, cold: bool, shifted: bool = False) -> Iterator[None]:
        """Around one query: a line at the start of a long read, then one every `every_s` until it ends.
        `shifted`: the model moves its cached window instead of rereading it (KV-cache shifting), so a warm
        query reads only the newest pair, whatever the prompts' common prefix."""
        common = len(prompt) if shifted and self._last_prompt else len(commonprefix([self._last_prompt, prompt]))
        new_chars = len(prompt) if cold else max(0, len(prompt) - common)
        self._last_prompt = prompt
        tokens = new_chars / (self.chars_per_token or CHARS_PER_TOKEN_GUESS)
        if tokens < self.min_tokens:
            yield
            return
        expected = tokens / self.tokens_per_s if self.tokens_per_s else None
        about = f"; about {expected:.0f} s at the {self.tokens_per_s:.0f} tok/s read before" if expected else \
            "; no estimate yet (first long read of this model)"
        self._print(f"reading a prompt of about {tokens:,.0f} new tokens{' (cold)' if cold else ''}{about}")
        done, started = threading.Event(), time.monotonic()

        def tick() -> None:
            while not done.wait(self.every_s):
                so_far = time.monotonic() - started
                self._print(f"still reading the prompt: {so_far:.0f} s so far"
                            + (f" of about {expected:.0f} s" if expected else ""))

        ticker = threading.Thread(target=tick, daemon=True)
        ticker.start()
        try:
            yield
        finally:
            done.set()
            ticker.join()

    def learn(self, prompt: str, prompt_tokens: int, new_tokens: int, seconds: float) -> None:
        """After a reply: the model's characters per token and, from long reads, its reading rate."""
        if prompt_tokens > 0:
            self.chars_per_token = len(prompt) / prompt_tokens
        if new_tokens >= self.min_tokens and seconds > 0:
            self.tokens_per_s = new_tokens / seconds


class RecentRate:
    """Seconds per step over the last `window` steps: an ETA that forgets a slow start."""

    def __init__(self, window: int = 5) -> None:
        self._stamps: deque[tuple[float, int]] = deque(maxlen=window + 1)

    def add(self, done: int, now: float | None = None) -> None:
        self._stamps.append((time.monotonic() if now is None else now, done))

    def eta(self, remaining: int) -> float | None:
        """Seconds left for `remaining` steps at the recent rate; None until two steps were seen."""
        if len(self._stamps) < 2:
            return None
        (t0, n0), (t1, n1) = self._stamps[0], self._stamps[-1]
        return (t1 - t0) / (n1 - n0) * remaining if n1 > n0 else None
