"""A small MLP actor stored as plain numpy arrays (`.npz`) and run without torch.

The shipped seed policies are the deterministic actors of SB3 PPO policies: hidden layers
with an activation, then a linear output clipped to the action limit. Storing them as
arrays keeps checkpoints small (no optimizer state, no pickled classes) and inference fast.

Inference gives the same bits on every CPU. `w @ x` goes through BLAS, whose kernel (and with
it the order of the sums) depends on the CPU, and numpy's `expm1`/`tanh` use SIMD code chosen by
CPU too (SVML on AVX-512); on rough ground a last-bit difference grows into metres. So each
layer multiplies elementwise and sums every row with numpy's pairwise summation (a fixed order
in float64), and the activations use the C library's scalar functions.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_expm1 = np.frompyfunc(math.expm1, 1, 1)
_tanh = np.frompyfunc(math.tanh, 1, 1)


def _elu(x: np.ndarray) -> np.ndarray:
    out = x.copy()
    negative = x < 0
    out[negative] = _expm1(x[negative]).astype(np.float64)
    return out


ACTIVATIONS = {
    "elu": _elu,
    "tanh": lambda x: _tanh(x).astype(np.float64),
    "relu": lambda x: np.maximum(x, 0.0),
}


def linear(w: np.ndarray, b: np.ndarray, x: np.ndarray) -> np.ndarray:
    """w @ x + b, summed in a fixed order whatever BLAS or CPU (numpy's pairwise row sums, float64)."""
    return (w * x).sum(axis=1) + b


@dataclass(frozen=True)
class MlpActor:
    weights: tuple[np.ndarray, ...]  # (out, in) per layer, torch's layout
    biases: tuple[np.ndarray, ...]
    activation: str
    action_limit: float
    meta: dict

    @property
    def symmetric(self) -> bool:
        """Left/right symmetric inference (`meta["symmetric"]`): the mean of the actor's answer and the mirror
        image of its answer to the mirrored observation, so the policy has exactly no turning bias
        (benchmark.trial.symmetry; set for actors trained with mirrored-state augmentation)."""
        return bool(self.meta.get("symmetric", False))

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if self.symmetric:
            from benchmark.trial.symmetry import mirror_joints, mirror_rl_observation

            return 0.5 * (self._forward(obs) + mirror_joints(self._forward(mirror_rl_observation(obs))))
        return self._forward(obs)

    def _forward(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float64)
        act = ACTIVATIONS[self.activation]
        for w, b in zip(self.weights[:-1], self.biases[:-1]):
            x = act(linear(w, b, x))
        return np.clip(linear(self.weights[-1], self.biases[-1], x), -self.action_limit, self.action_limit)

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
