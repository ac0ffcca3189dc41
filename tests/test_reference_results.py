"""The committed reference stores reproduce at HEAD: a stale reference cannot land again.

The seed-policy trials of the cross-engine store in MuJoCo and PyBullet (deterministic on a CPU)
are re-run from the settings each row records and must match trial for trial (a few seconds)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from benchmark.cell import make_cell, run_cell, setting_fields

STORE = Path(__file__).parents[1] / "reports" / "data" / "cross_engine.parquet"


def test_committed_seed_policy_trials_reproduce_at_head():
    frame = pd.read_parquet(STORE)
    rows = frame[(frame["policy"] == "rl") & frame["sim"].isin(["mujoco", "pybullet"])]
    assert len(rows) == 40
    keys = setting_fields()
    for _, group in rows.groupby("cell_id"):
        first = group.iloc[0]
        cell = make_cell({k: first[k] for k in keys if k in first and not pd.isna(first[k])}, strict=False)
        results = run_cell(cell, [int(s) for s in group["seed"]])
        for result, (_, row) in zip(results, group.iterrows()):
            where = f"{cell.label()} seed {row['seed']}"
            assert result.success == row["success"], where
            for key in ("nwt", "upright_fraction", "distance_m", "lateral_drift_m", "mean_vx"):
                assert getattr(result, key) == pytest.approx(row[key], abs=1e-9), f"{where}: {key}"
