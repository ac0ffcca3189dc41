"""Imitation skill on teacher-forced items: 1 - error / the error of freezing on the newest action, averaged over
probe cells (freezing scores 0, the seed policy's own action 1), and its bootstrap over items resampled within each
cell. The probe scores a run with it; the reports compare two runs over the same items with it."""

from __future__ import annotations

import numpy as np

BOOTSTRAP = 2000  # resamples of a bootstrap interval


def skill(errors: np.ndarray, hold_errors: np.ndarray, cells: np.ndarray) -> float:
    """Mean over cells of 1 - mean error / mean hold error (hold 0, oracle 1)."""
    values = [1.0 - errors[cells == c].mean() / max(hold_errors[cells == c].mean(), 1e-12) for c in np.unique(cells)]
    return float(np.mean(values))


def item_resamples(cells: np.ndarray, seed: int = 0) -> np.ndarray:
    """(BOOTSTRAP, N) item indices, resampled within each cell (the cells keep their weight)."""
    rng = np.random.default_rng(seed)
    out = np.empty((BOOTSTRAP, len(cells)), dtype=int)
    for c in np.unique(cells):
        where = np.flatnonzero(cells == c)
        out[:, where] = rng.choice(where, size=(BOOTSTRAP, len(where)))
    return out


def skill_difference(errors: np.ndarray, other_errors: np.ndarray, hold_errors: np.ndarray, cells: np.ndarray,
                     seed: int = 0, other_hold_errors: np.ndarray | None = None) -> tuple[float, float, float]:
    """skill(errors) - skill(other_errors) on the same items, with its paired 95% bootstrap interval; the other run
    may measure its errors in other units (another number format: `other_hold_errors`)."""
    other_hold = hold_errors if other_hold_errors is None else other_hold_errors
    draws = [skill(errors[i], hold_errors[i], cells[i]) - skill(other_errors[i], other_hold[i], cells[i])
             for i in item_resamples(cells, seed)]
    low, high = np.percentile(draws, [2.5, 97.5])
    return skill(errors, hold_errors, cells) - skill(other_errors, other_hold, cells), float(low), float(high)


def unpaired_skill_difference(errors: np.ndarray, hold_errors: np.ndarray, other_errors: np.ndarray,
                              other_hold_errors: np.ndarray) -> tuple[float, float, float]:
    """skill of one run minus another's over different items (one cell each), with a 95% bootstrap interval that
    resamples each run's items on its own."""
    one, other = np.zeros(len(errors)), np.zeros(len(other_errors))
    draws = [skill(errors[i], hold_errors[i], one) - skill(other_errors[j], other_hold_errors[j], other)
             for i, j in zip(item_resamples(one, 0), item_resamples(other, 1))]
    low, high = np.percentile(draws, [2.5, 97.5])
    return skill(errors, hold_errors, one) - skill(other_errors, other_hold_errors, other), float(low), float(high)
