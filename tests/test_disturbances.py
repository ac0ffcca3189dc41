"""Disturbances after the takeover: applied on schedule in every engine, and the hard-track condition defeats
copying the demonstrations while the seed policy's own action walks through it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from benchmark.trial.cell import make_cell
from benchmark.trial.disturbances import DISTURBANCES
from benchmark.trial.trials import TrialHooks, run_cell


class LateralSpeed(TrialHooks):
    """The base's world-frame sideways speed after every control step."""

    def start(self, seed, sim, policy, episode):
        self.vy = []
        return lambda loop: self.vy.append(float(loop.state.base_lin_vel[1]))


def test_shoves_land_on_schedule_after_the_takeover():
    """MuJoCo, the seed policy from a 1 s takeover: the base's sideways speed jumps by about the shove at 1 s + 2 s,
    and an undisturbed trial of the same seed shows no such jump."""
    speeds = {}
    for name in ("none", "shoves"):
        cell = make_cell({"sim": "mujoco", "policy": "llm", "model": "oracle", "duration": 4.0, "llm_after": 1.0,
                          "seed_start": 0.5, "disturbance": name})
        watch = LateralSpeed()
        run_cell(cell, [0], hooks=[watch])
        speeds[name] = np.array(watch.vy)
    jump = speeds["shoves"] - speeds["none"]
    at = int(round((1.0 + DISTURBANCES["shoves"].shoves[0][0]) / 0.1)) - 1  # the step the shove follows
    assert np.allclose(jump[:at], 0.0) and jump[at + 1] > 0.5  # identical before, then shoved left


@pytest.mark.parametrize("sim, undisturbed_twin", [("mujoco", True), ("pybullet", True),
                                                    pytest.param("newton", False, marks=pytest.mark.slow)])
def test_weak_motors_defeat_copying_while_the_seed_policy_walks(sim, undisturbed_twin):
    """A1 flat on `nearest-only`, seed 0, 4 s after the takeover at 10 s: with 60% of the motors' torque from the
    takeover, `oracle` (the seed policy through the text channel) walks on, while `knn` and `hold`, copying targets
    shown for full-strength motors, do not; undisturbed, `knn` walks (measured over 10 seeds and 20 s in MuJoCo and
    PyBullet: oracle 10/10, knn 0/10, hold 0/10; Newton, 3 seeds: 3/3, 0/3, 0/3)."""
    def success(model: str, disturbance: str) -> bool:
        cell = make_cell({"sim": sim, "robot": "a1", "policy": "llm", "model": model, "duration": 14.0,
                          "prompt_strategy": "nearest-only", "disturbance": disturbance})
        return bool(run_cell(cell, [0])[0].success)

    assert success("oracle", "weak_motors")
    assert not success("knn", "weak_motors") and not success("hold", "weak_motors")
    if undisturbed_twin:  # Newton, the slowest engine here, leaves it to its matrix cells' undisturbed knn rows
        assert success("knn", "none")


