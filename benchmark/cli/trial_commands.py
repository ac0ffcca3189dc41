"""`bench run`, `view`, `prompt` and `list`: trials of one cell, their recordings and prompts."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

from tqdm import tqdm

from benchmark.cli.options import CliError
from benchmark.common.interrupt import Interrupted, Interruption
from benchmark.common.settings import build
from benchmark.llm.controller import takeover_prompt
from benchmark.llm.progress import RecentRate
from benchmark.trial.cell import CellSpec, make_cell
from benchmark.trial.resources import Resources, Runtime, SharedModels
from benchmark.trial.runner import TrialResult, summarize
from benchmark.trial.trials import TrialHooks, run_cell, run_side_by_side
from benchmark.trial.video import TrackHook, VideoConfig, check_video_path, clip_path, render_clip, track_labels


class _Collect(TrialHooks):
    """Finished trials, kept as they finish (an error later keeps them)."""

    def __init__(self) -> None:
        self.results: list[TrialResult] = []
        self.on_end = lambda result: None

    def end(self, seed, result) -> None:
        self.results.append(result)
        self.on_end(result)


class _QueryBar(TrialHooks):
    """Per trial, a bar over the LLM queries with the latest latency and an ETA; when stderr is not a
    terminal (nohup, CI, a pipe), a progress line every `every_s` seconds instead."""

    def __init__(self, every_s: float = 30.0) -> None:
        self.every_s = every_s

    def start(self, seed, sim, policy, episode):
        queries = getattr(policy, "queries", None)
        if queries is None:
            return None
        import time

        total = int(round((episode.duration - episode.eval_start) / sim.physics.control_dt))
        bar = self.bar = tqdm(total=total, desc=f"seed {seed}: LLM queries", unit="query", file=sys.stderr,
                              disable=None, leave=False)
        last_line, recent = [time.monotonic()], RecentRate()

        def update(loop) -> None:
            done = len(policy.queries)
            if done == bar.n:
                return
            latency = policy.queries[-1].reply.latency_s
            bar.set_postfix_str(f"{latency:.2f} s/query", refresh=False)
            bar.update(done - bar.n)
            now = time.monotonic()
            recent.add(done, now)
            if bar.disable and (now - last_line[0] >= self.every_s or done == total):
                last_line[0] = now
                eta = recent.eta(total - done)
                print(f"bench: seed {seed}: {done}/{total} LLM queries, last {latency:.2f} s, ETA "
                      + (f"{eta:.0f} s for this trial (recent rate)" if eta is not None else "after the next query"),
                      file=sys.stderr, flush=True)

        return update

    def end(self, seed, result) -> None:
        if getattr(self, "bar", None) is not None:
            self.bar.close()


def trial_params(cell: CellSpec, seed: int) -> dict:
    """A trial's cell parameters with its seed and takeover time: a recording's meta, a clip's labels."""
    return {**cell.params(), "seed": seed, "eval_start": cell.eval_start}


class _Record(TrialHooks):
    """One Rerun recording per trial, into a folder (`--record-dir`) or merged into one file at the end."""

    def __init__(self, cell: CellSpec, folder: Path) -> None:
        self.cell, self.folder, self.written = cell, folder, []
        self.recorders: dict = {}  # seed -> its recorder (trials may run side by side)

    def start(self, seed, sim, policy, episode):
        from benchmark.trial.recorder import Recorder

        c = self.cell
        name = f"{c.sim}-{Path(c.robot).name}-{c.terrain}-{c.policy}-seed{seed}"
        self.recorders[seed] = Recorder(self.folder / f"{name}.rrd", sim.robot, sim.terrain, sim, policy, name,
                                        trial_params(c, seed))
        return self.recorders[seed].on_step

    def end(self, seed, result) -> None:
        self.written.append(self.recorders.pop(seed).write(result))


