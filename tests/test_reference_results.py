"""The committed reference stores reproduce at HEAD: a stale reference cannot land again.

The seed-policy trials of the cross-engine store in MuJoCo and PyBullet are re-run from the
settings each row records. Which check applies depends on where the test runs:

- **Bit for bit**, trial for trial (1e-9), where that can hold: the engines shown to give the
  same bits under every BLAS kernel and numpy SIMD level (`BIT_EXACT_ENGINES`, checked by
  `test_seed_policy_trials_are_bit_identical_across_blas_kernels`), and any engine when this
  machine's platform fingerprint equals the one the store's rows were made on.
- **Statistically**, per cell, everywhere else (README, "Reproducibility across CPUs"):
  - success count: an alarm only when one side succeeded in every trial and the other in none.
    For any success rate p, two samples of n = 5 do that with probability 2 p^5 (1-p)^5 <= 0.2%.
  - mean distance: an alarm beyond 5 standard errors of the difference of means (Welch; about
    0.1% for near-normal trial distances at n = 5).
  Over the 8 cells the false-alarm rate is at most about 2.4%.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmark.trial.cell import make_cell, setting_fields
from benchmark.trial.trials import run_cell
from benchmark.common.fingerprint import fingerprint_id

STORE = Path(__file__).parents[1] / "reports" / "data" / "cross_engine.parquet"
BIT_EXACT_ENGINES = ("mujoco", "pybullet")  # same bits under Haswell/Sandybridge OpenBLAS, numpy X86_V2/V3
STANDARD_ERRORS = 5.0


def _reruns():
    frame = pd.read_parquet(STORE)
    rows = frame[(frame["policy"] == "rl") & frame["sim"].isin(["mujoco", "pybullet"]) & (frame["seed"] < 5)]
    assert len(rows) == 40  # 8 cells x the first 5 seeds: a few seconds
    keys = setting_fields()
    for _, group in rows.groupby("cell_id"):
        first = group.iloc[0]
        values = {k: first[k] for k in keys if k in first and not pd.isna(first[k])}
        values.setdefault("heading_hold", True)  # stores from before the fixed command ran with the hold
        cell = make_cell(values, strict=False)
        yield cell, group, run_cell(cell, [int(s) for s in group["seed"]])


def statistical_mismatch(stored: pd.DataFrame, results) -> str | None:
    """Why the re-run trials disagree with the stored ones beyond chance, or None."""
    n_old, n_new = len(stored), len(results)
    won_old, won_new = int(stored["success"].sum()), sum(r.success for r in results)
    if {won_old / n_old, won_new / n_new} == {0.0, 1.0}:
        return f"success {won_new}/{n_new} here against {won_old}/{n_old} stored"
    old = stored["distance_m"].to_numpy(float)
    new = np.array([r.distance_m for r in results])
    se = math.sqrt(old.var(ddof=1) / n_old + new.var(ddof=1) / n_new)
    gap = abs(new.mean() - old.mean())
    if gap > STANDARD_ERRORS * se + 1e-6:
        return (f"mean distance {new.mean():.3f} m here against {old.mean():.3f} m stored "
                f"({gap / max(se, 1e-12):.1f} standard errors apart, > {STANDARD_ERRORS:g})")
    return None


def test_committed_seed_policy_trials_reproduce_at_head():
    here = fingerprint_id()
    for cell, group, results in _reruns():
        made_on = set(group.get("fingerprint_id", pd.Series(dtype=str)).dropna())
        exact = cell.sim in BIT_EXACT_ENGINES or made_on == {here}
        if exact:
            for result, (_, row) in zip(results, group.iterrows()):
                where = (f"bit-exact check failed ({cell.sim} is claimed bit-exact across CPUs, or this machine's "
                         f"fingerprint {here} made the store): {cell.label()} seed {row['seed']}")
                assert result.success == row["success"], where
                for key in ("nwt", "upright_fraction", "distance_m", "lateral_drift_m", "mean_vx"):
                    assert getattr(result, key) == pytest.approx(row[key], abs=1e-9), f"{where}: {key}"
        else:
            why = statistical_mismatch(group, results)
            assert why is None, f"statistical check failed (fingerprint {here}, store {sorted(made_on)}): " \
                                f"{cell.label()}: {why}"


def test_the_statistical_check_flags_a_real_change_and_passes_noise():
    from benchmark.trial.runner import TrialResult

    def trials(distances, success=True):
        return [TrialResult(seed=i, nwt=1.0, success=success, upright_fraction=1.0, distance_m=d, lateral_drift_m=0.0,
                            mean_vx=1.0, mean_height_m=0.3, heading_change_rad=0.0, fall_time=None, fall_reason=None,
                            stop_time=None, walk_window_s=2.0, walk_min_speed=0.2, walk_min_distance_m=4.0,
                            control_steps=100, wall_s=1.0) for i, d in enumerate(distances)]

    stored = pd.DataFrame({"success": [True] * 5, "distance_m": [9.0, 9.2, 8.8, 9.1, 1.7]})
    assert statistical_mismatch(stored, trials([9.5, 8.7, 9.2, 9.0, 8.9])) is None  # a rough-ground reshuffle
    assert "success 0/5" in statistical_mismatch(stored, trials([9.0] * 5, success=False))
    tight = pd.DataFrame({"success": [True] * 5, "distance_m": [9.0, 9.1, 9.0, 9.1, 9.05]})
    assert "mean distance" in statistical_mismatch(tight, trials([7.0, 7.1, 7.0, 7.1, 7.05]))


def _distances(sim: str, env: dict) -> list[float]:
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "run", "--policy", "rl", "--sim", sim, "--terrain",
                          "rough", "--trials", "2", "--duration", "6", "--json"], capture_output=True, text=True,
                         timeout=600, env={**os.environ, **env})
    assert out.returncode == 0, out.stderr
    return [t["distance_m"] for t in json.loads(out.stdout)["trials"]]


@pytest.mark.parametrize("sim", BIT_EXACT_ENGINES)
def test_seed_policy_trials_are_bit_identical_across_blas_kernels(sim):
    """The machines a store meets, emulated: two OpenBLAS kernels, and numpy held to its baseline SIMD."""
    one = _distances(sim, {"OPENBLAS_CORETYPE": "Haswell"})
    other = _distances(sim, {"OPENBLAS_CORETYPE": "Sandybridge", "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4"})
    assert one == other, f"{sim}: Haswell {one} vs Sandybridge/baseline SIMD {other}"
