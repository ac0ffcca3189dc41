"""What each `bench` command does, once its options are parsed (`benchmark/cli.py` parses)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from tqdm import tqdm

from benchmark.cell import CellSpec, Resources, Runtime, TrialHooks, make_cell, run_cell
from benchmark.interrupt import Interrupted, Interruption
from benchmark.llm.progress import RecentRate
from benchmark.llm.controller import takeover_prompt
from benchmark.runner import TrialResult, summarize
from benchmark.settings import SettingError, build


class CliError(SettingError):
    """A user mistake: reported as one line, exit code 2."""


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


class _Record(TrialHooks):
    """One Rerun recording per trial, into a folder (`--record-dir`) or merged into one file at the end."""

    def __init__(self, cell: CellSpec, folder: Path) -> None:
        self.cell, self.folder, self.written = cell, folder, []

    def start(self, seed, sim, policy, episode):
        from benchmark.recorder import Recorder

        c = self.cell
        name = f"{c.sim}-{Path(c.robot).name}-{c.terrain}-{c.policy}-seed{seed}"
        self.recorder = Recorder(self.folder / f"{name}.rrd", sim.robot, sim.terrain, sim, policy, name)
        return self.recorder.on_step

    def end(self, seed, result) -> None:
        self.written.append(self.recorder.write(result))


def cmd_run(args, values: dict, runtime: Runtime) -> int:
    import tempfile

    from benchmark.recorder import merge_recordings, rerun_command

    cell = make_cell(values, where="bench run")
    collect = _Collect()
    hooks = [collect, _QueryBar()]
    parts = tempfile.TemporaryDirectory(prefix="promptwalk-rec-") if args.record else None
    record = None
    if args.record or args.record_dir:
        if args.record:
            rerun_command()  # fail before running, not after
        record = _Record(cell, Path(args.record_dir) if args.record_dir else Path(parts.name))
        hooks.append(record)
    seeds = range(args.seed, args.seed + args.trials)
    trials_bar = tqdm(total=args.trials, desc=cell.label(), unit="trial", file=sys.stderr, disable=None)
    collect.on_end = lambda result: trials_bar.update()
    error, interrupted, resources = None, False, Resources(runtime)
    try:
        with Interruption(what="trial in flight") as stop:
            hooks.append(_StopBetweenTrials(stop))
            run_cell(cell, seeds, resources, hooks=hooks)
    except (OSError, RuntimeError) as err:  # keep what finished: report it, then the error
        error = err
    except (Interrupted, KeyboardInterrupt):
        interrupted = True
    finally:
        trials_bar.close()
        resources.close()
    trials = collect.results
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
        print(f"{t['seed']:>4} {t['nwt']:>5.2f} {'yes' if t['success'] else 'no':>3} {t['upright_fraction']:>7.2f} "
              f"{t['distance_m']:>7.2f} {t['mean_vx']:>7.2f} {t['lateral_drift_m']:>8.2f} "
              f"{t['heading_change_rad']:>7.2f}  {end}")
    print(f"mean NWT {result['nwt']:.3f}, success rate {result['success_rate']:.2f}, "
          f"upright {result['upright_fraction']:.2f}, distance {result['distance_m']:.2f} m, vx {result['mean_vx']:.2f} m/s")
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


def cmd_sweep(args, overrides_text: list[str], only_text: list[str]) -> int:
    import importlib.util

    from benchmark.experiment import available_experiments, load_experiment, parse_overrides
    from benchmark.llm.models import LLMError
    from benchmark.store import ResultStore
    from benchmark.sweep import TrialError, run_sweep

    if args.list or args.experiment is None:
        if args.experiment is None and not args.list:
            raise CliError(f"name an experiment: {', '.join(available_experiments())} (or a path to a .toml)")
        for name in available_experiments():
            exp = load_experiment(name)
            print(f"{name:<14} {len(exp.trials()):>4} trials  {exp.title}")
        return 0
    experiment = load_experiment(args.experiment)
    overrides = parse_overrides(overrides_text)
    trials = experiment.trials(overrides, key_values(only_text, "--only", "KEY=VALUE"))
    if args.executor == "ray" and importlib.util.find_spec("ray") is None:
        raise CliError("--executor ray needs Ray: pip install -e '.[ray]'")
    if not trials:
        raise CliError(f"no cell of '{experiment.name}' matches --only {' '.join(only_text)}")
    if args.seeds is not None:
        trials = [t for t in trials if t.seed in experiment.seeds[:args.seeds]]
    root = Path(args.results or f"results/{experiment.name}")
    if root.exists() and not root.is_dir():
        raise CliError(f"--results '{root}' is a file; give a directory (the store holds one file per trial)")
    store = ResultStore(root)
    if args.dry_run:
        from benchmark.sweep import stale_trials

        done = store.done_ids() - stale_trials(store)  # a trial of another seed policy runs again
        cells: dict[str, list] = {}
        for t in trials:
            cells.setdefault(t.cell_id, []).append(t)
        print(f"{experiment.name}: {len(cells)} cells, {len(trials)} trials, "
              f"{sum(t.id not in done for t in trials)} missing in {store.root}")
        for group in cells.values():
            t = group[0]
            params = {**t.cell.params(), **t.labels}
            shown = {k: params[k] for k in [*experiment.axes, *overrides] if k in params}
            print(f"  {t.cell_id}  {t.cell.label():<32} {json.dumps(shown)}  seeds {[x.seed for x in group]}"
                  f"  missing {sum(x.id not in done for x in group)}")
        if args.price_in is not None and args.price_out is not None:
            _print_cost(cells, args)
        return 0
    try:
        outcome = run_sweep(trials, store, workers=args.workers, executor=args.executor, address=args.ray_address,
                            requests_per_minute=args.rate_limit, threads=args.threads,
                            command=" ".join(["bench", *args.argv]), concurrency=args.concurrency)
    except (TrialError, LLMError) as err:
        print(f"bench: error: {err} ({len(store.done_ids())} trial(s) stored in {store.root}; "
              "run the same command again to resume)", file=sys.stderr)
        return 1
    except Interrupted:
        print(f"bench: interrupted: {len(store.done_ids())} trial(s) stored in {store.root}; "
              "run the same command again to resume", file=sys.stderr)
        return 130
    print(f"{experiment.name}: {outcome.ran} trial(s) run, {outcome.skipped} already stored, "
          f"{outcome.total} in the grid; {outcome.wall_s:.1f} s with {args.workers} {args.executor} worker(s); "
          f"results in {store.root}")
    return 0


def _print_cost(cells: dict, args) -> None:
    """The estimated bill of the LLM cells (server models only), per history mode."""
    from benchmark.llm.cost import MODES, estimate

    llm = [(g[0].cell, len(g)) for g in cells.values()
           if g[0].cell.policy == "llm" and g[0].cell.settings.model.startswith("openai")]
    if not llm:
        print("cost: no cell queries a server model (set model=openai:MODEL)")
        return
    print(f"estimated cost (GPT-4 tokens of real prompts, no trial ending early; cached: prefixes of >= 1024 "
          f"tokens at ${args.price_cached_in if args.price_cached_in is not None else args.price_in}/1M):")
    print(f"  {'history mode':<13} {'queries':>8} {'input tokens':>13} {'cached':>12} {'output':>10} {'USD':>9}")
    for mode in MODES:
        e = estimate([c for c, _ in llm], [n for _, n in llm], mode, args.price_in, args.price_out,
                     args.price_cached_in)
        print(f"  {mode:<13} {e['queries']:>8,} {e['input_tokens']:>13,} {e['cached_input_tokens']:>12,} "
              f"{e['output_tokens']:>10,} {e['usd']:>9,.2f}")


def key_values(items: list[str], option: str, form: str) -> dict[str, str]:
    """`KEY=VALUE` words of an option as a dict; anything else is a one-line error."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise CliError(f"{option} expects {form}, got '{item}'")
        out[key] = value
    return out