class _Video(TrialHooks):
    """One clip per trial, drawn when the trial ends from the states of its control steps."""

    def __init__(self, cell: CellSpec, path: Path, config: VideoConfig, many: bool) -> None:
        self.cell, self.path, self.config, self.many, self.written = cell, path, config, many, []
        self.tracks: dict = {}  # seed -> (its state collector, its engine) (trials may run side by side)

    def start(self, seed, sim, policy, episode):
        self.tracks[seed] = (TrackHook(), sim)
        return self.tracks[seed][0].on_step

    def end(self, seed, result) -> None:
        hook, sim = self.tracks.pop(seed)
        track = hook.track(**track_labels(trial_params(self.cell, seed), sim.robot, result.fall_time))
        out = clip_path(self.path, seed, self.many)
        self.written.append(render_clip(track, sim.robot, sim.terrain, out, self.config))


def cmd_run(args, values: dict, runtime: Runtime, video: dict | None = None) -> int:
    import tempfile

    from benchmark.trial.recorder import merge_recordings, rerun_command

    from benchmark.llm.models import require_models

    cell = make_cell(values, where="bench run")
    require_models([model] if (model := getattr(cell.settings, "model", None)) else [])  # assembled, before running
    collect = _Collect()
    hooks = [collect, _QueryBar()]
    parts = tempfile.TemporaryDirectory(prefix="promptwalk-rec-") if args.record else None
    record = None
    if args.record or args.record_dir:
        if args.record:
            rerun_command()  # fail before running, not after
        record = _Record(cell, Path(args.record_dir) if args.record_dir else Path(parts.name))
        hooks.append(record)
    clips = None
    if args.video:
        check_video_path(Path(args.video))
        clips = _Video(cell, Path(args.video), build(VideoConfig, video or {}, "bench run"), args.trials > 1)
        hooks.append(clips)
    seeds = range(args.seed, args.seed + args.trials)
    trials_bar = tqdm(total=args.trials, desc=cell.label(), unit="trial", file=sys.stderr, disable=None)
    collect.on_end = lambda result: trials_bar.update()
    error, interrupted = None, False
    concurrency = min(args.concurrency, args.trials)
    shared = SharedModels() if concurrency > 1 else None
    resources = Resources(runtime if shared is None else dataclasses.replace(runtime, slots=concurrency), shared)
    try:
        with Interruption(what="trial in flight" if shared is None else "trials in flight") as stop:
            hooks.append(_StopBetweenTrials(stop))
            if shared is None:
                run_cell(cell, seeds, resources, hooks=hooks)
            else:
                run_side_by_side(cell, list(seeds), resources, hooks, concurrency)
    except (OSError, RuntimeError) as err:  # keep what finished: report it, then the error
        error = err
    except (Interrupted, KeyboardInterrupt):
        interrupted = True
    finally:
        trials_bar.close()
        resources.close()
        if shared is not None:
            shared.close()
    trials = sorted(collect.results, key=lambda t: t.seed)
    if error is not None and not trials:
        print(f"bench: error: {error}", file=sys.stderr)
        return 1
    if interrupted and not trials:
        print("bench: interrupted before any trial finished", file=sys.stderr)
        return 130
    result = {**cell.params(), "eval_start": cell.eval_start, "seed": args.seed,
              "trials": [t.to_dict() for t in trials], **summarize(trials)}
    if args.json:
        print(json.dumps(result))
    else:
        print_run_table(cell, result)
    if args.record and trials:
        merge_recordings(record.written, Path(args.record))
        parts.cleanup()
        print(f"recording: {args.record} ({len(trials)} trial(s), one recording per seed); open with "
              f"'bench view {args.record}'", file=sys.stderr)
    if clips is not None and clips.written:
        print(f"clip{'s' if len(clips.written) > 1 else ''}: {', '.join(map(str, clips.written))}", file=sys.stderr)
    if error is not None:
        print(f"bench: error: {error} ({len(trials)} finished trial(s) reported above)", file=sys.stderr)
        return 1
    if interrupted:
        print(f"bench: interrupted: {len(trials)} finished trial(s) reported above", file=sys.stderr)
        return 130
    return 0


class _StopBetweenTrials(TrialHooks):
    """After the first Ctrl-C, no new trial starts."""

    def __init__(self, stop: Interruption) -> None:
        self.stop = stop

    def start(self, seed, sim, policy, episode):
        if self.stop.requested:
            raise Interrupted


