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
import pyarrow.compute as pc
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
        """Every stored trial, one row each, in file-name order (empty frame when nothing ran yet).

        A trial's missing values (null, or NaN) are left out of its row, so they only blur dtypes as
        absences do. Trials with the same columns and types are joined in Arrow and turned into pandas
        once per group (a store holds a dozen shapes, not thousands): the frame is the one a per-trial
        `pd.concat` builds, at a fraction of its cost.
        """
        files = sorted(self.trials_dir.glob("*.parquet"))
        if not files:
            return pd.DataFrame()
        groups: dict[pa.Schema, list[tuple[int, pa.Table]]] = {}
        order: dict[str, None] = {}  # columns in order of first appearance, as pd.concat unites them
        for i, f in enumerate(files):
            table = _without_missing(pq.ParquetFile(f).read(use_threads=False))
            order.update(dict.fromkeys(table.column_names))
            groups.setdefault(table.schema, []).append((i, table))
        frames, rows = [], []
        for members in groups.values():
            frames.append(pa.concat_tables([t for _, t in members]).to_pandas())
            rows += [i for i, t in members for _ in range(t.num_rows)]
        frame = pd.concat(frames, ignore_index=True)
        frame.index = rows
        return frame.sort_index()[list(order)].reset_index(drop=True)

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


def _without_missing(table: pa.Table) -> pa.Table:
    """The table less its columns that hold nothing (only nulls, or only NaN)."""
    def empty(column: pa.ChunkedArray) -> bool:
        if column.null_count == len(column):
            return True
        return pa.types.is_floating(column.type) and bool(pc.all(pc.is_nan(column.drop_null())).as_py())
    return table.select([n for n, c in zip(table.column_names, table.columns) if not empty(c)])


def _is_text_list(value) -> bool:
    """Lists of text (or empty ones) become JSON; numeric arrays and trajectories stay columns."""
    return isinstance(value, list) and (not value or not isinstance(value[0], (int, float, list)))
