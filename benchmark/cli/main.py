"""The `bench` entry point: parse, dispatch to the command's layer, turn user mistakes into one line."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from benchmark.checks.gait import GaitConfig
from benchmark.checks.straight import StraightConfig
from benchmark.checks.validate import ValidateConfig
from benchmark.cli import (
    check_commands,
    evaluate_commands,
    experiment_commands,
    llm_commands,
    training_commands,
    trial_commands,
)
from benchmark.cli.options import CliError, key_values
from benchmark.cli.parser import build_parser
from benchmark.common.interrupt import Interrupted
from benchmark.common.settings import build
from benchmark.evaluate.probe import ProbeRun
from benchmark.llm.controller import LLMSettings
from benchmark.llm.models import leave
from benchmark.training.train import TrainConfig
from benchmark.trial.cell import setting_fields
from benchmark.trial.resources import Runtime
from benchmark.trial.video import VideoConfig
from robots import UnknownNameError

NO_SETTINGS = {  # commands that take only their parsed arguments
    "view": trial_commands.cmd_view, "list": trial_commands.cmd_list, "report": experiment_commands.cmd_report,
    "ship": training_commands.cmd_ship, "models": llm_commands.cmd_models,
    "leaderboard": evaluate_commands.cmd_leaderboard,
}


def _settings(args: argparse.Namespace, cls: type) -> dict:
    return {f.name: getattr(args, f.name) for f in dataclasses.fields(cls) if hasattr(args, f.name)}


def dispatch(args: argparse.Namespace) -> int:
    given = {k: v for k, v in vars(args).items() if k not in ("command", "argv")}
    runtime = build(Runtime, {**_settings(args, Runtime), "cache": not getattr(args, "no_cache", False)}, "bench")
    cell_keys = set(setting_fields())
    cell_values = {k: v for k, v in given.items() if k in cell_keys}
    match args.command:
        case "run":
            return trial_commands.cmd_run(args, cell_values, runtime, _settings(args, VideoConfig))
        case "render":
            return trial_commands.cmd_render(args, _settings(args, VideoConfig))
        case "prompt":
            return trial_commands.cmd_prompt(args, cell_values, runtime)
        case "perf":
            return check_commands.cmd_perf(args, cell_values)
        case "sweep":
            return experiment_commands.cmd_sweep(args, args.overrides, args.only)
        case "train":
            rewards = {k: _float(v, k) for k, v in key_values(args.reward, "--reward", "TERM=NUMBER").items()}
            ppo = {k: _float(v, k, "--ppo", "NAME") for k, v in key_values(args.ppo, "--ppo", "NAME=NUMBER").items()}
            return training_commands.cmd_train(_settings(args, TrainConfig), rewards, ppo)
        case "latency":
            return llm_commands.cmd_latency(args, runtime.threads)
        case "throughput":
            return llm_commands.cmd_throughput(args)
        case "validate":
            return check_commands.cmd_validate(_settings(args, ValidateConfig))
        case "gait":
            return check_commands.cmd_gait(_settings(args, GaitConfig))
        case "straight":
            return check_commands.cmd_straight(_settings(args, StraightConfig))
        case "eval":
            return evaluate_commands.cmd_eval(args, _settings(args, LLMSettings), runtime)
        case "probe":
            return evaluate_commands.cmd_probe(args, _settings(args, LLMSettings), _settings(args, ProbeRun), runtime)
    return NO_SETTINGS[args.command](args)


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
    except BrokenPipeError:  # the reader went away (`bench sweep --list | head`): stop quietly
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes stdout
        return leave(0)
    except (Interrupted, KeyboardInterrupt):  # a command that says what it kept returns 130 itself
        print("bench: interrupted: everything finished is stored; run the same command again to resume", file=sys.stderr)
        return leave(130)


if __name__ == "__main__":
    sys.exit(main())
