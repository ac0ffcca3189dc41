"""Experiment files, sweeps (local processes and Ray), the resumable results store and reports."""

from __future__ import annotations

import json

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmark.experiments.experiment import ExperimentError, available_experiments, load_experiment
from benchmark.experiments.report import bar_figure, paper_table, repeated_targets, summary_table, write_reports
from benchmark.common.store import ResultStore, load_results
from benchmark.common.tables import live_latency_mean
from benchmark.experiments.sweep import run_sweep

TINY = Path(__file__).parent / "data" / "tiny_sweep.toml"
BENCH = [sys.executable, "-m", "benchmark.cli"]


def _sweep(results: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([*BENCH, "sweep", str(TINY), "--workers", "2", "--results", str(results), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _metrics(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.set_index("trial_id").sort_index()[["terrain", "seed", "nwt", "success", "mean_height_m"]]


def _store_of(tmp_path: Path, name: str, toml: str) -> tuple[pd.DataFrame, Path]:
    """Write the experiment file `name`.toml, sweep it in one process into tmp_path/store: (rows, the file)."""
    path = tmp_path / f"{name}.toml"
    path.write_text(toml)
    run_sweep(load_experiment(str(path)).trials(), ResultStore(tmp_path / "store"), workers=1)
    return load_results(tmp_path / "store"), path


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> pd.DataFrame:
    """The tiny grid run start to finish with two worker processes."""
    results = tmp_path_factory.mktemp("uninterrupted")
    proc = _sweep(results)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert "4 trial(s) run, 0 already stored" in out
    return load_results(results)


def test_shipped_experiments_expand_into_the_papers_grids():
    assert set(available_experiments()) >= {"normalization", "history", "observation", "description", "cross_engine"}
    norm = load_experiment("normalization").trials()
    # The seed policy ignores the encoding: one seed-policy cell beside five encodings x five models
    # (the embedded model and four reference models), every row over the LLM's phase.
    assert len({t.cell for t in norm}) == 26 and len(norm) == 130
    llm = [t for t in norm if t.cell.policy == "llm"]
    assert sorted({t.cell.settings.encoding for t in llm}) == ["E1", "E2", "E3", "E4", "E5"]
    assert sorted({t.cell.settings.model for t in llm}) == ["embedded", "hold", "knn", "oracle", "replay"]
    assert all(t.cell.settings.observation == "O2" and t.cell.duration == 20.0 for t in llm)
    assert {t.cell.eval_start for t in norm} == {10.0}
    description = [t for t in load_experiment("description").trials() if t.labels["controller"] == "embedded"]
    assert [len(t.cell.settings.prompt_parts) for t in description[::5]] == [1, 2, 3, 4, 5]
    # the seed policy uses no description part: its one cell is labelled "-" in reports, not "E1"
    seed = [t for t in load_experiment("description").trials() if t.labels["controller"] == "seed_policy"]
    assert len({t.cell for t in seed}) == 1 and {t.labels["description"] for t in seed} == {None}
    history = load_experiment("history").trials()
    assert sorted({t.cell.settings.history for t in history if t.cell.policy == "llm"}) == [0, 10, 30, 50]
    cross = load_experiment("cross_engine")
    assert len({t.cell for t in cross.trials()}) == 3 * 2 * 2 * 2
    rl = cross.trials(only={"controller": "rl"})
    assert len(rl) == 12 * 20 and {t.cell.duration for t in rl} == {10.0}  # 20 seeds
    # Ids are stable (a resumed sweep finds its trials) and unique.
    assert [t.id for t in rl] == [t.id for t in cross.trials(only={"controller": "rl"})]
    assert len({t.id for t in cross.trials()}) == len(cross.trials())
    # A slice keeps each cell's place in the whole grid, so tables of slices run apart line up.
    place = {t.id: t.cell_index for t in cross.trials()}
    assert all(place[t.id] == t.cell_index for t in rl) and rl[-1].cell_index > len(rl) // 20


@pytest.mark.parametrize("text, message", [
    ("[fixed]\nengine = 'mujoco'\n", "unknown setting 'engine'; valid: sim, robot"),
    ("[grid]\nterrain = 'flat'\n", "grid.terrain must be a non-empty list"),
    ("[grid]\ncontroller = ['fast']\n[variants.controller]\nslow = { policy = 'rl' }\n",
     "names variant 'fast', not in [variants.controller]: slow"),
    ("seeds = 'five'\n", "seeds must be a count or a list of integers"),
    ("[grid\n", "not valid TOML"),
    ("tittle = 'x'\n", "unknown key 'tittle'"),
    ("[grid]\nhistory = [0, 10]\n[paper]\naxis = 'encoding'\n", "paper.axis must name a grid axis (history)"),
    ("[grid]\nhistory = [0, 10]\n[paper]\naxis = 'history'\nnwt = { 20 = 0.5 }\n",
     "paper.nwt needs numbers keyed by grid.history values (0, 10), not '20'"),
    ("[grid]\nhistory = [0, 10]\n[paper]\naxis = 'history'\nspeed = { 0 = 0.5 }\n", "paper.speed: expected a table"),
])
def test_malformed_experiment_files_are_one_clear_line(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ExperimentError) as err:
        load_experiment(str(path))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_bad_sweep_input_exits_2_with_one_line(tmp_path):
    for args, message in [(["sweep", "nope"], "shipped experiments: compact, cross_engine, description"),
                          (["sweep", str(TINY), "--set", "sim=gazebo", "--results", str(tmp_path)],
                           "unknown simulator 'gazebo'"),
                          (["sweep", str(TINY), "--set", "colour=red"], "--set: unknown setting 'colour'"),
                          (["sweep", str(TINY), "--only", "terrain=lava"], "no cell of 'tiny' matches")]:
        proc = subprocess.run([*BENCH, *args], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2, proc.stderr
        lines = [line for line in proc.stderr.splitlines() if line.startswith("bench:")]
        assert len(lines) == 1 and message in lines[0], proc.stderr
    assert not any(tmp_path.iterdir())  # nothing ran, nothing was written


def test_dry_run_lists_cells_and_missing_trials(tmp_path):
    proc = subprocess.run([*BENCH, "sweep", str(TINY), "--dry-run", "--results", str(tmp_path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "tiny: 2 cells, 4 trials, 4 missing" in proc.stdout
    assert "pybullet/a1/flat/stand" in proc.stdout and "pybullet/a1/rough/stand" in proc.stdout


def test_sweep_killed_mid_run_resumes_without_duplicates(tmp_path, uninterrupted):
    results = tmp_path / "killed"
    store = ResultStore(results)
    proc = _sweep(results)
    deadline = time.monotonic() + 240
    while not store.done_ids() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and its workers, no chance to clean up
    proc.wait()
    stored_at_kill = len(store.done_ids())
    assert 1 <= stored_at_kill < 4, "the kill came after the sweep finished: the test proves nothing"
    resumed = _sweep(results)
    out, err = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, err
    assert f"{4 - stored_at_kill} trial(s) run, {stored_at_kill} already stored" in out
    frame = load_results(results)
    assert len(frame) == 4 and frame["trial_id"].is_unique
    pd.testing.assert_frame_equal(_metrics(frame), _metrics(uninterrupted))
    assert len(pd.read_parquet(results / "results.parquet")) == 4


def test_ray_executor_on_a_local_ray_instance(tmp_path, uninterrupted):
    pytest.importorskip("ray")
    proc = subprocess.run([*BENCH, "sweep", str(TINY), "--workers", "2", "--executor", "ray",
                           "--results", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "4 trial(s) run" in proc.stdout and "ray worker" in proc.stdout
    frame = load_results(tmp_path)
    pd.testing.assert_frame_equal(_metrics(frame), _metrics(uninterrupted))
    assert frame["git_commit"].notna().all() and frame["versions"].str.contains("pybullet").all()


def test_rows_carry_parameters_metrics_versions_and_trajectories(uninterrupted):
    row = uninterrupted.iloc[0]
    assert row["experiment"] == "tiny" and row["sim"] == "pybullet" and row["policy"] == "stand"
    assert row["duration"] == 60.0 and row["control_steps"] == 600 and len(row["traj_joint_pos"]) == 600
    assert len(row["traj_joint_pos"][0]) == 12 
    assert row["sweep_command"].startswith("bench sweep ") and "--workers 2" in row["sweep_command"]
    assert pd.isna(row.get("encoding")) and row["promptwalk_version"] == "0.1.0"


def test_rows_and_reports_say_which_machine_made_them(uninterrupted, tmp_path):
    from benchmark.common.fingerprint import fingerprint_id, platform_fingerprint

    row = uninterrupted.iloc[0]
    stored = json.loads(row["fingerprint"])
    assert row["fingerprint_id"] == fingerprint_id(stored) == fingerprint_id()
    assert stored == json.loads(json.dumps(platform_fingerprint()))
    assert stored["blas"] and stored["blas"][0]["architecture"]  # the OpenBLAS kernel this machine picked
    write_reports(uninterrupted, tmp_path, "md")
    md = (tmp_path / "tiny.md").read_text()
    assert f"Made on: `{row['fingerprint_id']}` (4 trials): {stored['cpu']}" in md
    assert f"kernel {stored['blas'][0]['architecture']}" in md


def test_report_writes_markdown_html_csv_and_png_figures(tmp_path, uninterrupted):
    written = write_reports(uninterrupted, tmp_path, "md")
    md = (tmp_path / "tiny.md").read_text()
    lines = [line for line in md.splitlines() if line.startswith("|")]
    headline, table = lines[:4], lines[4:8]  # a narrow headline table, then every metric
    assert headline[0] == "| terrain | trials | NWT | success rate | distance (m) |"
    assert table[0].startswith("| terrain | trials | NWT | success rate | upright")
    assert [line.split(" | ")[0] for line in table[2:]] == ["| flat", "| rough"]  # grid order
    # standing is not walking: NWT 0, success 0 with its 95% interval at 2 trials, upright throughout
    assert all(" | 2 | 0.000 ± 0.000 | 0.00 [0.00, 0.66] | 1 |" in line for line in table[2:]), table
    for name in ("tiny_bars.png", "tiny_trajectories.png"):
        png = tmp_path / "figures" / name
        assert png in written and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000
        assert f"](figures/{name})" in md
    write_reports(uninterrupted, tmp_path, "csv")
    assert len(pd.read_csv(tmp_path / "tiny.csv")) == 2
    write_reports(uninterrupted, tmp_path, "html")
    assert "<table" in (tmp_path / "tiny.html").read_text()


def test_the_store_loads_trials_of_many_shapes_as_one_frame_per_trial_concat_would(tmp_path):
    """The grouped Arrow load gives the frame that concatenating each trial's own frame gives (the reference
    semantics: a trial's missing values are absences), rows in file-name order, columns by first appearance."""
    import pyarrow.parquet as pq

    store = ResultStore(tmp_path)
    rows = [{"trial_id": "c", "nwt": 0.5, "success": True, "path": [1.0, 2.0], "note": "x"},
            {"trial_id": "a", "nwt": 1.0, "success": None, "path": [3.0], "model": "knn"},
            {"trial_id": "b", "nwt": float("nan"), "success": False, "path": [4.0], "note": None, "queries": 7},
            {"trial_id": "d", "nwt": 0.25, "success": True, "path": [5.0], "note": "y"},
            {"trial_id": "e", "nwt": float("nan"), "queries": 3}]
    for row in rows:
        store.write(row)
    files = sorted(store.trials_dir.glob("*.parquet"))
    reference = pd.concat([pq.read_table(f).to_pandas().dropna(axis=1, how="all") for f in files], ignore_index=True)
    loaded = store.load()
    pd.testing.assert_frame_equal(loaded, reference)
    assert list(loaded["trial_id"]) == ["a", "b", "c", "d", "e"]
    assert list(loaded.columns) == ["trial_id", "nwt", "path", "model", "success", "queries", "note"]
    assert loaded["success"].tolist()[1:4] == [False, True, True] and pd.isna(loaded["success"][0])
    assert ResultStore(tmp_path / "none").load().empty


def test_report_of_a_missing_or_empty_store_is_one_line(tmp_path):
    for target, message in [(tmp_path / "nothing", "no results at"), (tmp_path, "holds no trials yet")]:
        proc = subprocess.run([*BENCH, "report", str(target), "--out", str(tmp_path / "out")],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2 and message in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr


def test_llm_cells_sweep_with_the_embedded_model_and_report_tokens(tmp_path, monkeypatch):
    monkeypatch.setenv("PROMPTWALK_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "llm.toml"
    path.write_text('name = "llm_tiny"\nseeds = [0]\n[fixed]\nsim = "mujoco"\nduration = 2.3\nllm_after = 2.0\n'
                    'history = 5\nhistory_mode = "block"\n[grid]\npolicy = ["rl", "llm"]\nencoding = ["E4", "E5"]\n')
    trials = load_experiment(str(path)).trials()
    assert len(trials) == 3  # one seed-policy cell, two LLM cells
    outcome = run_sweep(trials, ResultStore(tmp_path / "results"), workers=1, threads=1)
    assert outcome.ran == 3
    frame = load_results(tmp_path / "results")
    llm = frame[frame["policy"] == "llm"]
    assert (llm["queries"] >= 1).all() and (llm["input_tokens"] > llm["gpt4_input_tokens"]).all()
    assert (llm["eval_start"] == 2.0).all() and frame[frame["policy"] == "rl"]["encoding"].isna().all()
    write_reports(frame, tmp_path / "reports")
    md = (tmp_path / "reports" / "llm_tiny.md").read_text()
    assert "| policy | encoding | trials | NWT |" in md and "GPT-4 input tokens" in md and "| rl | - | 1 |" in md
    assert "kNN agreement" in md and "Wilson 95% interval" in md
    assert (tmp_path / "reports" / "figures" / "llm_tiny_trajectories.png").is_file()


def test_reference_rows_cover_the_llm_phase_from_the_same_state_and_tables_show_intervals(tmp_path):
    frame, _ = _store_of(tmp_path, "phase",
        'name = "phase"\nseeds = [0, 1]\n[fixed]\nduration = 2.5\nseed_start = 1.0\nllm_after = 2.0\n'
        'history = 5\n[grid]\ncontroller = ["seed_policy", "hold"]\n[variants.controller]\n'
        'seed_policy = { policy = "rl" }\nhold = { policy = "llm", model = "hold" }\n')
    assert set(frame["eval_start"]) == {2.0} and len(frame) == 4
    for seed in (0, 1):
        rows = frame[frame["seed"] == seed].set_index("controller")
        before = 20  # control steps up to the takeover at 2 s
        seed_traj, hold_traj = rows.loc["seed_policy", "traj_joint_pos"], rows.loc["hold", "traj_joint_pos"]
        assert [list(q) for q in seed_traj[:before]] == [list(q) for q in hold_traj[:before]]
        assert [list(q) for q in seed_traj[before:]] != [list(q) for q in hold_traj[before:]]
    write_reports(frame, tmp_path / "reports")
    text = (tmp_path / "reports" / "phase.md").read_text().split("## Closed-loop diagnostics")[0]
    table = [line for line in text.splitlines()
             if line.startswith("| ") and not line.startswith("| controller |")]  # rows of both tables
    assert len(table) == 4 and all(" [" in line and "±" in line for line in table), table
    repeated = summary_table(frame).set_index("controller")["repeated targets"]
    assert repeated["hold"] == 1.0 and np.isnan(repeated["seed_policy"])  # frozen by design; not an LLM row


def test_latency_is_the_mean_over_live_queries_and_cached_replies_carry_none():
    trials = pd.DataFrame({"latency_mean_s": [2.0, 14.0, 0.0], "queries": [100, 100, 50], "cache_hits": [0, 98, 50]})
    assert live_latency_mean(trials) == pytest.approx((100 * 2.0 + 2 * 14.0) / 102)  # not (2 + 14 + 0) / 3
    assert np.isnan(live_latency_mean(trials.iloc[2:]))  # every reply from the cache: nothing measured
    # The committed description ablation: its E5 cell came wholly from the cache, E1's trials were partly resumed.
    frame = load_results(Path(__file__).parents[1] / "reports" / "data" / "description.parquet")
    latency = summary_table(frame, spread=False).set_index(["controller", "description"])["latency (s)"]
    assert np.isnan(latency["embedded", "E5"])
    e1 = frame[(frame["controller"] == "embedded") & (frame["description"] == "E1")]
    live = e1["queries"] - e1["cache_hits"]
    assert latency["embedded", "E1"] == round(float((e1["latency_mean_s"] * live).sum() / live.sum()), 2)
    assert latency["embedded", "E1"] < e1["latency_mean_s"].mean()  # its 5-query resumed trials read cold


def test_the_papers_figures_stand_beside_the_stores_in_table_and_figure(tmp_path):
    frame, path = _store_of(tmp_path, "paper",
        'name = "paper"\nseeds = [0]\n[fixed]\nduration = 2.5\nllm_after = 2.0\nseed_start = 1.0\n'
        '[grid]\ncontroller = ["seed_policy", "hold"]\nhistory = [5, 10]\n[variants.controller]\n'
        'seed_policy = { policy = "rl" }\nhold = { policy = "llm", model = "hold" }\n'
        '[paper]\naxis = "history"\nsource = "a paper"\nnwt = { 5 = 0.25, 10 = 0.75 }\n')
    published = paper_table(frame, load_experiment(str(path)).paper)
    assert list(published["history"]) == ["5", "10"] and list(published["paper NWT"]) == [0.25, 0.75]
    assert published["hold: success / NWT"].str.startswith("0.00 / ").all()
    paper = load_experiment(str(path)).paper
    assert bar_figure(frame, summary_table(frame, spread=False), tmp_path / "bars.png", "t", paper).is_file()
    # The shipped ablations carry the paper's figures into their reports (here from the committed store).
    committed = load_results(Path(__file__).parents[1] / "reports" / "data" / "history.parquet")
    write_reports(committed, tmp_path / "reports", fmt="md")
    text = (tmp_path / "reports" / "history.md").read_text()
    assert "Beside the paper (Wang et al. 2023, GPT-4" in text and "| 50 | 7298 |" in text
    # Made with the heading hold, before the fixed command: no row is in today's grid, and the report says so.
    assert "Partial store" not in text and "**Earlier protocol**: none of these 105 trials" in text
    trials = load_experiment("history").trials()
    current = committed.assign(trial_id=[t.id for t in trials[:len(committed)]])
    write_reports(current.iloc[:-7], tmp_path / "partial", fmt="md")
    assert "**Partial store**: 98 of the grid's 105 trials" in (tmp_path / "partial" / "history.md").read_text()


def test_repeated_targets_tell_a_frozen_reply_from_a_gait():
    row = {"policy": "llm", "control_dt": 0.1, "eval_start": 0.2}
    still = [[0.0, 1.0]] * 2 + [[0.5, 0.5]] * 4  # the phase (steps at 0.3-0.6 s) repeats one reply
    moving = [[0.0, 1.0]] * 2 + [[0.1 * i, 0.5] for i in range(4)]
    assert repeated_targets(pd.Series({**row, "traj_joint_target": still})) == 1.0
    assert repeated_targets(pd.Series({**row, "traj_joint_target": moving})) == 0.0
    assert np.isnan(repeated_targets(pd.Series({**row, "policy": "rl", "traj_joint_target": still})))


def test_axis_values_read_as_written_in_tables():
    # the seed policy's row has no history, so the stored column is float: history 10 must still read "10"
    store = pd.read_parquet(Path(__file__).parents[1] / "reports" / "data" / "history.parquet")
    table = summary_table(store, spread=False)
    assert set(table["history"]) == {"-", "0", "10", "30", "50"}


def test_trials_of_another_seed_policy_run_again_and_say_so(tmp_path, capsys):
    """A store's trials record the seed policy they ran; after a new policy ships, a sweep reruns them."""
    import dataclasses

    import pyarrow as pa
    import pyarrow.parquet as pq

    trials = [t for t in load_experiment(TINY).trials() if t.seed == 0][:1]
    trials = [dataclasses.replace(t, cell=dataclasses.replace(t.cell, duration=0.5)) for t in trials]
    store = ResultStore(tmp_path / "store")
    assert run_sweep(trials, store).ran == 1
    assert run_sweep(trials, store).ran == 0  # same policy: kept
    path = next(store.trials_dir.glob("*.parquet"))
    row = pq.read_table(path).to_pylist()[0]
    pq.write_table(pa.Table.from_pylist([{**row, "seed_policy_sha256": "0123456789ab"}]), path)
    capsys.readouterr()
    assert run_sweep(trials, store).ran == 1
    assert "1 stored trial(s) of a1 ran another seed policy (0123456789ab, now" in capsys.readouterr().err
    assert len(load_results(store.root)) == 1


def test_a_dry_run_counts_trials_of_another_seed_policy_as_missing(tmp_path, capsys):
    import pyarrow as pa
    import pyarrow.parquet as pq

    from benchmark.cli.main import main

    args = ["sweep", str(TINY), "--results", str(tmp_path / "store"), "--set", "duration=0.5", "--seeds", "1",
            "--only", "terrain=flat"]
    assert main(args) == 0
    capsys.readouterr()
    assert main([*args, "--dry-run"]) == 0
    assert "1 trials, 0 missing" in capsys.readouterr().out
    path = next((tmp_path / "store" / "trials").glob("*.parquet"))
    row = pq.read_table(path).to_pylist()[0]
    pq.write_table(pa.Table.from_pylist([{**row, "seed_policy_sha256": "0123456789ab"}]), path)
    assert main([*args, "--dry-run"]) == 0
    assert "1 trials, 1 missing" in capsys.readouterr().out


@pytest.mark.parametrize("name", ["realtime", "latency", "prompting"])
def test_committed_stores_keep_their_trial_ids_under_todays_settings(name):
    """A setting added after a store was made (prompt strategies came after these stores) leaves the ids of
    trials at its default as they were: the committed store still matches its experiment, so nothing reruns."""
    ids = {t.id for t in load_experiment(name).trials()}
    stored = load_results(Path(__file__).parents[1] / "reports" / "data" / (name if name == "prompting" else f"{name}.parquet"))
    closed_loop = stored[stored["kind"] != "probe"] if "kind" in stored else stored
    assert len(closed_loop) and closed_loop["trial_id"].isin(ids).all()
    if "kind" in stored:  # the probe stage's rows too, each keyed by the history mode its probe read with
        from benchmark.evaluate.probe import load_probe_set
        from benchmark.evaluate.study import probe_jobs

        experiment = load_experiment(name)
        probes = stored[stored["kind"] == "probe"]
        jobs = {j.id: j for j in probe_jobs(experiment, load_probe_set(experiment.probe_set).digest)}
        assert len(probes) and probes["trial_id"].isin(jobs).all()
        assert all(jobs[i].llm.history_mode == mode == "sliding" for i, mode in zip(probes["trial_id"],
                                                                                   probes["history_mode"]))


def test_an_experiment_naming_an_unassembled_model_lists_dry_runs_and_asks_for_it_only_to_run(tmp_path):
    """`PROMPTWALK_MODELS` is an empty folder: the ladder's optional models are absent, as on a fresh machine."""
    env = {**os.environ, "PROMPTWALK_MODELS": str(tmp_path / "models")}
    listed = subprocess.run([*BENCH, "sweep", "--list"], capture_output=True, text=True, timeout=120, env=env)
    assert listed.returncode == 0 and "prompting" in listed.stdout, listed.stderr
    dry = subprocess.run([*BENCH, "sweep", "prompting", "--dry-run", "--results", "reports/data/prompting"],
                         capture_output=True, text=True, timeout=120, env=env, cwd=Path(__file__).parents[1])
    assert dry.returncode == 0 and "0 missing" in dry.stdout, dry.stderr
    run = subprocess.run([*BENCH, "sweep", "prompting", "--only", "controller=qwen15_nearest_only", "--seeds", "1",
                          "--results", str(tmp_path / "store")], capture_output=True, text=True, timeout=120, env=env)
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert "bench models --assemble qwen2.5-coder-1.5b" in run.stderr
    assert not (tmp_path / "store" / "rows").exists() or not any((tmp_path / "store" / "rows").iterdir())


def test_a_trial_whose_seed_phase_falls_is_counted_apart(tmp_path):
    """MuJoCo A1 rough, seed 53: the seed policy falls at 3.1 s, before the takeover at 10 s, so the controller under
    test never acts; seed 50 walks. The report counts the fall apart and measures the controller on seed 50 alone."""
    frame, _ = _store_of(tmp_path, "early",
        'name = "early"\nseeds = [50, 53]\n[fixed]\nsim = "mujoco"\nrobot = "a1"\nterrain = "rough"\n'
        'duration = 12.0\nllm_after = 10.0\nseed_start = 1.0\nprompt_strategy = "nearest-only"\n'
        '[grid]\ncontroller = ["oracle"]\n[variants.controller]\noracle = { policy = "llm", model = "oracle" }\n')
    assert sorted(frame["fall_time"].fillna(99.0).round(1)) == [3.1, 99.0]  # the seed phase of seed 53 fell
    row = summary_table(frame, spread=False).iloc[0]
    assert row["trials"] == 1 and row["fell before takeover (apart)"] == 1
    assert row["success rate"] == 1.0 and row["NWT"] == 1.0  # not 0.5: the fall is not the controller's
    write_reports(frame, tmp_path / "reports")
    assert "fell before takeover (apart)" in (tmp_path / "reports" / "early.md").read_text()


def test_a_report_says_when_rough_trials_ran_on_earlier_ground():
    """Rows record the ground's digest; a rough row made on other ground (or before the digest) is named in the
    report, a row on today's ground and a flat row are not."""
    from benchmark.experiments.report import earlier_ground
    from benchmark.experiments.sweep import terrain_digest

    today = terrain_digest("rough", 0)
    frame = pd.DataFrame({"terrain": ["rough", "rough", "flat"], "terrain_seed": [0, 0, 0],
                          "terrain_sha256": [today, None, "flat"]})
    assert earlier_ground(frame).startswith("**Earlier ground**: 1 of these rough-ground trials")
    assert earlier_ground(frame.iloc[[0, 2]]) == ""