def test_the_matrix_report_names_a_hard_track_cell_and_pairs_gains_over_seeds(tmp_path):
    """A tiny matrix in MuJoCo (A1 flat, undisturbed and with weak motors, 2 seeds, the paper's takeover at 10 s, 5 s
    after it): the report draws the matrix, marks the paper's cell, puts weak motors on the hard track (oracle walks, knn and hold do not)
    and leaves the undisturbed cell off it (knn walks)."""
    from benchmark.common.store import ResultStore, load_results
    from benchmark.experiments.experiment import load_experiment
    from benchmark.experiments.report import write_reports
    from benchmark.experiments.sweep import run_sweep

    path = tmp_path / "tiny_matrix.toml"
    path.write_text('name = "tiny_matrix"\nseeds = 2\n[fixed]\nduration = 15.0\nllm_after = 10.0\nseed_start = 1.0\n'
                    'prompt_strategy = "nearest-only"\n[grid]\nsim = ["mujoco"]\nrobot = ["a1"]\nterrain = ["flat"]\n'
                    'disturbance = ["none", "weak_motors"]\ncontroller = ["oracle", "knn_nearest_only", "hold_nearest_only"]\n'
                    '[variants.controller]\noracle = { policy = "llm", model = "oracle" }\n'
                    'knn_nearest_only = { policy = "llm", model = "knn" }\nhold_nearest_only = { policy = "llm", model = "hold" }\n')
    run_sweep(load_experiment(str(path)).trials(), ResultStore(tmp_path / "store"), workers=1)
    write_reports(load_results(tmp_path / "store"), tmp_path / "reports")
    text = (tmp_path / "reports" / "tiny_matrix.md").read_text()
    assert (tmp_path / "reports" / "figures" / "tiny_matrix_matrix.png").stat().st_size > 10_000
    hard = next(line for line in text.splitlines() if line.startswith("**The hard track**"))
    assert "mujoco/a1/flat/weak_motors" in hard and "mujoco/a1/flat *" not in hard
    assert "| mujoco/a1/flat * | 0 | 2/2" in text  # the paper's cell, marked; no fall before the takeover
    from benchmark.experiments.report_matrix import closed_loop_view

    view = "\n".join(closed_loop_view([tmp_path / "store", tmp_path / "absent"]))  # the leaderboard's per-cell view
    assert "| controller | mujoco/a1/flat * | mujoco/a1/flat/weak_motors (hard) |" in view  # the hard track named
    assert "where a model's own contribution can show: mujoco/a1/flat/weak_motors." in view
    assert "| oracle | 2/2 | 2/2 |" in view and "| knn_nearest_only | 2/2 | 0/2 |" in view


def test_a_trial_ended_at_its_stop_keeps_nwt_and_success_and_asks_fewer_queries(tmp_path):
    """`--end-at-stop` in MuJoCo, A1 with weak motors, copying the nearest example (seeds 0-2: two stop, one falls):
    NWT, success, the stop and the fall are those of the whole episode; the stopped trials end 2 s after the stop
    began (the walking test's window), ask a quarter of the queries and leave upright unmeasured; the fall is
    untouched. Through the sweep, the store and the report say so."""
    from benchmark.common.store import ResultStore, load_results
    from benchmark.experiments.experiment import load_experiment
    from benchmark.experiments.report import write_reports
    from benchmark.experiments.sweep import run_sweep
    from benchmark.trial.resources import Resources, Runtime

    cell = make_cell({"prompt_strategy": "nearest-only", "model": "knn", "disturbance": "weak_motors"})
    whole = run_cell(cell, range(3))
    resources = Resources(Runtime(end_at_stop=True))
    try:
        cut = run_cell(cell, range(3), resources)
    finally:
        resources.close()
    for w, c in zip(whole, cut):
        assert (c.nwt, c.success, c.stop_time, c.fall_time) == (w.nwt, w.success, w.stop_time, w.fall_time)
    assert [c.ended_at_stop for c in cut] == [w.stop_time is not None and w.fall_time is None for w in whole]
    assert sum(c.ended_at_stop for c in cut) >= 1 and any(c.fall_time is not None for c in cut)
    for w, c in zip(whole, cut):
        if c.ended_at_stop:
            assert c.upright_fraction is None and c.control_steps == int(round((c.stop_time + 2.0) / 0.1))
            assert c.policy_metrics["queries"] < 0.5 * w.policy_metrics["queries"]
        else:
            timeless = {"wall_s": 0, "policy_metrics": {}}  # times and latencies differ run to run
            assert dataclasses.replace(c, **timeless) == dataclasses.replace(w, **timeless)

    path = tmp_path / "tiny_stop.toml"
    path.write_text('name = "tiny_stop"\nseeds = 2\n[fixed]\nduration = 20.0\nllm_after = 10.0\nseed_start = 1.0\n'
                    'prompt_strategy = "nearest-only"\ndisturbance = "weak_motors"\n[grid]\ncontroller = ["knn"]\n'
                    '[variants.controller]\nknn = { policy = "llm", model = "knn" }\n')
    run_sweep(load_experiment(str(path)).trials(), ResultStore(tmp_path / "store"), workers=1,
              runtime=Runtime(end_at_stop=True))
    stored = load_results(tmp_path / "store").sort_values("seed")
    assert stored["seed"].tolist() == [0, 1] and stored["ended_at_stop"].tolist() == [c.ended_at_stop for c in cut[:2]]
    assert (stored["load_1m_mean"] > 0).all() and (stored["load_1m_max"] >= stored["load_1m_mean"]).all()
    write_reports(stored, tmp_path / "reports")
    text = (tmp_path / "reports" / "tiny_stop.md").read_text()
    assert f"**Trials ended at their stop**: {sum(c.ended_at_stop for c in cut[:2])} of 2 trials" in text