def cmd_report(args) -> int:
    from benchmark.report import write_reports
    from benchmark.store import load_results

    try:
        frame = load_results(args.results)
    except FileNotFoundError as err:
        raise CliError(str(err)) from None
    if frame.empty:
        raise CliError(f"'{args.results}' holds no trials yet; run 'bench sweep' into it first")
    from benchmark.report import ReportConflict

    print(f"writing reports into {Path(args.out).resolve()}", file=sys.stderr)
    try:
        written = write_reports(frame, Path(args.out), args.format, force=args.force)
    except ReportConflict as err:
        raise CliError(str(err)) from None
    for path in written:
        print(path)
    return 0


def cmd_view(args) -> int:
    if not Path(args.path).is_file():
        raise CliError(f"recording '{args.path}' not found")
    from benchmark.recorder import rerun_command

    try:
        viewer = rerun_command()
    except FileNotFoundError as err:
        raise CliError(str(err)) from None
    if args.web:
        grpc = args.port + 1
        print(f"serving {args.path} in Rerun's web viewer: open http://localhost:{args.port}/?url=rerun%2Bhttp"
              f"%3A%2F%2Flocalhost%3A{grpc}%2Fproxy (forward ports {args.port} and {grpc}; Ctrl-C stops)",
              file=sys.stderr, flush=True)
        return _run_child([viewer, "--serve-web", "--web-viewer-port", str(args.port), "--port", str(grpc),
                           args.path])
    return _run_child([viewer, args.path])


