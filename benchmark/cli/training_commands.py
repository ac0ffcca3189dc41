"""`bench train` and `bench ship`: seed policies."""

from __future__ import annotations

import sys
from pathlib import Path

from benchmark.cli.options import CliError, _as_typed
from benchmark.common.interrupt import Interruption
from benchmark.common.settings import build


def cmd_train(values: dict, rewards: dict, ppo: dict | None = None) -> int:
    from benchmark.training.train import TrainConfig, ppo_settings, reward_weights, train
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
    from benchmark.training.train import ship_policy
    from robots import load_robot

    load_robot(args.robot)
    if not Path(args.path).is_file():
        raise CliError(f"'{args.path}' not found; give a policy.npz written by bench train")
    print(f"shipped {ship_policy(Path(args.path), args.robot)}")
    return 0
