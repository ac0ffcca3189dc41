"""The control clock: does the simulation wait for the controller?

`paused` is the paper's protocol: simulated time stops while the model answers, so any model can
control at 10 Hz. `realtime` is what a robot lives with: the simulation keeps stepping at 10 Hz
while a query is in flight and the robot holds its last targets (zero-order hold); an answer takes
effect at the first control step at or after it arrives, and the next query starts at once, from
the newest observation. One query is in flight at a time. Latency is the query's measured wall
time, or a fixed number of seconds (simulated: reproducible for any controller). With measured
latency the model first reads the prompt of the step before its takeover, untimed (`warmup_s` in
the row), as a deployed controller would while the seed policy walks; timed queries then read only
what is new, and never come from the on-disk reply cache.

Steps are simulated, not slept: a query is answered when it is issued and its answer is held back
until simulated time has caught up with its latency, which gives the same trajectory as a robot
whose controller really ran that long, and runs at the simulator's speed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from benchmark.common.settings import SettingError

CLOCKS = ("paused", "realtime")
MEASURED = "measured"
ARRIVAL_SLACK_S = 1e-6  # float slack when comparing an arrival with a control step's time


def parse_latency(text: str | float) -> float | None:
    """None for "measured", else a number of seconds >= 0; anything else is a SettingError."""
    if isinstance(text, str) and text.strip() == MEASURED:
        return None
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise SettingError(f"latency must be '{MEASURED}' or a number of seconds >= 0, got '{text}'") from None
    if not math.isfinite(value) or value < 0:
        raise SettingError(f"latency must be '{MEASURED}' or a number of seconds >= 0, got {text}")
    return value


@dataclass
class _InFlight:
    arrives: float  # s of simulated time
    action: np.ndarray


class RealtimeClock:
    """Zero-order hold while one query is in flight; `latency` None: each query's own wall time."""

    def __init__(self, latency: float | None) -> None:
        self.latency = latency
        self.reset(np.zeros(0))

    def reset(self, held: np.ndarray) -> None:
        self.applied = np.asarray(held, dtype=float).copy()
        self.in_flight: _InFlight | None = None
        self.latencies: list[float] = []  # s, one per query
        self.held_steps: list[int] = []  # control steps each answer was applied (finished answers)
        self._steps_on_current = 0
        self._current_is_answer = False

    def _apply(self, action: np.ndarray) -> None:
        if self._current_is_answer:
            self.held_steps.append(self._steps_on_current)
        self.applied, self._steps_on_current, self._current_is_answer = action, 0, True

    def step(self, now: float, ask: Callable[[], tuple[np.ndarray, float]]) -> np.ndarray:
        """The targets for the control step at simulated time `now`. `ask()` answers from the newest
        observation and returns (action, its wall seconds); it is called only when nothing is in flight."""
        if self.in_flight is not None and self.in_flight.arrives <= now + ARRIVAL_SLACK_S:
            self._apply(self.in_flight.action)
            self.in_flight = None
        if self.in_flight is None:
            action, wall_s = ask()
            latency = wall_s if self.latency is None else self.latency
            self.latencies.append(latency)
            self.in_flight = _InFlight(now + latency, np.asarray(action, dtype=float))
            if self.in_flight.arrives <= now + ARRIVAL_SLACK_S:
                self._apply(self.in_flight.action)
                self.in_flight = None
        self._steps_on_current += 1
        return self.applied

    def metrics(self) -> dict:
        held = self.held_steps + ([self._steps_on_current] if self._current_is_answer else [])
        # None, not [], when nothing was asked (a fall before the takeover): the store keeps numeric lists as lists
        return {"query_latencies_s": [round(x, 6) for x in self.latencies] or None, "held_steps": held or None,
                "mean_held_steps": float(np.mean(held)) if held else None,
                "answers_applied": len(held), "mean_latency_s": float(np.mean(self.latencies)) if self.latencies
                else None}