def _matrix_cells() -> list:
    """Every (engine, robot, terrain, disturbance) cell of the shipped matrix and hard-track experiments, once."""
    from benchmark.experiments.experiment import load_experiment

    cells = {}
    for name in ("matrix", "hard_track"):
        for trial in load_experiment(name).trials(only={"controller": "knn_nearest_only"}):
            c = trial.cell
            key = (c.sim, c.robot, c.terrain, c.disturbance)
            marks = [pytest.mark.slow] if c.sim == "newton" else []
            cells.setdefault(key, pytest.param(c, id="/".join(key), marks=marks))
    return list(cells.values())


@pytest.mark.parametrize("cell", _matrix_cells())
def test_every_matrix_cell_loads_and_runs_a_reference_trial(cell):
    """Each cell's `knn` row, shortened to 2 s of the model after a 2 s seed phase: it runs, answers every step from
    its prompt and records the cell's disturbance."""
    import dataclasses

    settings = dataclasses.replace(cell.settings, llm_after=2.0, seed_start=0.5)
    short = dataclasses.replace(cell, duration=4.0, settings=settings)
    result = run_cell(short, [0])[0]
    assert result.control_steps > 0 and result.policy_metrics["parse_failures"] == 0
    assert short.params()["disturbance"] in DISTURBANCES


def test_an_engine_never_carries_one_cells_weak_motors_into_another_cell():
    """One worker's resources run a weak-motors cell, then a shoved one, as a sweep does: the shoved trial equals the
    same trial on fresh engines (a shared engine kept the weakened motors before engines were keyed by disturbance)."""
    from benchmark.trial.resources import Resources

    def cell(disturbance: str):
        return make_cell({"sim": "mujoco", "robot": "a1", "policy": "llm", "model": "oracle", "duration": 14.0,
                          "prompt_strategy": "nearest-only", "disturbance": disturbance})

    shared = Resources()
    try:
        run_cell(cell("weaker_motors"), [0], shared)
        after = run_cell(cell("shoves"), [0], shared)[0]
    finally:
        shared.close()
    fresh = run_cell(cell("shoves"), [0])[0]
    assert (after.fall_time, after.distance_m) == (fresh.fall_time, fresh.distance_m)


