"""A small MLP actor stored as plain numpy arrays (`.npz`) and run without torch.

The shipped seed policies are the deterministic actors of SB3 PPO policies: hidden layers
with an activation, then a linear output clipped to the action limit. Storing them as
arrays keeps checkpoints small (no optimizer state, no pickled classes) and inference fast.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ACTIVATIONS = {
    "elu": lambda x: np.where(x > 0, x, np.expm1(np.minimum(x, 0.0))),
    "tanh": np.tanh,
    "relu": lambda x: np.maximum(x, 0.0),
}


@dataclass(frozen=True)
class MlpActor:
    weights: tuple[np.ndarray, ...]  # (out, in) per layer, torch's layout
    biases: tuple[np.ndarray, ...]
    activation: str
    action_limit: float
    meta: dict

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float64)
        act = ACTIVATIONS[self.activation]
        for w, b in zip(self.weights[:-1], self.biases[:-1]):
            x = act(w @ x + b)
        return np.clip(self.weights[-1] @ x + self.biases[-1], -self.action_limit, self.action_limit)

    def save(self, path: Path) -> None:
        arrays = {f"w{i}": w for i, w in enumerate(self.weights)} | {f"b{i}": b for i, b in enumerate(self.biases)}
        np.savez_compressed(path, **{k: v.astype(np.float32) for k, v in arrays.items()},
                            meta=np.array(json.dumps({"activation": self.activation,
                                                      "action_limit": self.action_limit, **self.meta})))

    @classmethod
    def load(cls, path: Path) -> MlpActor:
        with np.load(path) as data:
            layers = sum(1 for k in data.files if k.startswith("w"))
            meta = json.loads(str(data["meta"]))
            weights = tuple(data[f"w{i}"].astype(np.float64) for i in range(layers))
            biases = tuple(data[f"b{i}"].astype(np.float64) for i in range(layers))
        return cls(weights, biases, meta.pop("activation"), float(meta.pop("action_limit")), meta)
