"""The results store: one parquet file per finished trial, named by the trial's id.

A trial is written to a temporary name and renamed into place, so a sweep killed at any
moment leaves only whole trials behind, and re-running it skips every id already there.
`results.parquet` beside `trials/` is a one-file snapshot for people and other tools.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq


class ResultStore:
    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)
        self.trials_dir = self.root / "trials"

    def done_ids(self) -> set[str]:
        return {p.stem for p in self.trials_dir.glob("*.parquet")}

    def columns(self, names: list[str]) -> pd.DataFrame:
        """Only these columns of every stored trial (missing ones as None): cheap on a big store."""
        rows = []
        for f in sorted(self.trials_dir.glob("*.parquet")):
            schema = pq.read_schema(f).names
            table = pq.read_table(f, columns=[n for n in names if n in schema]).to_pylist()[0]
            rows.append({n: table.get(n) for n in names})
        return pd.DataFrame(rows, columns=names)

    def write(self, row: dict) -> Path:
        """Store one trial atomically; nested values that are not numeric arrays go in as JSON text."""
        self.trials_dir.mkdir(parents=True, exist_ok=True)
        clean = {k: (json.dumps(v) if isinstance(v, dict) or _is_text_list(v) else v) for k, v in row.items()}
        path = self.trials_dir / f"{row['trial_id']}.parquet"
        tmp = self.trials_dir / f".{row['trial_id']}.parquet.tmp"
        pq.write_table(pa.Table.from_pylist([clean]), tmp)
        os.replace(tmp, path)
        return path

    def load(self) -> pd.DataFrame:
        """Every stored trial, one row each (empty frame when nothing ran yet)."""
        files = sorted(self.trials_dir.glob("*.parquet"))
        if not files:
            return pd.DataFrame()
        frames = [pq.read_table(f).to_pandas() for f in files]
        frames = [f.dropna(axis=1, how="all") for f in frames]  # all-null columns only blur dtypes
        return pd.concat(frames, ignore_index=True)

    def snapshot(self) -> Path:
        """Write `results.parquet`: all trials in one file."""
        path = self.root / "results.parquet"
        frame = self.load()
        if not frame.empty:
            frame.to_parquet(path, index=False)
        return path


def load_results(path: Path | str) -> pd.DataFrame:
    """A results directory (its trials) or a single parquet snapshot."""
    path = Path(path)
    if path.is_file():
        return pd.read_parquet(path)
    if not path.is_dir():
        raise FileNotFoundError(f"no results at '{path}': give a directory written by 'bench sweep' "
                                "or a results.parquet file")
    return ResultStore(path).load()


def _is_text_list(value) -> bool:
    """Lists of text (or empty ones) become JSON; numeric arrays and trajectories stay columns."""
    return isinstance(value, list) and (not value or not isinstance(value[0], (int, float, list)))