def test_each_engine_screens_its_cells_on_its_own_probe_set(tmp_path):
    """A probe stage keyed by engine (MuJoCo's and PyBullet's committed sets) scores each engine's cells on its own
    walks: two runs with two digests, and the matrix report puts each model's per-cell probe skill and gain beside
    that engine's closed loop (knn here, whose gain over the prompt's knn is 0 by construction)."""
    from benchmark.cli.main import main
    from benchmark.common.store import load_results
    from benchmark.experiments.report import write_reports

    sets = Path(__file__).parents[1] / "benchmark" / "experiments"
    path = tmp_path / "screen.toml"
    path.write_text(
        'name = "screen"\nseeds = 1\n[fixed]\nduration = 11.0\nllm_after = 10.0\nseed_start = 1.0\n'
        'prompt_strategy = "nearest-only"\nhistory = 50\n[grid]\nsim = ["mujoco", "pybullet"]\nrobot = ["a1"]\n'
        'terrain = ["flat"]\ncontroller = ["oracle", "knn_nearest_only", "hold_nearest_only"]\n[variants.controller]\n'
        'oracle = { policy = "llm", model = "oracle" }\nknn_nearest_only = { policy = "llm", model = "knn" }\n'
        'hold_nearest_only = { policy = "llm", model = "hold" }\n[probe]\n'
        f'probe_set = {{ mujoco = "{sets / "prompting_probe.npz"}", pybullet = "{sets / "probe_pybullet.npz"}" }}\n'
        'cells = ["a1/flat"]\nitems = 2\ngrid = { sim = ["mujoco", "pybullet"], model = ["knn"] }\n')
    assert main(["sweep", str(path), "--results", str(tmp_path / "store")]) == 0
    frame = load_results(tmp_path / "store")
    probes = frame[frame["kind"] == "probe"]
    assert sorted(probes["sim"]) == ["mujoco", "pybullet"] and probes["probe_digest"].nunique() == 2
    write_reports(frame, tmp_path / "reports")
    text = (tmp_path / "reports" / "screen.md").read_text()
    for cell in ("mujoco/a1/flat *", "pybullet/a1/flat *"):
        line = next(row for row in text.splitlines() if row.startswith(f"| {cell} |"))
        assert "skill " in line and "gain +0.00 [+0.00, +0.00]" in line, line


def test_a_disturbed_probe_cell_walks_its_undisturbed_twin_until_the_takeover():
    """`bench probe --make --cells a1/flat/weak_motors`: the seed policy walks the undisturbed walk's pairs up to and
    including the takeover's, then answers a weakened body (other observations and actions)."""
    from benchmark.evaluate.probe import ProbeSetConfig, make_probe_set

    probe = make_probe_set(ProbeSetConfig(cells=("a1/flat", "a1/flat/weak_motors"), rollouts=1, items=5),
                           progress=lambda _: None)
    plain, weak = probe.walks
    assert probe.cells == ["a1/flat", "a1/flat/weak_motors"] and weak.robot == "a1"
    first = plain.first_item
    assert np.array_equal(plain.observations[:first + 1], weak.observations[:first + 1])
    assert not np.allclose(plain.observations[first + 2:], weak.observations[first + 2:])
    assert not np.allclose(plain.actions[first + 2:], weak.actions[first + 2:])


def test_a_probe_cell_that_names_no_terrain_or_disturbance_is_one_line(tmp_path):
    import subprocess
    import sys

    for cells, message in ((["a1/flat/earthquake"], "unknown disturbance 'earthquake'; valid: none, weak_motors"),
                           (["a1/ice"], "unknown terrain 'ice'; valid: flat, rough"),
                           (["a1"], "expected ROBOT/TERRAIN or ROBOT/TERRAIN/DISTURBANCE")):
        out = subprocess.run([sys.executable, "-m", "benchmark.cli", "probe", "--make", "--cells", *cells, "--out",
                              str(tmp_path / "p.npz")], capture_output=True, text=True, timeout=120)
        assert out.returncode == 2 and out.stderr.count("\n") == 1 and message in out.stderr, out.stderr
    assert not (tmp_path / "p.npz").exists()


