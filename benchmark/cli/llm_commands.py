"""`bench latency` and `bench models`: the LLM layer's own commands."""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from pathlib import Path


def cmd_throughput(args) -> int:
    from benchmark.llm.models import require_models
    from benchmark.llm.throughput import SPEED_SETTINGS, Setup, ThroughputRun, measure, table

    if args.settings and args.encoding:
        print("bench: error: --settings names the number layout itself; give it alone, or --encoding without it "
              f"(settings: {', '.join(SPEED_SETTINGS)})", file=sys.stderr)
        return 2
    require_models([args.llm])
    chosen = [SPEED_SETTINGS[name][0] for name in args.settings] if args.settings \
        else [Setup(encoding=args.encoding or Setup.encoding)]
    drafts = args.drafts or [None]  # None: each setup's own draft
    setups = tuple(u if d is None else dataclasses.replace(u, draft=d) for u in chosen for d in drafts)
    run = ThroughputRun(model=args.llm, strategy=args.prompt_strategy, concurrency=tuple(args.concurrency),
                        queries=args.queries, threads=args.threads, setups=setups)
    result = measure(run)
    if args.json:
        print(json.dumps(result))
        return 0
    text = table(result)
    print(text)
    if args.out:
        load, cores = os.getloadavg()[0], os.cpu_count()
        Path(args.out).write_text(f"# Closed-loop throughput and the query floor\n\nMade with `bench {' '.join(args.argv)}` "
                                  f"(machine load {load:.1f} on {cores} cores as it finished).\n\n{text}\n")
        print(f"written to {args.out}", file=sys.stderr)
    return 0


def cmd_latency(args, threads: int | None) -> int:
    from benchmark.llm.latency import measure
    from benchmark.llm.strategies import DEFAULT_STRATEGY
    from benchmark.llm.models import check_model_spec

    check_model_spec(args.llm)
    rows = measure(args.llm, args.histories, args.modes, args.queries, threads, args.llm_url, drift=not args.no_drift,
                   drafts=tuple(args.drafts), strategies=tuple(args.strategies))
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
    by_strategy = args.strategies != [DEFAULT_STRATEGY]  # the prompt strategy column, when one was asked for
    if by_strategy:
        lines[2] = "| strategy " + lines[2]
        lines[3] = "|---" + lines[3]
    for r in rows:
        after = f"{r['latency_after_first_s']:.2f}" if r["latency_after_first_s"] is not None else "-"
        same = f"{r['identical_to_cold']:.2f}" if r.get("identical_to_cold") is not None else "-"
        diff = f"{r['action_diff_vs_cold']:.3f}" if r.get("action_diff_vs_cold") is not None else "-"
        changed = {True: "changed", False: "same"}.get(r.get("outcome_changed"), "-")
        mode = r["mode"] + (" (approximate)" if r["approximate"] else "")
        undrafted = f"{r['same_as_no_draft']:.2f}" if r.get("same_as_no_draft") is not None else "-"
        lines.append((f"| {r['strategy']} " if by_strategy else "") + f"| {r['history']} | {mode} | {r['draft']} | {r['prompt_tokens']:.0f} | {r['latency_first_s']:.2f} | "
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