def _run_child(command: list[str]) -> int:
    """Run the viewer in a process group of its own (rerun-sdk's `rerun` is a wrapper that starts the real
    binary); Ctrl-C, SIGTERM or SIGHUP (a closed terminal) ends the whole group, so no viewer outlives
    `bench view`."""
    import os
    import signal

    from benchmark.interrupt import TERMINATING

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


def cmd_train(values: dict, rewards: dict, ppo: dict | None = None) -> int:
    from benchmark.train import TrainConfig, ppo_settings, reward_weights, train
    from robots import load_robot
    from sims import engine

    config = build(TrainConfig, {**values, "rewards": reward_weights(rewards), "ppo": ppo_settings(ppo)},
                   where="bench train")
    load_robot(config.robot)
    for sim in config.sim:
        engine(sim)
    if not 0.0 <= config.rough_share <= 1.0:
        raise CliError(f"--rough-share must be between 0 and 1, got {config.rough_share}")
    if config.init_from and not Path(config.init_from).is_file():
        raise CliError(f"--init-from '{config.init_from}' not found; give a policy.npz written by bench train")
    with Interruption(grace_s=30.0, what="training (it saves and evaluates the policy so far)") as stop:
        try:
            path = train(config, stop=lambda: stop.requested, command=_as_typed("train"))
        except KeyboardInterrupt:
            print(f"bench: interrupted: the last periodic policy is in {config.out_dir}", file=sys.stderr)
            return 130
    if stop.requested:
        print(f"bench: interrupted: policy so far written to {path}", file=sys.stderr)
        return 130
    print(f"policy written to {path}; log in {config.out_dir / 'train_log.csv'}; evaluate it with "
          f"'bench run --policy rl --robot {config.robot} --policy-file {path}'")
    return 0


def cmd_ship(args) -> int:
    from benchmark.train import ship_policy
    from robots import load_robot

    load_robot(args.robot)
    if not Path(args.path).is_file():
        raise CliError(f"'{args.path}' not found; give a policy.npz written by bench train")
    print(f"shipped {ship_policy(Path(args.path), args.robot)}")
    return 0


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


