"""Experiment files: a TOML grid over cells, expanded into trials.

    name = "normalization"
    title = "Normalization methods: 20 s walks, velocities only"
    seeds = [0, 1, 2, 3, 4]

    [fixed]                      # every cell
    policy = "llm"
    observation = "O2"

    [grid]                       # every combination of these
    encoding = ["E1", "E2", "E3", "E4", "E5"]

    [variants.description]       # optional: named bundles of settings, one axis of the grid
    D1 = { prompt_parts = ["task"] }

    [paper]                      # optional: the published figures per value of one axis
    axis = "encoding"
    source = "Wang et al. 2023, GPT-4"
    nwt = { E1 = 0.137, E2 = 0.086, E3 = 0.700, E4 = 0.504, E5 = 0.721 }

    [probe]                      # optional: the imitation probe for every combination of its grid,
    cells = ["a1/flat"]          # one row each in the same store (benchmark.evaluate.study)
    grid = { model = ["embedded", "knn"], strategy = ["chronological", "nearest"] }

A cell is one `CellSpec` (engine, robot, terrain, policy and its settings); a trial is a
cell and a seed. Settings that only another policy reads are dropped from a cell, so a grid
over encodings does not run the seed policy five times.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from benchmark.common.settings import SettingError
from benchmark.trial.cell import CellSpec, make_cell, setting_fields

if TYPE_CHECKING:
    import pandas as pd

EXPERIMENTS_DIR = Path(__file__).parent


class ExperimentError(SettingError):
    """A malformed experiment file or override: one line for the user."""


@dataclass(frozen=True)
class Trial:
    experiment: str
    cell: CellSpec
    seed: int
    labels: dict = field(default_factory=dict, compare=False)  # the cell's value on each grid axis
    cell_index: int = field(default=0, compare=False)  # position of the cell in the grid, for tables

    @property
    def id(self) -> str:
        """Stable across runs and machines: the results store's key."""
        key = json.dumps([self.experiment, self.cell.id_params(), self.seed], sort_keys=True)
        return hashlib.sha256(key.encode()).hexdigest()[:16]

    @property
    def cell_id(self) -> str:
        key = json.dumps([self.experiment, self.cell.id_params()], sort_keys=True)
        return hashlib.sha256(key.encode()).hexdigest()[:12]


@dataclass(frozen=True)
class Experiment:
    name: str
    title: str
    fixed: dict
    grid: dict  # axis -> list of values; an axis named after a variants table picks from it
    variants: dict  # axis -> {variant name -> settings}
    seeds: tuple[int, ...]
    source: Path | None = None
    paper: dict = field(default_factory=dict)  # {"axis", "source", metric -> {axis value (text) -> figure}}
    probe: dict = field(default_factory=dict)  # {"grid", "cells", "window", "items", "draft", "probe_set"}: the probe stage

    @property
    def probe_set(self) -> Path | None:
        """The probe set the probe stage scores on (None: the shipped one; see `probe_set_for` when one per engine)."""
        sets = self.probe.get("probe_set")
        return Path(sets) if isinstance(sets, str) else None

    def probe_set_for(self, labels: dict) -> Path | None:
        """The probe set of one probe run: the engine's (its `sim` label) when the table keys sets by engine."""
        sets = self.probe.get("probe_set")
        return Path(sets[str(labels["sim"])]) if isinstance(sets, dict) else self.probe_set

    def probe_settings(self, overrides: dict | None = None, only: dict | None = None) -> list[tuple[dict, dict]]:
        """(LLM settings, labels) of every combination of the probe's grid: the file's [fixed] LLM settings, then
        the grid's (an axis named after a variants table picks from it), then `overrides`; `only` keeps the
        combinations whose labels or settings match (as text)."""
        grid = self.probe.get("grid", {})
        out = []
        for combo in itertools.product(*grid.values()):
            settings, labels = {k: v for k, v in self.fixed.items() if k not in PROBE_IGNORES}, {}
            for axis, value in zip(grid, combo):
                labels[axis] = value
                settings.update(self.variants[axis][value] if axis in self.variants else {axis: value})
            settings.update({k: v for k, v in (overrides or {}).items() if k not in PROBE_IGNORES})
            if only and any(str({**settings, **labels}.get(k)) != v for k, v in only.items()):
                continue
            out.append((settings, labels))
        return out

    @property
    def axes(self) -> list[str]:
        return list(self.grid)

    def trials(self, overrides: dict | None = None, only: dict | None = None) -> list[Trial]:
        """Every (cell, seed), deduplicated, in grid order; `overrides` win over the file's settings,
        `only` keeps the cells whose parameters match (values compared as text)."""
        out, seen, cells = [], set(), {}
        valid = list(dict.fromkeys([*setting_fields(), *self.grid]))
        for key in only or {}:
            if key not in valid:
                raise ExperimentError(f"--only: unknown setting '{key}'; valid: {', '.join(valid)}")
        for combo in itertools.product(*self.grid.values()):
            settings, variants = dict(self.fixed), {}
            for axis, value in zip(self.grid, combo):
                if axis in self.variants:
                    variants[axis] = value
                    settings.update(self.variants[axis][value])
                else:
                    settings[axis] = value
            settings.update(overrides or {})
            cell = make_cell(settings, where=self.name, strict=False)
            params = cell.params()
            labels = {}
            for axis in self.grid:
                if axis in variants:  # None where the policy uses none of its settings (seed policy: no description)
                    used = any(params.get(key) is not None for key in self.variants[axis][variants[axis]])
                    labels[axis] = variants[axis] if used else None
                else:  # a setting the policy ignores reads None (the seed policy has no encoding)
                    labels[axis] = params.get(axis)
            index = cells.setdefault(cell, len(cells))  # counted over the whole grid, so slices agree
            if only and any(str({**params, **labels}.get(k)) != v for k, v in only.items()):
                continue
            for seed in self.seeds:
                trial = Trial(self.name, cell, seed, labels=labels, cell_index=index)
                if trial.id not in seen:
                    seen.add(trial.id)
                    out.append(trial)
        return out