@pytest.mark.parametrize("sim", ["mujoco", "pybullet", "newton"])
def test_copying_misses_more_on_the_hard_tracks_probe_sets(sim):
    """The hard track's probe stage screens each engine on its committed disturbed set: `knn` (the nearest example's
    action) misses the seed policy's answer to weak motors by more than it misses the same engine's undisturbed walk,
    in A1 and ANYmal alike; so a model that answers the state rather than copying can gain there."""
    from benchmark.evaluate.probe import ProbeRun, answer_items, load_probe_set, summarize_answers
    from benchmark.experiments.experiment import load_experiment
    from benchmark.llm.controller import LLMSettings
    from benchmark.llm.models import make_model

    experiment = load_experiment("hard_track")
    hard = load_probe_set(experiment.probe_set_for({"sim": sim}))
    plain = load_probe_set(load_experiment("matrix").probe_set_for({"sim": sim}))
    assert hard.meta["config"]["sim"] == plain.meta["config"]["sim"] == sim
    llm = LLMSettings(model="knn", history=50, prompt_strategy="nearest-only")

    def errors(probe, cells):
        answers = answer_items(probe, ProbeRun(llm=llm, cells=cells), model=make_model("knn", cache=False))
        return {cell: c["error"] for cell, c in summarize_answers(answers)["cells"].items()}

    disturbed = errors(hard, None)
    undisturbed = errors(plain, ("a1/flat", "anymal/flat"))
    assert set(disturbed) == {"a1/flat/weak_motors", "anymal/flat/weaker_motors"}
    for robot, name in (("a1", "a1/flat/weak_motors"), ("anymal", "anymal/flat/weaker_motors")):
        assert disturbed[name] > 1.5 * undisturbed[f"{robot}/flat"], (name, disturbed, undisturbed)


def test_the_report_screens_a_disturbed_cell_with_its_disturbed_probe_cell():
    """probe_screen: a hard-track row (weak motors) reads the probe's a1/flat/weak_motors cell, an undisturbed row the
    plain a1/flat cell, and neither reads the other's."""
    import json

    import pandas as pd

    from benchmark.experiments.report_matrix import probe_screen

    probes = pd.DataFrame([{"sim": "mujoco", "model": "m", "cell_skills": json.dumps({"a1/flat/weak_motors": 0.4}),
                            "cell_gains": json.dumps({"a1/flat/weak_motors": [0.1, 0.05, 0.15]})}])
    weak = probe_screen(probes, {"sim": "mujoco", "robot": "a1", "terrain": "flat", "disturbance": "weak_motors"})
    assert weak == {"probe: m": "skill 0.40; gain +0.10 [+0.05, +0.15]"}
    assert probe_screen(probes, {"sim": "mujoco", "robot": "a1", "terrain": "flat", "disturbance": "none"}) == {}
    elsewhere = {"sim": "pybullet", "robot": "a1", "terrain": "flat", "disturbance": "weak_motors"}
    assert probe_screen(probes, elsewhere) == {}


def test_the_nwt_gain_pairs_seeds_where_success_cannot_move():
    """Both fall on every seed (success gain 0): the NWT gain still pairs each seed's walking fraction, only over the
    seeds both ran."""
    import pandas as pd

    from benchmark.experiments.report_matrix import paired_gain

    model = pd.DataFrame({"seed": [0, 1, 2, 3], "success": [False] * 4, "nwt": [0.10, 0.06, 0.51, 0.90]})
    trivial = pd.DataFrame({"seed": [0, 1, 2], "success": [False] * 3, "nwt": [0.05, 0.06, 0.20]})
    rng = np.random.default_rng(0)
    assert paired_gain(model, trivial, rng)[:1] + paired_gain(model, trivial, rng)[3:] == (0.0, 3)
    gain, low, high, n = paired_gain(model, trivial, rng, "nwt")
    assert n == 3 and gain == pytest.approx((0.05 + 0.0 + 0.31) / 3) and 0.0 <= low <= gain <= high <= 0.31


