"""Disturbances: what happens to the robot after the takeover that its demonstrations never showed.

    bench run --llm knn --prompt-strategy nearest-only --disturbance shoves

A prompt's examples come from the seed policy walking undisturbed before the takeover, so a controller
that copies them (`knn`, `hold`) meets a shove or a weakened body with actions made for another
state. The seed policy was trained with shoves (up to 0.5 m/s per axis every 5 s) and motor strength
0.9-1.1, so `oracle` (its action through the text channel) may ride out more than the copies do:
where `oracle` walks and the same prompt's trivial answers do not, a model's own contribution shows
(the hard track; `bench report hard_track` names those cells). Times count from the evaluated phase's
start (the takeover), so the prompts up to it are those of the undisturbed trial, and every engine
applies the same schedule through `Simulator.push_base` and `Simulator.set_dynamics`. With the LLM
setting `tell_disturbance` the description says what the disturbance does (its `told` sentence):
copying cannot read a sentence, so a model that turns it into other targets shows it.

    none           nothing (the paper's protocol)
    weak_motors    every motor gives 60% of its PD torque from the takeover on: the shown targets
                   no longer produce the shown motion
    weaker_motors  50%
    shoves         sideways shoves of 1 m/s, left, right, left, 2, 5 and 8 s after the takeover

Measured on A1 flat in MuJoCo, 10 seeds (oracle / knn / hold success): weak_motors 10 / 0 / 0, shoves of
1 m/s 5 / 3 / 3 (of 5). A 40% heavier base (10 / 10 / 10), friction 0.4 (10 / 10 / 10) and shoves of
0.5 m/s (10 / 10 / 10) left the copies walking, so they are not offered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sims.base import Dynamics, Simulator


@dataclass(frozen=True)
class Disturbance:
    """A schedule of shoves and a change of dynamics, in s after the evaluated phase starts."""

    name: str
    help: str
    shoves: tuple[tuple[float, float, float], ...] = ()  # (s after the takeover, vx, vy in m/s, world frame)
    dynamics: Dynamics | None = None  # applied at the takeover, nominal again at the next reset
    told: str = ""  # the sentence a prompt adds to its description with `tell_disturbance` (our words)

    def start(self, sim: Simulator) -> None:
        """At the episode's start: nominal dynamics (an engine is reused across trials)."""
        if self.dynamics is not None:
            sim.set_dynamics(Dynamics())

    def apply(self, sim: Simulator, since_takeover: float, dt: float) -> None:
        """Called after every control step with the time since the takeover (negative before it)."""
        if self.dynamics is not None and 0.0 <= since_takeover < dt / 2:
            sim.set_dynamics(self.dynamics)
        for at, vx, vy in self.shoves:
            if abs(since_takeover - at) < dt / 2:
                sim.push_base(np.array([vx, vy]))


DISTURBANCES: dict[str, Disturbance] = {d.name: d for d in (
    Disturbance("none", "nothing: the paper's protocol"),
    Disturbance("weak_motors", "every motor gives 60% of its torque from the takeover on",
                dynamics=Dynamics(motor_strength=0.6),
                told="Now every motor gives only 60% of the torque it gave when the examples were recorded: the "
                     "same targets move the joints less and later than the examples show."),
    Disturbance("weaker_motors", "every motor gives 50% of its torque from the takeover on",
                dynamics=Dynamics(motor_strength=0.5),
                told="Now every motor gives only half the torque it gave when the examples were recorded: the same "
                     "targets move the joints less and later than the examples show."),
    Disturbance("shoves", "sideways shoves of 1 m/s, left, right, left, 2, 5 and 8 s after the takeover",
                shoves=((2.0, 0.0, 1.0), (5.0, 0.0, -1.0), (8.0, 0.0, 1.0)),
                told="Now the body is shoved sideways at 1 m/s every 3 s, left, right, then left again; the "
                     "examples never met a shove."),
)}
NO_DISTURBANCE = DISTURBANCES["none"]