def parse_overrides(items: list[str]) -> dict:
    """`--set key=value` pairs; values are read as TOML (numbers, booleans, lists), else as text."""
    out = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ExperimentError(f"--set expects KEY=VALUE, got '{item}'")
        try:
            out[key] = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            out[key] = text
    known = setting_fields()
    for key in out:
        if key not in known:
            raise ExperimentError(f"--set: unknown setting '{key}'; valid: {', '.join(known)}")
    return out


def available_experiments() -> list[str]:
    return sorted(p.stem for p in EXPERIMENTS_DIR.glob("*.toml"))


def load_experiment(name_or_path: str) -> Experiment:
    """A shipped experiment by name (see `bench sweep --list`) or a TOML file by path."""
    path = Path(name_or_path)
    if not path.is_file():
        shipped = EXPERIMENTS_DIR / f"{name_or_path}.toml"
        if not shipped.is_file():
            raise ExperimentError(f"no experiment file '{name_or_path}'; shipped experiments: "
                                  f"{', '.join(available_experiments())} (or give a path to a .toml)")
        path = shipped
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise ExperimentError(f"{path}: not valid TOML: {err}") from None
    allowed = {"name", "title", "seeds", "fixed", "grid", "variants", "paper", "probe"}
    unknown = [k for k in data if k not in allowed]
    if unknown:
        raise ExperimentError(f"{path}: unknown key '{unknown[0]}'; valid: {', '.join(sorted(allowed))}")
    grid, variants = data.get("grid", {}), data.get("variants", {})
    for axis, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ExperimentError(f"{path}: grid.{axis} must be a non-empty list")
        if axis in variants:
            missing = [v for v in values if v not in variants[axis]]
            if missing:
                raise ExperimentError(f"{path}: grid.{axis} names variant '{missing[0]}', not in "
                                      f"[variants.{axis}]: {', '.join(variants[axis])}")
    paper = _paper_figures(path, data.get("paper", {}), grid)
    seeds = data.get("seeds", [0, 1, 2, 3, 4])
    if isinstance(seeds, int):
        seeds = list(range(seeds))
    if not seeds or not all(isinstance(s, int) for s in seeds):
        raise ExperimentError(f"{path}: seeds must be a count or a list of integers")
    probe = _probe_table(path, data.get("probe", {}), variants)
    experiment = Experiment(name=data.get("name", path.stem), title=data.get("title", path.stem),
                            fixed=data.get("fixed", {}), grid=grid,
                            variants=variants, seeds=tuple(seeds), source=path, paper=paper, probe=probe)
    try:
        experiment.trials()  # every cell must build: unknown settings fail here, before any trial runs
    except ExperimentError:
        raise
    except ValueError as err:
        raise ExperimentError(f"{path}: {err}") from None
    return experiment