def test_each_model_is_paired_with_the_trivial_answers_of_its_own_examples():
    """A cell with the walking prompt's references, the recent3 prompt's and three model rows: the nearest-only and
    told rows (one more sentence, the same examples) pair with the better of `knn`/`hold` on nearest-only, the recent3
    row with the better of its own prompt's (here `hold_recent3`, 2 of 2, where nearest-only's copying walks 1 of 2);
    the hard track reads the walking prompt's alone."""
    import pandas as pd

    from benchmark.experiments.report_matrix import cell_rows, is_hard_cell, same_prompt_trivial

    only, recent = dict(prompt_strategy="nearest-only", history=50), dict(prompt_strategy="nearest", history=3)
    rows = {"oracle": ("oracle", only, [True, True]), "knn_nearest_only": ("knn", only, [True, False]),
            "hold_nearest_only": ("hold", only, [False, False]),
            "knn_chronological": ("knn", dict(prompt_strategy="chronological", history=50), [True, True]),
            "knn_recent3": ("knn", recent, [False, False]), "hold_recent3": ("hold", recent, [True, True]),
            "qwen15_nearest_only": ("qwen2.5-coder-1.5b", only, [False, False]),
            "qwen15_told": ("qwen2.5-coder-1.5b", {**only, "tell_disturbance": True}, [False, True]),
            "qwen15_recent3": ("qwen2.5-coder-1.5b", recent, [True, False])}
    trials = pd.DataFrame([{"sim": "mujoco", "robot": "a1", "terrain": "flat", "disturbance": "weak_motors",
                            "controller": name, "model": model, "seed": seed, "success": ok, "nwt": float(ok),
                            "retrieve_k": 3, "memory": "demonstrations", "distance": "l2", "encoding": "E5",
                            "observation": "O5", **prompt}
                           for name, (model, prompt, wins) in rows.items() for seed, ok in enumerate(wins)])
    by = cell_rows(trials).set_index("controller")
    assert same_prompt_trivial(by, "qwen15_nearest_only").name == "knn_nearest_only"
    assert same_prompt_trivial(by, "qwen15_told").name == "knn_nearest_only"
    assert same_prompt_trivial(by, "qwen15_recent3").name == "hold_recent3"
    assert same_prompt_trivial(by.drop(["knn_recent3", "hold_recent3"]), "qwen15_recent3") is None
    assert is_hard_cell(by)  # nearest-only's copying 1 of 2 (< 0.6); hold_recent3 and knn_chronological walking
    assert not is_hard_cell(by.drop("hold_nearest_only").assign(successes=by["n"]))  # do not count; all walking does


def test_a_cell_replayed_from_the_reply_cache_does_not_read_as_fast():
    """Trials an hour count every cached reply at the live latency: a resumed trial (98 of 100 replies cached) costs
    what a live one does, and a cell whose every reply came from the cache reads the latency recorded when its
    replies were made, marked as replayed."""
    import pandas as pd

    from benchmark.experiments.report_matrix import cell_speed

    live = pd.DataFrame({"latency_mean_s": [10.0, 10.0], "queries": [100, 100], "cache_hits": [0, 98],
                         "trial_wall_s": [1010.0, 30.0], "latency_recorded_mean_s": [10.0, 10.0]})
    speed = cell_speed(live)
    assert speed["s_query"] == 10.0 and not speed["replayed"]
    assert speed["trial_s"] == pytest.approx((1010.0 + 30.0 + 980.0) / 2)  # the median of two: their mean
    replayed = pd.DataFrame({"latency_mean_s": [0.0, 0.0], "queries": [100, 100], "cache_hits": [100, 100],
                             "trial_wall_s": [12.0, 14.0], "latency_recorded_mean_s": [9.0, 11.0]})
    speed = cell_speed(replayed)
    assert speed["replayed"] and speed["s_query"] == 10.0 and speed["trial_s"] == pytest.approx(1013.0)
    old = replayed.drop(columns="latency_recorded_mean_s")  # a store from before the column: no speed, not a fast one
    assert np.isnan(cell_speed(old)["s_query"]) and cell_speed(old)["trial_s"] == pytest.approx(13.0)


