"""The paper's observation choices: which of the 33 LLM observation values enter the prompt."""

from __future__ import annotations

import numpy as np

from robots import UnknownNameError

# Slices of the 33-dim LLM observation: lin vel 0:3, ang vel 3:6, gravity 6:9, joint pos 9:21, joint vel 21:33.
OBSERVATIONS: dict[str, tuple[str, np.ndarray]] = {
    "O1": ("none", np.arange(0)),
    "O2": ("base linear and angular velocity", np.arange(0, 6)),
    "O3": ("joint positions and velocities", np.arange(9, 33)),
    "O4": ("base velocities, joint positions and velocities", np.r_[0:6, 9:33]),
    "O5": ("full observation", np.arange(33)),
}
DEFAULT_OBSERVATION = "O5"
FIELD_NAMES = (["base linear velocity x, y, z"] + ["base angular velocity x, y, z"] + ["projected gravity x, y, z"]
               + ["joint positions (12, relative to the default pose)"] + ["joint velocities (12)"])


def select(choice: str) -> np.ndarray:
    """Indices into the 33-dim LLM observation for observation choice O1..O5."""
    if choice not in OBSERVATIONS:
        raise UnknownNameError("observation choice", choice, list(OBSERVATIONS))
    return OBSERVATIONS[choice][1]


def describe(choice: str) -> list[str]:
    """The groups of values a choice contains, in order, for the prompt text."""
    idx = set(select(choice).tolist())
    groups = [(range(0, 3), FIELD_NAMES[0]), (range(3, 6), FIELD_NAMES[1]), (range(6, 9), FIELD_NAMES[2]),
              (range(9, 21), FIELD_NAMES[3]), (range(21, 33), FIELD_NAMES[4])]
    return [name for r, name in groups if set(r) <= idx]