def _fraction(value: float | None) -> str:
    """A fraction to two decimals; '-' where it was not measured (a trial ended at its stop)."""
    return "-" if value is None else f"{value:.2f}"


def _measured(trials: list[dict]) -> str:
    """' (of k trials)' when some trials ended at their stop, so upright was measured on the others only."""
    k = sum(t["upright_fraction"] is not None for t in trials)
    return "" if k == len(trials) else f" (of the {k} trials not ended at their stop)"


def print_run_table(cell: CellSpec, result: dict) -> None:
    mode = getattr(cell.settings, "history_mode", None)
    print(f"{cell.policy} on {cell.robot} / {cell.sim} / {cell.terrain}, {len(result['trials'])} x "
          f"{cell.duration:g} s" + (f" (metrics from {cell.eval_start:g} s)" if cell.eval_start else "")
          + (f", history mode {mode}" + (" (APPROXIMATE: KV-cache shifting)" if cell.settings.approximate else "")
             if mode else ""))
    print(f"{'seed':>4} {'nwt':>5} {'ok':>3} {'upright':>7} {'dist m':>7} {'vx m/s':>7} {'drift m':>8} "
          f"{'yaw rad':>7}  end")
    for t in result["trials"]:
        end = (f"fell at {t['fall_time']:.1f} s: {t['fall_reason']}" if t["fall_time"] is not None
               else f"stopped walking at {t['stop_time']:.1f} s" if t["stop_time"] is not None else "-")
        end += " (trial ended there: --end-at-stop)" if t.get("ended_at_stop") else ""
        print(f"{t['seed']:>4} {t['nwt']:>5.2f} {'yes' if t['success'] else 'no':>3} {_fraction(t['upright_fraction']):>7} "
              f"{t['distance_m']:>7.2f} {t['mean_vx']:>7.2f} {t['lateral_drift_m']:>8.2f} "
              f"{t['heading_change_rad']:>7.2f}  {end}")
    print(f"mean NWT {result['nwt']:.3f}, success rate {result['success_rate']:.2f}, "
          f"upright {_fraction(result['upright_fraction'])}{_measured(result['trials'])}, distance {result['distance_m']:.2f} m, vx {result['mean_vx']:.2f} m/s")
    llm_trials = [t for t in result["trials"] if t.get("queries")]
    if llm_trials:
        print(f"{'seed':>4} {'queries':>7} {'cached':>6} {'unparsed':>8} {'tokens in/out':>14} {'gpt-4 in/out':>13} "
              f"{'latency s':>10} {'p95 s':>6} {'RTF':>6}")
        for t in llm_trials:
            live = t["queries"] - t["cache_hits"]
            rtf = f"{t['realtime_factor']:.3f}" if live and t.get("realtime_factor") else "-"
            latency = f"{t['latency_mean_s']:>10.2f} {t['latency_p95_s']:>6.2f}" if live else f"{'-':>10} {'-':>6}"
            print(f"{t['seed']:>4} {t['queries']:>7} {t['cache_hits']:>6} {t['parse_failures']:>8} "
                  f"{t['input_tokens']:>8.0f}/{t['output_tokens']:<5.0f} "
                  f"{t['gpt4_input_tokens']:>7.0f}/{t['gpt4_output_tokens']:<5.0f} {latency} {rtf:>6}")
        if any(t["cache_hits"] for t in llm_trials):
            print("cached replies come from the on-disk cache (--no-cache to query live); latency and RTF count "
                  "live queries only")


def cmd_render(args, video: dict) -> int:
    """Clips of a recording's trials, drawn from the states it holds."""
    from benchmark.trial.recorder import read_tracks
    from robots import load_robot
    from sims.terrain import Terrain

    if not Path(args.path).is_file():
        raise CliError(f"recording '{args.path}' not found")
    out = Path(args.out)
    check_video_path(out)
    config = build(VideoConfig, video, "bench render")
    tracks = read_tracks(Path(args.path))
    if args.recording is not None:
        names = [t.meta.get("name") for t in tracks]
        tracks = [t for t in tracks if t.meta.get("name") == args.recording]
        if not tracks:
            raise CliError(f"no recording '{args.recording}' in {args.path}; it holds: {', '.join(map(str, names))}")
    for track in tracks:
        meta = track.meta
        robot = load_robot(meta["robot"])
        terrain = Terrain(meta["terrain"], seed=int(meta.get("terrain_seed", 0)))
        path = clip_path(out, meta.get("seed", 0), len(tracks) > 1)
        render_clip(track, robot, terrain, path, config)
        print(f"clip: {path} ({meta.get('name')}, {len(track.times)} control steps)", file=sys.stderr)
    return 0


