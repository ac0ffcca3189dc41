"""`bench probe`, `eval` and `leaderboard`: scoring models."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from benchmark.cli.options import CliError
from benchmark.common.settings import build
from benchmark.trial.resources import Runtime


def cmd_probe(args, llm_values: dict, run_values: dict, runtime: Runtime) -> int:
    """`bench probe`: make the probe set, or score one model on it (a table, or --json)."""
    import dataclasses

    from benchmark.evaluate.probe import (
        DEFAULT_PROBE,
        ProbeProgress,
        ProbeRun,
        ProbeSetConfig,
        answer_items,
        load_probe_set,
        make_probe_set,
        save_probe_set,
        summarize_answers,
    )
    from benchmark.llm.controller import LLMSettings, strategy_label

    if args.make:
        config = ProbeSetConfig(sim=args.sim or ProbeSetConfig.sim,
                                **({"cells": tuple(args.cells)} if args.cells else {}))
        probe = make_probe_set(config, progress=lambda line: print(f"bench: {line}", file=sys.stderr, flush=True))
        path = save_probe_set(probe, Path(args.out) if args.out else DEFAULT_PROBE)
        print(f"wrote {path}: {len(probe.walks)} walks, {probe.items()} items, digest {probe.digest}")
        return 0
    if args.sim is not None:
        raise CliError("--sim goes with --make (the engine a new probe set walks in); a probe set is one engine's: "
                       "--probe PATH scores another")
    probe = load_probe_set(args.probe or DEFAULT_PROBE)
    llm = build(LLMSettings, {"history": 10, **llm_values}, "bench probe")  # the probe's default history: 10
    run = build(ProbeRun, {k: v for k, v in run_values.items() if k != "llm"}, "bench probe")
    unknown = [c for c in (args.cells or []) if c not in probe.cells]
    if unknown:
        raise CliError(f"unknown probe cell '{unknown[0]}'; valid: {', '.join(probe.cells)}")
    run = dataclasses.replace(run, llm=llm, cells=tuple(args.cells) if args.cells else None)
    answers = answer_items(probe, run, runtime, progress=ProbeProgress())
    summary = {"model": llm.model, "probe": probe.digest, "history": llm.history, "window": run.window,
               **summarize_answers(answers)}
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"probe {probe.digest} ({probe.meta.get('config', {}).get('sim', 'mujoco')}): {llm.model}, {strategy_label(llm)}, history {llm.history} ({run.window}), {llm.encoding}, "
          f"{llm.observation}: {summary['items']} items in {summary['wall_s']:.0f} s")
    width = max(14, *(len(cell) + 2 for cell in summary["cells"]))
    print(f"{'cell':<{width}}{'items':>6}{'error':>8}{'skill':>8}{'within 1 step':>15}")
    for cell, c in summary["cells"].items():
        print(f"{cell:<{width}}{c['items']:>6}{c['error']:>8.3f}{c['skill']:>8.3f}{c['within_step']:>15.2f}")
    print(f"{'all':<{width}}{summary['items']:>6}{summary['error']:>8.3f}{summary['skill']:>8.3f}"
          f"{summary['within_step']:>15.2f}   skill 95% [{summary['skill_low']:.3f}, {summary['skill_high']:.3f}], "
          f"{summary['parse_failures']} parse failures, median {summary['latency_median_s']:.2f} s a query")
    same = summary.get("same_prompt")
    if same:
        print(f"same prompt's trivial answers: hold (its last example line) skill {same['hold_skill']:.3f}, knn "
              f"{same['knn_skill']:.3f}; gain over {same['best']}: {same['gain']:+.3f} "
              f"[{same['gain_low']:+.3f}, {same['gain_high']:+.3f}]")
    return 0


def cmd_eval(args, llm_values: dict, runtime: Runtime) -> int:
    """`bench eval`: run (or find) one model's scorecard row, print it, refresh reports/leaderboard.md."""
    from benchmark.evaluate.probe import DEFAULT_PROBE, load_probe_set
    from benchmark.evaluate.scorecard import DEFAULT_SUITE, evaluate
    from benchmark.llm.controller import LLMSettings

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
    strategy = f", prompt {row['strategy']}" if "strategy" in row else ""  # rows without it ran the paper's prompt
    print(f"scorecard {row['row_id']}: {row['model']} ({row['kind']}), {row['tier']} tier{strategy}, probe "
          f"{row['probe_digest']}")
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
    from benchmark.evaluate.leaderboard import write_leaderboard

    path, page = write_leaderboard(args.store, args.out, command="bench " + " ".join(args.argv))
    print(f"wrote {path}" + (f" and {page}" if page else ""))
    return 0