def cmd_latency(args, threads: int | None) -> int:
    from benchmark.llm.latency import measure
    from benchmark.llm.models import check_model_spec

    check_model_spec(args.llm)
    rows = measure(args.llm, args.histories, args.modes, args.queries, threads, args.llm_url, drift=not args.no_drift,
                   drafts=tuple(args.drafts))
    if args.json:
        print(json.dumps({"model": args.llm, "rows": rows}))
        return 0
    lines = [f"{args.llm}: query latency, {args.queries} queries per cell, reply cache off; drift: each reply "
             "against a cold recompute of the same prompt (identical fraction, mean |action difference|); "
             "outcome: the shifted trial against the exact sliding one; draft: speculative decoding (ngram or none), "
             "same as undrafted: replies equal to the undrafted cell's, query by query", "",
             "| history | mode | draft | prompt tokens | first (s) | mean (s) | p95 (s) | after the first (s) | "
             "identical to cold | mean abs action diff | outcome | same as undrafted |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        after = f"{r['latency_after_first_s']:.2f}" if r["latency_after_first_s"] is not None else "-"
        same = f"{r['identical_to_cold']:.2f}" if r.get("identical_to_cold") is not None else "-"
        diff = f"{r['action_diff_vs_cold']:.3f}" if r.get("action_diff_vs_cold") is not None else "-"
        changed = {True: "changed", False: "same"}.get(r.get("outcome_changed"), "-")
        mode = r["mode"] + (" (approximate)" if r["approximate"] else "")
        undrafted = f"{r['same_as_no_draft']:.2f}" if r.get("same_as_no_draft") is not None else "-"
        lines.append(f"| {r['history']} | {mode} | {r['draft']} | {r['prompt_tokens']:.0f} | {r['latency_first_s']:.2f} | "
                     f"{r['latency_mean_s']:.2f} | {r['latency_p95_s']:.2f} | {after} | {same} | {diff} | {changed} | "
                     f"{undrafted} |")
    print("\n".join(lines))
    if args.out:
        load, cores = os.getloadavg()[0], os.cpu_count()  # above the core count, other work shared the machine
        Path(args.out).write_text(f"# LLM latency and drift by history mode\n\nMade with `bench {' '.join(args.argv)}` "
                                  f"({threads or 'all'} threads; machine load {load:.1f} on {cores} cores as it "
                                  f"finished{', so other work shared the cores' if load > cores + 0.5 else ''}).\n\n"
                                  + "\n".join(lines) + "\n")
        print(f"written to {args.out}", file=sys.stderr)
    return 0


def cmd_list(args) -> int:
    from benchmark.llm.models import MODEL_FORMS
    from benchmark.policies import available_policies
    from robots import available_robots
    from sims import available_sims
    from sims.terrain import TERRAINS

    listing = {"sims": available_sims(), "robots": available_robots(), "terrains": list(TERRAINS),
               "policies": available_policies(), "models": list(MODEL_FORMS)}
    if args.json:
        print(json.dumps(listing))
    else:
        for key, names in listing.items():
            print(f"{key:9} {', '.join(names)}")
    return 0


def cmd_perf(args, values: dict) -> int:
    from benchmark.perf import measure, print_table

    result = measure(make_cell(values, where="bench perf"), args.steps, args.rounds, args.worlds)
    if args.json:
        print(json.dumps(result))
    else:
        print_table(result)
    return 0


def _as_typed(name: str) -> str:
    """The command line that ran `bench NAME`, to print in the report it writes."""
    return " ".join([f"bench {name}", *sys.argv[2:]]) if sys.argv[1:2] == [name] else f"bench {name}"


def cmd_validate(values: dict) -> int:
    from benchmark.validate import ValidateConfig, main

    path = main(build(ValidateConfig, values, where="bench validate"), _as_typed("validate"))
    print(f"wrote {path} and its figures")
    return 0


def cmd_gait(values: dict) -> int:
    from benchmark.gait import GaitConfig, main

    config = build(GaitConfig, values, where="bench gait")
    if config.policy_file and len(config.robot) != 1:
        raise CliError("--policy-file needs exactly one --robot (it was trained for one robot)")
    path = main(config, _as_typed("gait"))
    print(f"wrote {path} and its figures")
    return 0


def cmd_straight(values: dict) -> int:
    from benchmark.straight import StraightConfig, main

    config = build(StraightConfig, values, where="bench straight")
    if config.policy_file and len(config.robot) != 1:
        raise CliError("--policy-file needs exactly one --robot (it was trained for one robot)")
    path = main(config, _as_typed("straight"))
    print(f"wrote {path} and its figure")
    return 0


def cmd_probe(args, llm_values: dict, run_values: dict, runtime: Runtime) -> int:
    """`bench probe`: make the probe set, or score one model on it (a table, or --json)."""
    import dataclasses

    from benchmark.llm.controller import LLMSettings
    from benchmark.probe import (DEFAULT_PROBE, ProbeRun, load_probe_set, make_probe_set, print_progress,
                                 save_probe_set, summarize_answers, answer_items)

    if args.make:
        probe = make_probe_set(progress=lambda line: print(f"bench: {line}", file=sys.stderr, flush=True))
        path = save_probe_set(probe, Path(args.out) if args.out else DEFAULT_PROBE)
        print(f"wrote {path}: {len(probe.walks)} walks, {probe.items()} items, digest {probe.digest}")
        return 0
    probe = load_probe_set(args.probe or DEFAULT_PROBE)
    llm = build(LLMSettings, {"history": 10, **llm_values}, "bench probe")  # the probe's default history: 10
    run = build(ProbeRun, {k: v for k, v in run_values.items() if k != "llm"}, "bench probe")
    unknown = [c for c in (args.cells or []) if c not in probe.cells]
    if unknown:
        raise CliError(f"unknown probe cell '{unknown[0]}'; valid: {', '.join(probe.cells)}")
    run = dataclasses.replace(run, llm=llm, cells=tuple(args.cells) if args.cells else None)
    answers = answer_items(probe, run, runtime, progress=print_progress)
    summary = {"model": llm.model, "probe": probe.digest, "history": llm.history, "window": run.window,
               **summarize_answers(answers)}
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"probe {probe.digest}: {llm.model}, history {llm.history} ({run.window}), {llm.encoding}, "
          f"{llm.observation}: {summary['items']} items in {summary['wall_s']:.0f} s")
    print(f"{'cell':<14}{'items':>6}{'error':>8}{'skill':>8}{'within 1 step':>15}")
    for cell, c in summary["cells"].items():
        print(f"{cell:<14}{c['items']:>6}{c['error']:>8.3f}{c['skill']:>8.3f}{c['within_step']:>15.2f}")
    print(f"{'all':<14}{summary['items']:>6}{summary['error']:>8.3f}{summary['skill']:>8.3f}"
          f"{summary['within_step']:>15.2f}   skill 95% [{summary['skill_low']:.3f}, {summary['skill_high']:.3f}], "
          f"{summary['parse_failures']} parse failures, median {summary['latency_median_s']:.2f} s a query")
    return 0