def test_a_latency_measured_beside_other_work_is_marked_shared():
    """A live trial that ended with the load above its cores (other work ran beside it) marks its cell's speed;
    a trial alone, a replayed one (no live query) or one stored before the core count was recorded does not."""
    import pandas as pd

    from benchmark.common.tables import shared_machine
    from benchmark.experiments.report_matrix import cell_speed

    alone = pd.DataFrame({"latency_mean_s": [12.0, 12.5], "queries": [100, 100], "load_1m": [2.0, 2.1],
                          "cores": [2, 2], "trial_wall_s": [1200.0, 1250.0]})
    assert shared_machine(alone) == "" and cell_speed(alone)["shared"] == ""
    beside = alone.assign(load_1m=[2.0, 3.9])
    assert shared_machine(beside) == " (shared: load 3.9 on 2 cores)" == cell_speed(beside)["shared"]
    assert shared_machine(beside.assign(latency_mean_s=[0.0, 0.0])) == ""  # replayed: no latency measured here
    assert shared_machine(beside.drop(columns="cores")) == ""
    # judged on the load through the trial where it was recorded: a spike at the end is not a shared trial, and a
    # trial that shared the cores throughout is one even if the load had dropped when it ended
    spike = alone.assign(load_1m=[2.0, 3.9], load_1m_mean=[2.0, 2.2])
    assert shared_machine(spike) == ""
    throughout = alone.assign(load_1m_mean=[2.1, 3.0])
    assert shared_machine(throughout) == " (shared: mean load 3.0 on 2 cores)" == cell_speed(throughout)["shared"]


def test_the_told_prompt_says_its_cells_disturbance_in_the_closed_loop_and_the_probe_alike():
    """`tell_disturbance` (the hard track's `qwen15_told`): the description gains the cell's own `told` sentence, in a
    closed-loop trial (MuJoCo A1 with weak motors, on `hold`, 1 s of queries) and in the probe's A1 and ANYmal walks
    (each its own disturbance); the examples below it are nearest-only's to the character, so its trivial answers are
    nearest-only's; under disturbance none there is nothing to tell."""
    from benchmark.evaluate.probe import ProbeRun, answer_items, load_probe_set
    from benchmark.evaluate.study import probe_jobs
    from benchmark.experiments.experiment import load_experiment
    from benchmark.llm.prompt import split_prompt
    from benchmark.trial.trials import KeepPolicy
    from conftest import RecordingHold

    experiment = load_experiment("hard_track")
    only = {"sim": "mujoco", "robot": "a1", "disturbance": "weak_motors"}

    def loop_prompt(controller: str, **change) -> str:
        cell = experiment.trials(only={**only, "controller": controller})[0].cell
        settings = dataclasses.replace(cell.settings, model="hold", seed_start=0.5, llm_after=3.0)
        keep = KeepPolicy()
        run_cell(dataclasses.replace(cell, duration=4.0, settings=settings, **change), [0], hooks=[keep])
        return keep.policy.last_prompt

    told, plain = loop_prompt("qwen15_told"), loop_prompt("qwen15_nearest_only")
    weak = DISTURBANCES["weak_motors"].told
    assert weak and weak not in plain and split_prompt(told)[0] == split_prompt(plain)[0] + "\n\n" + weak
    assert split_prompt(told)[1] == split_prompt(plain)[1]  # the same examples and input: the same trivial answers
    assert loop_prompt("qwen15_told", disturbance="none") == loop_prompt("qwen15_nearest_only", disturbance="none")

    job = next(j for j in probe_jobs(experiment) if j.labels["sim"] == "mujoco" and j.llm.tell_disturbance)
    def probe_prompt(cell: str) -> str:  # the first item of the cell's first walk
        model = RecordingHold()
        answer_items(load_probe_set(job.probe_path), ProbeRun(llm=dataclasses.replace(job.llm, model="hold"),
                                                              window=job.window, items=1, cells=(cell,)), model=model)
        return model.prompts[0]

    a1, anymal = probe_prompt("a1/flat/weak_motors"), probe_prompt("anymal/flat/weaker_motors")
    assert split_prompt(a1)[0] == split_prompt(told)[0]  # the closed loop's description, word for word
    assert DISTURBANCES["weaker_motors"].told in anymal and weak not in anymal
