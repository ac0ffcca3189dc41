"""Ctrl-C semantics for long work (`bench run`, `bench sweep`, `bench train`).

First Ctrl-C: stop starting new trials, let the trials in flight finish for a short grace
period, keep everything finished, exit with code 130 saying what was kept. Second Ctrl-C:
stop at once. Worker processes ignore SIGINT (the driver ends them), so a Ctrl-C to the
process group or to the driver alone leaves no orphans and no tracebacks. SIGTERM (a process
manager, `kill`) and SIGHUP (a closed terminal, a dropped SSH connection) stop at once, as a
second Ctrl-C does: workers and servers are ended and what finished is kept.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable

TERMINATING = (signal.SIGTERM, signal.SIGHUP)  # signals that end the work at once
GRACE_S = 5.0  # s that trials in flight get to finish after the first Ctrl-C


class Interrupted(Exception):
    """The user stopped the work; what finished was kept."""


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


class Interruption:
    """While active, the first SIGINT sets `requested` (and, with `alarm`, interrupts the work
    after the grace period); the second calls `on_second` and interrupts at once."""

    def __init__(self, grace_s: float = GRACE_S, alarm: bool = True, on_second: Callable[[], None] | None = None,
                 what: str = "trials in flight") -> None:
        self.grace_s, self.alarm, self.on_second, self.what = grace_s, alarm, on_second, what
        self.requested = False

    def _handle(self, signum, frame) -> None:
        if self.requested:
            if self.on_second is not None:
                self.on_second()
            raise KeyboardInterrupt
        self.requested = True
        print(f"bench: interrupted: letting the {self.what} finish for up to {self.grace_s:g} s; "
              "Ctrl-C again to stop at once", file=sys.stderr, flush=True)
        if self.alarm:
            signal.signal(signal.SIGALRM, _raise_interrupt)
            signal.setitimer(signal.ITIMER_REAL, self.grace_s)

    def _terminate(self, signum, frame) -> None:
        self.requested = True
        if self.on_second is not None:
            self.on_second()
        raise KeyboardInterrupt

    def __enter__(self) -> Interruption:
        self._previous = {signal.SIGINT: signal.signal(signal.SIGINT, self._handle)}
        for signum in TERMINATING:
            self._previous[signum] = signal.signal(signum, self._terminate)
        return self

    def __exit__(self, *exc) -> None:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)


def ignore_sigint() -> None:
    """In a worker process: the driver decides when work stops."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
