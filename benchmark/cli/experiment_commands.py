"""`bench sweep` and `bench report`: experiment grids into a store, and reports from it."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from benchmark.cli.options import CliError, key_values
from benchmark.common.interrupt import Interrupted


def cmd_sweep(args, overrides_text: list[str], only_text: list[str]) -> int:
    import importlib.util

    from benchmark.common.store import ResultStore
    from benchmark.experiments.experiment import available_experiments, load_experiment, parse_overrides
    from benchmark.experiments.sweep import TrialError, run_sweep
    from benchmark.llm.models import LLMError

    if args.list or args.experiment is None:
        if args.experiment is None and not args.list:
            raise CliError(f"name an experiment: {', '.join(available_experiments())} (or a path to a .toml)")
        for name in available_experiments():
            exp = load_experiment(name)
            print(f"{name:<14} {len(exp.trials()):>4} trials  {exp.title}")
        return 0
    experiment = load_experiment(args.experiment)
    overrides = parse_overrides(overrides_text)
    only = key_values(only_text, "--only", "KEY=VALUE")
    jobs, trials = _stages(experiment, overrides, only, args.stage)
    if args.executor == "ray" and importlib.util.find_spec("ray") is None:
        raise CliError("--executor ray needs Ray: pip install -e '.[ray]'")
    if not trials and not jobs:
        raise CliError(f"no cell of '{experiment.name}' matches --only {' '.join(only_text)}"
                       + (f" in stage {args.stage}" if args.stage != "all" else ""))
    if args.seeds is not None:
        trials = [t for t in trials if t.seed in experiment.seeds[:args.seeds]]
    root = Path(args.results or f"results/{experiment.name}")
    if root.exists() and not root.is_dir():
        raise CliError(f"--results '{root}' is a file; give a directory (the store holds one file per trial)")
    store = ResultStore(root)
    if args.dry_run:
        from benchmark.experiments.sweep import stale_trials

        done = store.done_ids() - stale_trials(store)  # a trial of another seed policy runs again
        if jobs:
            print(f"{experiment.name} probe: {len(jobs)} runs, {sum(j.id not in done for j in jobs)} missing in "
                  f"{store.root}")
            for job in jobs:
                print(f"  {job.id[:12]}  {job.label():<44} history {job.llm.history} ({job.window}), "
                      f"{'+'.join(job.cells or ['all cells'])}  {'missing' if job.id not in done else 'stored'}")
        cells: dict[str, list] = {}
        for t in trials:
            cells.setdefault(t.cell_id, []).append(t)
        if trials or not jobs:
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
        from benchmark.trial.resources import Runtime

        if jobs:
            from benchmark.evaluate.probe import DEFAULT_PROBE
            from benchmark.evaluate.study import run_probe_stage

            ran, stored = run_probe_stage(jobs, store, Runtime(threads=args.threads), draft=experiment.probe.get("draft"),
                                          command=" ".join(["bench", *args.argv]),
                                          probe_path=experiment.probe_set or DEFAULT_PROBE)
            print(f"{experiment.name} probe: {ran} run(s), {stored} already stored; results in {store.root}")
        if not trials:
            return 0
        outcome = run_sweep(trials, store, workers=args.workers, executor=args.executor, address=args.ray_address,
                            requests_per_minute=args.rate_limit, threads=args.threads,
                            command=" ".join(["bench", *args.argv]), concurrency=args.concurrency,
                            runtime=Runtime(draft=args.draft, end_at_stop=args.end_at_stop))
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


def _stages(experiment, overrides: dict, only: dict, stage: str) -> tuple[list, list]:
    """(probe runs, closed-loop trials) of the stages asked for. An --only key is matched in each stage that has it;
    a stage that has none of a key's kind matches nothing (--only strategy=nearest picks probe runs alone)."""
    import dataclasses

    from benchmark.evaluate.study import probe_jobs
    from benchmark.experiments.experiment import ExperimentError
    from benchmark.llm.controller import LLMSettings
    from benchmark.trial.cell import setting_fields

    trial_keys = {*setting_fields(), *experiment.grid}
    probe_keys = {*(f.name for f in dataclasses.fields(LLMSettings)), *experiment.probe.get("grid", {})} \
        if experiment.probe else set()
    unknown = [k for k in only if k not in trial_keys | probe_keys]
    if unknown:
        raise ExperimentError(f"--only: unknown setting '{unknown[0]}'; valid: {', '.join(sorted(trial_keys | probe_keys))}")
    jobs = trials = []
    if stage != "closed-loop" and experiment.probe and all(k in probe_keys for k in only):
        jobs = probe_jobs(experiment, None, overrides, only)  # each run's digest from its own probe set
    if stage != "probe" and all(k in trial_keys for k in only):
        trials = experiment.trials(overrides, only)
    return jobs, trials


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


def cmd_report(args) -> int:
    from benchmark.common.store import load_results
    from benchmark.experiments.report import write_reports

    try:
        frame = load_results(args.results)
    except FileNotFoundError as err:
        raise CliError(str(err)) from None
    if frame.empty:
        raise CliError(f"'{args.results}' holds no trials yet; run 'bench sweep' into it first")
    from benchmark.experiments.report import ReportConflict

    print(f"writing reports into {Path(args.out).resolve()}", file=sys.stderr)
    try:
        written = write_reports(frame, Path(args.out), args.format, force=args.force)
    except ReportConflict as err:
        raise CliError(str(err)) from None
    for path in written:
        print(path)
    return 0
