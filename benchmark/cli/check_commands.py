"""`bench perf`, `validate`, `gait` and `straight`: checks of engines, robots and seed policies."""

from __future__ import annotations

import json

from benchmark.cli.options import CliError, _as_typed
from benchmark.common.settings import build
from benchmark.trial.cell import make_cell


def cmd_perf(args, values: dict) -> int:
    from benchmark.checks.perf import measure, print_table

    result = measure(make_cell(values, where="bench perf"), args.steps, args.rounds, args.worlds)
    if args.json:
        print(json.dumps(result))
    else:
        print_table(result)
    return 0


def cmd_validate(values: dict) -> int:
    from benchmark.checks.validate import ValidateConfig, main

    path = main(build(ValidateConfig, values, where="bench validate"), _as_typed("validate"))
    print(f"wrote {path} and its figures")
    return 0


def _seed_policy_check(name: str, config_cls: type, main, values: dict, figures: str) -> int:
    """`bench gait` and `bench straight`: a report on seed policies, one robot's when a policy file is given."""
    config = build(config_cls, values, where=f"bench {name}")
    if config.policy_file and len(config.robot) != 1:
        raise CliError("--policy-file needs exactly one --robot (it was trained for one robot)")
    path = main(config, _as_typed(name))
    print(f"wrote {path} and its {figures}")
    return 0


def cmd_gait(values: dict) -> int:
    from benchmark.checks.gait import GaitConfig, main

    return _seed_policy_check("gait", GaitConfig, main, values, "figures")


def cmd_straight(values: dict) -> int:
    from benchmark.checks.straight import StraightConfig, main

    return _seed_policy_check("straight", StraightConfig, main, values, "figure")