def cmd_models(args) -> int:
    """`bench models`: the ladder, or --assemble one model's file."""
    from benchmark.llm import ladder

    if args.assemble:
        path = ladder.assemble(args.assemble)
        print(f"{args.assemble}: {path} ({path.stat().st_size:,} bytes, sha256 checked); use --llm {args.assemble}")
        return 0
    rows = ladder.status()
    if args.json:
        print(json.dumps(rows))
        return 0
    print(f"{'name':<20}{'params':>7}{'MB':>6}  {'present':<8} license / how to get it")
    for r in rows:
        print(f"{r['name']:<20}{r['parameters']:>7}{r['size_mb'] or '':>6}  {'yes' if r['present'] else 'no':<8} "
              f"{r['license']}; {r['install']}")
    print(f"model folder: {ladder.models_dir()}")
    return 0


def cmd_eval(args, llm_values: dict, runtime: Runtime) -> int:
    """`bench eval`: run (or find) one model's scorecard row, print it, refresh reports/leaderboard.md."""
    from benchmark.llm.controller import LLMSettings
    from benchmark.probe import DEFAULT_PROBE, load_probe_set
    from benchmark.scorecard import DEFAULT_SUITE, evaluate

    llm = build(LLMSettings, llm_values, "bench eval")
    if args.cells:
        cells = load_probe_set(args.probe or DEFAULT_PROBE).cells
        unknown = [c for c in args.cells if c not in cells]
        if unknown:
            raise CliError(f"unknown cell '{unknown[0]}'; valid: {', '.join(cells)}")
    command = "bench " + " ".join(args.argv)
    row = evaluate(llm, args.tier, args.suite or DEFAULT_SUITE, args.store, args.probe or DEFAULT_PROBE,
                   tuple(args.cells) if args.cells else None, runtime, command=command)
    p = row["probe"]
    print(f"scorecard {row['row_id']}: {row['model']} ({row['kind']}), {row['tier']} tier, probe {row['probe_digest']}")
    print(f"  probe: skill {p['skill']:.3f} [{p['skill_low']:.3f}, {p['skill_high']:.3f}], error {p['error']:.3f} "
          f"(hold {p['hold_error']:.3f}), within one step {p['within_step']:.2f}, {p['parse_failures']} parse "
          f"failures, {p['items']} items, median {p['latency_median_s']:.2f} s a query")
    for cell, c in p["cells"].items():
        print(f"    {cell:<14} skill {c['skill']:.3f}  error {c['error']:.3f}  within one step {c['within_step']:.2f}")
    for cell, c in (row.get("closed_loop") or {}).items():
        print(f"  closed loop {cell:<14} NWT {c['nwt']:.2f} ± {c['nwt_half_ci']:.2f}, success {c['success']:.2f}, "
              f"{c['distance_m']:.2f} m")
    print(f"  {row['wall_s']:.0f} s; stored in {args.store}/rows/{row['row_id']}.json")
    return 0


def cmd_leaderboard(args) -> int:
    from benchmark.leaderboard import write_leaderboard

    path, page = write_leaderboard(args.store, args.out, command="bench " + " ".join(args.argv))
    print(f"wrote {path}" + (f" and {page}" if page else ""))
    return 0