PROBE_KEYS = ("grid", "cells", "window", "items", "draft", "probe_set")
# cell settings the probe set fixes (its engine, walks and disturbance), not the prompt
PROBE_IGNORES = ("sim", "robot", "terrain", "terrain_seed", "policy", "duration", "heading_hold", "disturbance")


def _probe_table(path: Path, probe: dict, variants: dict) -> dict:
    """The `[probe]` table checked: known keys, a grid of non-empty lists naming existing variants."""
    unknown = [k for k in probe if k not in PROBE_KEYS]
    if unknown:
        raise ExperimentError(f"{path}: probe: unknown key '{unknown[0]}'; valid: {', '.join(PROBE_KEYS)}")
    if "probe_set" in probe:  # a probe set .npz, relative to the experiment file; or one per engine
        sets = probe["probe_set"]
        if isinstance(sets, dict):
            engines = probe.get("grid", {}).get("sim")
            if not engines or sorted(map(str, engines)) != sorted(sets):
                raise ExperimentError(f"{path}: probe.probe_set keyed by engine needs probe.grid.sim naming the same "
                                      f"engines ({', '.join(sets)})")
        found = {k: (path.parent / v).resolve() for k, v in (sets.items() if isinstance(sets, dict) else [("", sets)])}
        for where, file in found.items():
            if not file.is_file():
                raise ExperimentError(f"{path}: probe.probe_set{'.' + where if where else ''}: no file '{file}' (make "
                                      f"one: bench probe --make{' --sim ' + where if where else ''} --out PATH)")
        probe = {**probe, "probe_set": {k: str(v) for k, v in found.items()} if isinstance(sets, dict) else str(found[""])}
    for axis, values in probe.get("grid", {}).items():
        if not isinstance(values, list) or not values:
            raise ExperimentError(f"{path}: probe.grid.{axis} must be a non-empty list")
        missing = [v for v in values if axis in variants and v not in variants[axis]]
        if missing:
            raise ExperimentError(f"{path}: probe.grid.{axis} names variant '{missing[0]}', not in "
                                  f"[variants.{axis}]: {', '.join(variants[axis])}")
    return probe


PAPER_METRICS = ("nwt", "success", "gpt4_input_tokens", "gpt4_output_tokens")


def _findings(path: Path, findings, axis: str, values: set[str]) -> list[dict]:
    """`paper.findings`: each {better, worse, says}, two values of the paper's axis and the claim in words."""
    keys = ("better", "worse", "says")
    if not isinstance(findings, list) or not all(isinstance(f, dict) and set(f) == set(keys) for f in findings):
        raise ExperimentError(f"{path}: paper.findings must be a list of {{ better = ..., worse = ..., says = ... }}")
    for f in findings:
        stray = [str(f[k]) for k in ("better", "worse") if str(f[k]) not in values]
        if stray:
            raise ExperimentError(f"{path}: paper.findings names '{stray[0]}', not a grid.{axis} value "
                                  f"({', '.join(sorted(values))})")
    return [{k: str(f[k]) for k in keys} for f in findings]


def _paper_figures(path: Path, paper: dict, grid: dict) -> dict:
    """The `[paper]` table checked: one grid axis, figures keyed by that axis's values (as text)."""
    if not paper:
        return {}
    axis = paper.get("axis")
    if axis not in grid:
        raise ExperimentError(f"{path}: paper.axis must name a grid axis ({', '.join(grid)}), got {axis!r}")
    values = {str(v) for v in grid[axis]}
    out = {"axis": axis, "source": str(paper.get("source", "the paper"))}
    for key, figures in paper.items():
        if key in ("axis", "source"):
            continue
        if key == "findings":
            out[key] = _findings(path, figures, axis, values)
            continue
        if key not in PAPER_METRICS or not isinstance(figures, dict):
            raise ExperimentError(f"{path}: paper.{key}: expected a table of figures for one of "
                                  f"{', '.join(PAPER_METRICS)}")
        stray = [k for k in figures if k not in values]
        if stray or not all(isinstance(v, (int, float)) for v in figures.values()):
            raise ExperimentError(f"{path}: paper.{key} needs numbers keyed by grid.{axis} values "
                                  f"({', '.join(sorted(values))})" + (f", not '{stray[0]}'" if stray else ""))
        out[key] = {k: float(v) for k, v in figures.items()}
    return out


def axes_of(frame: pd.DataFrame) -> list[str]:
    """The experiment's grid axes, in the order of its file."""
    axes: list[str] = []
    for text in frame["axes"].dropna().unique():
        axes += [a for a in json.loads(text) if a not in axes]
    return axes
