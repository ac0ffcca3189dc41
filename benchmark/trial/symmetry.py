"""Left/right mirror symmetry of a quadruped's observations and actions.

Reflecting the world in the robot's sagittal (x-z) plane swaps the right legs with the left
(FR <-> FL, RR <-> RL in the canonical order), negates hip abduction (every robot here abducts
about +x, with a default pose symmetric under that sign flip) and keeps thigh and calf angles.
Base vectors map as vectors (vy -> -vy) and angular rates as pseudo-vectors (wx, wz -> -wx, -wz).
Training uses it for mirrored-state augmentation (`benchmark.training.train.SymmetricPPO`): every
transition is also learnt mirrored, so a policy has no turning bias to drift with.
"""

from __future__ import annotations

import numpy as np

from robots import JOINT_ROLES, LEGS

_LEG_MIRROR = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}
JOINT_PERMUTATION = np.array([LEGS.index(_LEG_MIRROR[leg]) * len(JOINT_ROLES) + r
                              for leg in LEGS for r in range(len(JOINT_ROLES))])
JOINT_SIGN = np.tile([-1.0, 1.0, 1.0], len(LEGS))  # hip abduction, thigh, calf
_VECTOR = np.array([1.0, -1.0, 1.0])  # linear velocity, projected gravity
_PSEUDO = np.array([-1.0, 1.0, -1.0])  # angular velocity
_COMMAND = np.array([1.0, -1.0, -1.0])  # vx, vy, yaw rate


def mirror_joints(x: np.ndarray) -> np.ndarray:
    """Per-joint quantities (..., 12) in canonical order, mirrored (offsets from a symmetric default)."""
    return x[..., JOINT_PERMUTATION] * JOINT_SIGN


def mirror_rl_observation(obs: np.ndarray) -> np.ndarray:
    """The 48-dim RL observation (..., 48) of the mirrored robot (layout: benchmark.trial.observation)."""
    obs = np.asarray(obs)
    base = np.concatenate([_VECTOR, _PSEUDO, _VECTOR, _COMMAND])
    return np.concatenate([obs[..., :12] * base, mirror_joints(obs[..., 12:24]), mirror_joints(obs[..., 24:36]),
                           mirror_joints(obs[..., 36:48])], axis=-1)


def mirror_matrices(obs_dim: int = 48, joints: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Both mirrors as matrices, x -> x @ M (they are linear): the RL observation's and the joints'."""
    return mirror_rl_observation(np.eye(obs_dim)), mirror_joints(np.eye(joints))