def cmd_view(args) -> int:
    if not Path(args.path).is_file():
        raise CliError(f"recording '{args.path}' not found")
    from benchmark.trial.recorder import rerun_command

    try:
        viewer = rerun_command()
    except FileNotFoundError as err:
        raise CliError(str(err)) from None
    if args.web:
        import ipaddress

        try:
            address = ipaddress.ip_address(args.bind)
        except ValueError:
            raise CliError(f"--bind: '{args.bind}' is not an IP address (e.g. 127.0.0.1, ::1 or 0.0.0.0)") from None
        grpc = args.port + 1
        host = "localhost" if address.is_loopback or address.is_unspecified else \
            (f"[{args.bind}]" if address.version == 6 else args.bind)
        reach = ("this machine only: forward ports " if address.is_loopback else "every host that can reach it: ports ")
        print(f"serving {args.path} in Rerun's web viewer on {args.bind} ({reach}{args.port} and {grpc}); open "
              f"http://{host}:{args.port}/?url=rerun%2Bhttp%3A%2F%2F{host}%3A{grpc}%2Fproxy (Ctrl-C stops)",
              file=sys.stderr, flush=True)
        return _run_child([viewer, "--serve-web", "--bind", args.bind, "--web-viewer-port", str(args.port),
                           "--port", str(grpc), args.path])
    return _run_child([viewer, args.path])


def _run_child(command: list[str]) -> int:
    """Run the viewer in a process group of its own (rerun-sdk's `rerun` is a wrapper that starts the real
    binary); Ctrl-C, SIGTERM or SIGHUP (a closed terminal) ends the whole group, so no viewer outlives
    `bench view`."""
    import signal

    from benchmark.common.interrupt import TERMINATING

    def stop(signum, frame):
        raise KeyboardInterrupt

    for signum in TERMINATING:
        signal.signal(signum, stop)
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        return child.wait()
    except KeyboardInterrupt:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(child.pid, sig)
                child.wait(timeout=5)
                break
            except subprocess.TimeoutExpired:
                continue
            except ProcessLookupError:
                break
        return 130


def cmd_prompt(args, values: dict, runtime: Runtime) -> int:
    """The prompt at the takeover of a real trial (nothing is queried) and its length in tokens."""
    from benchmark.llm.tokens import gpt4_tokens, server_tokens

    base = make_cell({**values, "policy": "llm"}, where="bench prompt")
    s = base.settings
    text = takeover_prompt(base, args.seed)
    if args.tokenizer == "gpt-4":
        tokens = gpt4_tokens(text)
    else:
        from benchmark.llm.models import EmbeddedModel

        model = EmbeddedModel(s.model.partition(":")[2] or None, threads=runtime.threads)
        tokens = server_tokens(model.url, text)
        model.close()
    if args.json:
        print(json.dumps({"robot": base.robot, "history": s.history, "encoding": s.encoding,
                          "observation": s.observation, "prompt_parts": list(s.prompt_parts),
                          "tokenizer": args.tokenizer, "tokens": tokens, "prompt": text}))
    else:
        print(text)
        print(f"\n[{tokens} tokens ({args.tokenizer}), history {s.history}, encoding {s.encoding}]", file=sys.stderr)
    return 0


def cmd_list(args) -> int:
    from benchmark.llm.models import model_forms
    from benchmark.trial.registry import available_policies
    from robots import available_robots
    from sims import available_sims
    from sims.terrain import TERRAINS

    listing = {"sims": available_sims(), "robots": available_robots(), "terrains": list(TERRAINS),
               "policies": available_policies(), "models": model_forms()}
    if args.json:
        print(json.dumps(listing))
    else:
        for key, names in listing.items():
            print(f"{key:9} {', '.join(names)}")
    return 0
