"""`bench`: run, compare and time legged-robot controllers across physics engines.

Examples:
  bench run                                    the main job: the embedded LLM walks A1 in MuJoCo
  bench run --policy rl                        the seed PPO policy alone
  bench list                                   what engines, robots, terrains and policies exist
  bench run --sim pybullet --robot anymal      5 trials of 10 s, a table of metrics
  bench run --policy stand --duration 5 --json one JSON object on stdout
  bench perf --sim mujoco --robot a1           framework vs raw engine steps/s
  bench perf --sim newton --worlds 64          1 world and 64 worlds per call
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import sys
import time

import numpy as np
from tqdm import tqdm

from benchmark import __version__
from benchmark.llm.models import LLMError
from benchmark.policies import available_policies, make_policy
from benchmark.runner import EpisodeConfig, TrialResult, run_trial, summarize
from robots import UnknownNameError, available_robots, load_robot
from sims import available_sims, make_sim, make_worlds
from sims.terrain import TERRAINS, Terrain


class CliError(Exception):
    """A user mistake: reported as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, not a usage dump
        raise CliError(f"{message} (see '{self.prog} --help')")


def _doc(module: str) -> str:
    """A command's long help: the docstring of the module that implements it."""
    return importlib.import_module(module).__doc__ or ""


def _key_values(items: list[str], option: str, form: str) -> dict[str, str]:
    """`KEY=VALUE` words of an option as a dict; anything else is a one-line error."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise CliError(f"{option} expects {form}, got '{item}'")
        out[key] = value
    return out


def _positive(kind: type) -> callable:
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {kind.__name__}, got '{text}'") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value

    parse.__name__ = f"positive {kind.__name__}"
    return parse


def _add_cell_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sim", default="mujoco", help=f"physics engine: {', '.join(available_sims())} (default mujoco)")
    parser.add_argument("--robot", default="a1", help=f"robot: {', '.join(available_robots())} (default a1)")
    parser.add_argument("--terrain", default="flat", help=f"terrain: {', '.join(TERRAINS)} (default flat)")
    parser.add_argument("--terrain-seed", type=int, default=0, help="seed of the rough heightfield (default 0)")
    parser.add_argument("--device", default=None,
                        help="newton only: cpu, cuda or cuda:N (default cuda when present, else cpu)")
    parser.add_argument("--solver", default=None, help="newton only: mujoco (default) or featherstone")


def _add_llm_options(parser: argparse.ArgumentParser) -> None:
    from benchmark.llm.encodings import DEFAULT_ENCODING, ENCODINGS
    from benchmark.llm.observations import DEFAULT_OBSERVATION, OBSERVATIONS
    from benchmark.llm.prompt import PARTS

    g = parser.add_argument_group("LLM policy (--policy llm)")
    g.add_argument("--llm", default="embedded",
                   help="model: embedded (Gemma 3 270M, offline), embedded:PATH.gguf, or openai:MODEL")
    g.add_argument("--llm-url", default=None, help="OpenAI-compatible base URL, e.g. http://127.0.0.1:8080/v1 "
                                                   "(or PROMPTWALK_LLM_URL); the key comes from PROMPTWALK_LLM_API_KEY "
                                                   "or OPENAI_API_KEY and is never printed")
    g.add_argument("--llm-api", default="completions", choices=("completions", "chat"), help="endpoint kind")
    g.add_argument("--llm-after", type=float, default=10.0, help="s: the LLM takes over (default 10)")
    g.add_argument("--seed-start", type=float, default=1.0, help="s: the seed policy starts filling the history")
    g.add_argument("--history", type=int, default=50, help="observation/action pairs in the prompt (default 50)")
    g.add_argument("--history-mode", default="sliding", choices=("sliding", "block"),
                   help="sliding window, or grow-then-cut-in-blocks (keeps llama.cpp's prompt cache warm)")
    g.add_argument("--prompt-parts", nargs="*", default=list(PARTS), help=f"description parts: {' '.join(PARTS)}")
    g.add_argument("--encoding", default=DEFAULT_ENCODING,
                   help="numbers: " + "; ".join(f"{k} {e.title}" for k, e in ENCODINGS.items()))
    g.add_argument("--observation", default=DEFAULT_OBSERVATION,
                   help="prompt inputs: " + "; ".join(f"{k} {v[0]}" for k, v in OBSERVATIONS.items()))
    g.add_argument("--unconstrained", action="store_true", help="no grammar/schema on the reply (as in the paper)")
    g.add_argument("--temperature", type=float, default=0.0, help="sampling temperature (default 0)")
    g.add_argument("--no-cache", action="store_true", help="do not read or write the on-disk reply cache")
    g.add_argument("--price-in", type=float, default=None, help="USD per 1M input tokens, for a cost estimate")
    g.add_argument("--price-out", type=float, default=None, help="USD per 1M output tokens")
    g.add_argument("--threads", type=int, default=None, help="llama.cpp threads (default: free cores)")


def _llm_config(args: argparse.Namespace):
    from benchmark.experiment import CellSpec

    cell = CellSpec(policy="llm", model=args.llm, url=args.llm_url, api=args.llm_api, history=args.history,
                    history_mode=args.history_mode, prompt_parts=tuple(args.prompt_parts), encoding=args.encoding,
                    observation=args.observation, constrained=not args.unconstrained, temperature=args.temperature,
                    llm_after=args.llm_after, seed_start=args.seed_start)
    return cell.llm_config(threads=args.threads, price_in=args.price_in, price_out=args.price_out,
                           cache=not args.no_cache)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="bench", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"promptwalk {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser("run", help="run trials of one policy on one robot, engine and terrain",
                         description="Run trials and report normalized walking time (NWT), success, "
                                     "distance and velocity per trial and on average.")
    _add_cell_options(run)
    run.add_argument("--policy", default="llm", help=f"controller: {', '.join(available_policies())} (default llm)")
    run.add_argument("--trials", type=_positive(int), default=5, help="number of trials (default 5, as in the paper)")
    run.add_argument("--duration", type=_positive(float), default=None,
                     help="episode length in s (default 20 for llm, the paper's episode; else 10)")
    _add_llm_options(run)
    run.add_argument("--seed", type=int, default=0, help="seed of the first trial; trial i uses seed+i (default 0)")
    run.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    run.add_argument("--record", default=None, metavar="PATH.rrd",
                     help="write a Rerun recording (several trials: PATH-seedN.rrd); open with bench view")
    run.add_argument("--record-dir", default=None, metavar="DIR",
                     help="write one recording per trial into DIR, named by cell and seed")
    run.set_defaults(func=cmd_run)

    view = sub.add_parser("view", help="open a recording in the Rerun viewer",
                          description="Launches the Rerun viewer (the `rerun` command of rerun-sdk) on the file.")
    view.add_argument("path", help="an .rrd file written by bench run --record")
    view.set_defaults(func=cmd_view)

    train = sub.add_parser("train", help="train a seed policy with stable-baselines3 PPO (CPU, minutes)",
                           description=_doc("benchmark.train"),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    train.add_argument("--robot", default="a1", help=f"robot: {', '.join(available_robots())} (default a1)")
    train.add_argument("--sim", nargs="+", default=["mujoco"],
                       help="engine(s) to train in; several share the 8 environments (default mujoco)")
    train.add_argument("--steps", type=_positive(int), default=1_000_000, help="environment steps (default 1e6)")
    train.add_argument("--seed", type=int, default=0, help="seed of PPO and the environments (default 0)")
    train.add_argument("--out", default=None, help="folder for train_log.csv and policy.npz (default runs/train-ROBOT)")
    train.add_argument("--eval-every", type=_positive(int), default=50_000, help="steps between evaluations")
    train.add_argument("--ship", action="store_true", help="also write robots/ROBOT/policy.npz and policy.json")
    train.add_argument("--init-from", default=None, help="warm start the actor from a policy.npz (fine-tuning)")
    train.add_argument("--reward", nargs="*", default=[], metavar="TERM=WEIGHT",
                       help="override reward weights, e.g. yaw_rate=-2 heading=-2 (see benchmark/rewards.py)")
    train.add_argument("--rough-share", type=float, default=0.5,
                       help="fraction of the 8 environments on rough terrain (default 0.5)")
    train.add_argument("--eval-terrain", choices=["flat", "rough"], default="flat",
                       help="terrain of the periodic evaluation trial (default flat)")
    train.set_defaults(func=cmd_train)

    sweep = sub.add_parser("sweep", help="run an experiment grid in parallel into a resumable results store",
                           description=_doc("benchmark.sweep"), formatter_class=argparse.RawDescriptionHelpFormatter)
    sweep.add_argument("experiment", nargs="?", default=None,
                       help="a shipped experiment (see --list) or the path of an experiment .toml")
    sweep.add_argument("--list", action="store_true", help="list the shipped experiments and exit")
    sweep.add_argument("--workers", type=_positive(int), default=1,
                       help="parallel trials (processes, or Ray tasks in flight; default 1)")
    sweep.add_argument("--results", default=None, metavar="DIR",
                       help="results store (default results/EXPERIMENT); trials already there are skipped")
    sweep.add_argument("--dry-run", action="store_true", help="list the cells and how many trials are missing")
    sweep.add_argument("--executor", default="local", choices=("local", "ray"),
                       help="local processes, or Ray tasks (pip install -e '.[ray]')")
    sweep.add_argument("--ray-address", default=None,
                       help="Ray cluster address (default: start a local Ray instance)")
    sweep.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", dest="overrides",
                       help="override a setting in every cell, e.g. history_mode=block model=openai:gpt-4o")
    sweep.add_argument("--only", nargs="*", default=[], metavar="KEY=VALUE",
                       help="run only the cells whose setting matches, e.g. policy=rl sim=mujoco")
    sweep.add_argument("--rate-limit", type=_positive(float), default=None, metavar="RPM",
                       help="remote LLM servers: at most RPM queries a minute over all workers")
    sweep.add_argument("--threads", type=_positive(int), default=None,
                       help="llama.cpp threads per worker (default: cores / workers)")
    sweep.set_defaults(func=cmd_sweep)

    report = sub.add_parser("report", help="tables and figures from a results store -> reports/",
                            description=_doc("benchmark.report"), formatter_class=argparse.RawDescriptionHelpFormatter)
    report.add_argument("results", help="a results directory written by bench sweep, or a results.parquet")
    report.add_argument("--format", default="md", choices=("md", "html", "csv"), help="table format (default md)")
    report.add_argument("--out", default="reports", help="folder for tables; figures go to OUT/figures")
    report.set_defaults(func=cmd_report)

    ship = sub.add_parser("ship", help="install a trained policy.npz as robots/ROBOT/policy.npz (+ policy.json)")
    ship.add_argument("path", help="a policy.npz written by bench train")
    ship.add_argument("--robot", required=True, help=f"robot: {', '.join(available_robots())}")
    ship.set_defaults(func=cmd_ship)

    base = sub.add_parser("baselines", help="evaluate the shipped seed policies in every cell -> reports/",
                          description=_doc("benchmark.baselines"),
                          formatter_class=argparse.RawDescriptionHelpFormatter)
    base.add_argument("--sims", nargs="+", default=available_sims(), help="engines (default: all)")
    base.add_argument("--robots", nargs="+", default=available_robots(), help="robots (default: all)")
    base.add_argument("--terrains", nargs="+", default=list(TERRAINS), help="terrains (default: all)")
    base.add_argument("--trials", type=_positive(int), default=5, help="trials per cell (default 5)")
    base.add_argument("--duration", type=_positive(float), default=10.0, help="trial length in s (default 10)")
    base.add_argument("--out", default="reports", help="folder for rl_baselines.csv and .md (default reports)")
    base.set_defaults(func=cmd_baselines)

    prompt = sub.add_parser("prompt", help="print a real LLM prompt (from a seed-policy rollout) and its token count",
                            description="Walks the seed policy in MuJoCo for 1 s standing plus HISTORY steps, then "
                                        "prints the prompt the LLM would get at that moment, and its length in tokens.")
    prompt.add_argument("--robot", default="a1", help=f"robot: {', '.join(available_robots())} (default a1)")
    prompt.add_argument("--tokenizer", default="gpt-4", choices=("gpt-4", "embedded"),
                        help="count with GPT-4's cl100k (offline) or the embedded model's tokenizer")
    prompt.add_argument("--seed", type=int, default=0, help="trial seed of the rollout")
    prompt.add_argument("--json", action="store_true", help="print one JSON object")
    _add_llm_options(prompt)
    prompt.set_defaults(func=cmd_prompt)

    lat = sub.add_parser("latency", help="LLM query latency by history length, sliding vs block-cut history",
                         description=_doc("benchmark.llm.latency"),
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    lat.add_argument("--llm", default="embedded", help="model spec, as for bench run (default embedded)")
    lat.add_argument("--llm-url", default=None, help="base URL for openai:MODEL")
    lat.add_argument("--histories", nargs="+", type=int, default=[10, 50], help="history lengths (default 10 50)")
    lat.add_argument("--modes", nargs="+", default=["sliding", "block"], choices=("sliding", "block"))
    lat.add_argument("--queries", type=_positive(int), default=8, help="LLM queries per cell (default 8)")
    lat.add_argument("--threads", type=int, default=None, help="llama.cpp threads (default: free cores)")
    lat.add_argument("--json", action="store_true", help="print one JSON object")
    lat.set_defaults(func=cmd_latency)

    lst = sub.add_parser("list", help="list engines, robots, terrains and policies")
    lst.add_argument("--json", action="store_true", help="print one JSON object")
    lst.set_defaults(func=cmd_list)

    perf = sub.add_parser("perf", help="framework steps/s against the raw engine loop, same model, same run",
                          description="Times `sims` stepping (PD, state, contacts) and the engine's bare loop "
                                      "on the same model, alternating rounds, and reports best-of physics steps/s.")
    _add_cell_options(perf)
    perf.add_argument("--steps", type=_positive(int), default=500, help="control steps per round (default 500 = 50 s)")
    perf.add_argument("--rounds", type=_positive(int), default=3, help="alternating rounds; the best is kept (default 3)")
    perf.add_argument("--worlds", type=_positive(int), default=None,
                      help="batched engines (newton): also time N worlds stepped in one call, beside 1 world")
    perf.add_argument("--json", action="store_true", help="print one JSON object")
    perf.set_defaults(func=cmd_perf)
    return parser


def _cell(args: argparse.Namespace):
    robot = load_robot(args.robot)
    terrain = Terrain(args.terrain, seed=args.terrain_seed)
    if args.sim not in available_sims():
        raise UnknownNameError("simulator", args.sim, available_sims())
    return robot, terrain


def cmd_run(args: argparse.Namespace) -> int:
    robot, terrain = _cell(args)
    llm = args.policy == "llm"
    duration = args.duration or (20.0 if llm else 10.0)
    options, eval_start = {}, 0.0
    if llm:
        config = _llm_config(args)
        if config.llm_after >= duration:
            raise CliError(f"--llm-after ({config.llm_after:g} s) must be before the end of the episode "
                           f"(--duration {duration:g} s)")
        options, eval_start = {"config": config}, config.llm_after
    episode = EpisodeConfig(duration=duration, eval_start=eval_start)
    policy = make_policy(args.policy, robot, **options)
    sim = make_sim(args.sim, robot, terrain, device=args.device, solver=args.solver)
    trials: list[TrialResult] = []
    error = None
    try:
        for i in tqdm(range(args.trials), desc=f"{args.sim}/{args.robot}/{args.terrain}/{args.policy}",
                      unit="trial", file=sys.stderr, disable=None):
            seed = args.seed + i
            hooks = [_llm_progress(policy, episode)] if llm else []
            recorder = _recorder(args, robot, terrain, sim, policy, seed)
            if recorder is not None:
                hooks.append(recorder.on_step)
            trial = run_trial(sim, robot, terrain, policy, episode, seed=seed,
                              on_step=(lambda loop: [hook(loop) for hook in hooks]) if hooks else None)
            trials.append(trial)
            if recorder is not None:
                recorder.write(trial)
    except LLMError as err:  # keep what finished: report it, then the error
        error = err
    finally:
        sim.close()
        getattr(getattr(policy, "model", None), "close", lambda: None)()
    result = {"sim": args.sim, "robot": args.robot, "terrain": args.terrain, "terrain_seed": args.terrain_seed,
              "policy": args.policy, "duration": duration, "eval_start": eval_start, "seed": args.seed,
              "trials": [t.to_dict() for t in trials], **summarize(trials)}
    if llm:
        result["llm"] = {"model": args.llm, "url": args.llm_url, "api": args.llm_api, "history": args.history,
                         "history_mode": args.history_mode, "encoding": args.encoding,
                         "observation": args.observation, "prompt_parts": args.prompt_parts,
                         "constrained": not args.unconstrained}
    if args.json:
        print(json.dumps(result))
    else:
        _print_run_table(result)
    if error is not None:
        print(f"bench: error: {error} ({len(trials)} finished trial(s) reported above)", file=sys.stderr)
        return 1
    return 0


def _recorder(args: argparse.Namespace, robot, terrain, sim, policy, seed: int):
    """The Recorder for this trial, or None when not recording."""
    from pathlib import Path

    from benchmark.recorder import Recorder

    name = f"{args.sim}-{args.robot}-{args.terrain}-{args.policy}-seed{seed}"
    if args.record_dir:
        return Recorder(Path(args.record_dir) / f"{name}.rrd", robot, terrain, sim, policy, name)
    if args.record:
        path = Path(args.record)
        if args.trials > 1:
            path = path.with_name(f"{path.stem}-seed{seed}{path.suffix or '.rrd'}")
        return Recorder(path, robot, terrain, sim, policy, name)
    return None


def cmd_sweep(args: argparse.Namespace) -> int:
    from pathlib import Path

    from benchmark.experiment import available_experiments, load_experiment, parse_overrides
    from benchmark.store import ResultStore
    from benchmark.sweep import TrialError, run_sweep, validate

    if args.list or args.experiment is None:
        if args.experiment is None and not args.list:
            raise CliError(f"name an experiment: {', '.join(available_experiments())} (or a path to a .toml)")
        for name in available_experiments():
            exp = load_experiment(name)
            print(f"{name:<14} {len(exp.trials()):>4} trials  {exp.title}")
        return 0
    experiment = load_experiment(args.experiment)
    overrides = parse_overrides(args.overrides)
    trials = experiment.trials(overrides, _key_values(args.only, "--only", "KEY=VALUE"))
    if args.executor == "ray" and importlib.util.find_spec("ray") is None:
        raise CliError("--executor ray needs Ray: pip install -e '.[ray]'")
    if not trials:
        raise CliError(f"no cell of '{experiment.name}' matches --only {' '.join(args.only)}")
    store = ResultStore(Path(args.results or f"results/{experiment.name}"))
    done = store.done_ids()
    if args.dry_run:  # a real run validates its cells in run_sweep
        for cell in dict.fromkeys(t.cell for t in trials):
            validate(cell)
        cells: dict[str, list] = {}
        for t in trials:
            cells.setdefault(t.cell_id, []).append(t)
        print(f"{experiment.name}: {len(cells)} cells, {len(trials)} trials, "
              f"{sum(t.id not in done for t in trials)} missing in {store.root}")
        for group in cells.values():
            t = group[0]
            missing = sum(x.id not in done for x in group)
            params = {**t.cell.params(), **t.labels}
            shown = {k: params[k] for k in [*experiment.axes, *overrides] if k in params}
            print(f"  {t.cell_id}  {t.cell.label():<32} {json.dumps(shown)}  seeds {[x.seed for x in group]}"
                  f"  missing {missing}")
        return 0
    try:
        outcome = run_sweep(trials, store, workers=args.workers, executor=args.executor, address=args.ray_address,
                            requests_per_minute=args.rate_limit, threads=args.threads,
                            command=" ".join(["bench", *args.argv]))
    except (TrialError, LLMError) as err:
        print(f"bench: error: {err} ({len(store.done_ids())} trial(s) stored in {store.root}; "
              "run the same command again to resume)", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"bench: interrupted ({len(store.done_ids())} trial(s) stored in {store.root}; "
              "run the same command again to resume)", file=sys.stderr)
        return 130
    print(f"{experiment.name}: {outcome.ran} trial(s) run, {outcome.skipped} already stored, "
          f"{outcome.total} in the grid; {outcome.wall_s:.1f} s with {args.workers} {args.executor} worker(s); "
          f"results in {store.root}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from pathlib import Path

    from benchmark.report import write_reports
    from benchmark.store import load_results

    try:
        frame = load_results(args.results)
    except FileNotFoundError as err:
        raise CliError(str(err)) from None
    if frame.empty:
        raise CliError(f"'{args.results}' holds no trials yet; run 'bench sweep' into it first")
    for path in write_reports(frame, Path(args.out), args.format):
        print(path)
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    import shutil
    import subprocess
    from pathlib import Path

    if not Path(args.path).is_file():
        raise CliError(f"recording '{args.path}' not found")
    viewer = shutil.which("rerun")
    if viewer is None:
        raise CliError("the 'rerun' viewer is not on PATH; it comes with rerun-sdk (pip install -e .)")
    return subprocess.call([viewer, args.path])


def _llm_progress(policy, episode: EpisodeConfig):
    """A progress bar over the LLM queries of one trial."""
    total = int(round((episode.duration - episode.eval_start) / 0.1))
    bar = tqdm(total=total, desc="LLM queries", unit="query", file=sys.stderr, disable=None, leave=False)

    def update(loop) -> None:
        bar.n = len(policy.queries)
        bar.refresh()
        if loop.time >= episode.duration - 1e-9 or loop.fall is not None:
            bar.close()

    return update


def _print_run_table(result: dict) -> None:
    print(f"{result['policy']} on {result['robot']} / {result['sim']} / {result['terrain']}, "
          f"{len(result['trials'])} x {result['duration']:g} s")
    print(f"{'seed':>4} {'nwt':>5} {'ok':>3} {'dist m':>7} {'vx m/s':>7} {'drift m':>8}  fall")
    for t in result["trials"]:
        fall = f"{t['fall_time']:.1f} s: {t['fall_reason']}" if t["fall_time"] is not None else "-"
        print(f"{t['seed']:>4} {t['nwt']:>5.2f} {'yes' if t['success'] else 'no':>3} {t['distance_m']:>7.2f} "
              f"{t['mean_vx']:>7.2f} {t['lateral_drift_m']:>8.2f}  {fall}")
    print(f"mean NWT {result['nwt']:.3f}, success rate {result['success_rate']:.2f}, "
          f"distance {result['distance_m']:.2f} m, vx {result['mean_vx']:.2f} m/s")
    llm_trials = [t for t in result["trials"] if t.get("queries")]
    if llm_trials:
        print(f"{'seed':>4} {'queries':>7} {'unparsed':>8} {'tokens in/out':>14} {'gpt-4 in/out':>13} "
              f"{'latency s':>10} {'p95 s':>6} {'RTF':>6}")
        for t in llm_trials:
            rtf = f"{t['realtime_factor']:.3f}" if t.get("realtime_factor") else "-"
            print(f"{t['seed']:>4} {t['queries']:>7} {t['parse_failures']:>8} "
                  f"{t['input_tokens']:>8.0f}/{t['output_tokens']:<5.0f} "
                  f"{t['gpt4_input_tokens']:>7.0f}/{t['gpt4_output_tokens']:<5.0f} "
                  f"{t['latency_mean_s']:>10.2f} {t['latency_p95_s']:>6.2f} {rtf:>6}")


def cmd_train(args: argparse.Namespace) -> int:
    from pathlib import Path

    from benchmark.train import reward_weights, train

    load_robot(args.robot)
    for sim in args.sim:
        if sim not in available_sims():
            raise UnknownNameError("simulator", sim, available_sims())
    overrides = {}
    for term, value in _key_values(args.reward, "--reward", "TERM=NUMBER").items():
        try:
            overrides[term] = float(value)
        except ValueError:
            raise CliError(f"--reward expects TERM=NUMBER, got '{term}={value}'") from None
    rewards = reward_weights(overrides)
    if not 0.0 <= args.rough_share <= 1.0:
        raise CliError(f"--rough-share must be between 0 and 1, got {args.rough_share}")
    out = Path(args.out or f"runs/train-{args.robot}")
    init = Path(args.init_from) if args.init_from else None
    path = train(args.robot, args.sim, args.steps, args.seed, out, args.eval_every, args.ship, rewards, init,
                 rough_share=args.rough_share, eval_terrain=args.eval_terrain)
    print(f"policy written to {path}; log in {out / 'train_log.csv'}")
    return 0


def cmd_ship(args: argparse.Namespace) -> int:
    from pathlib import Path

    from benchmark.train import ship_policy

    load_robot(args.robot)
    print(f"shipped {ship_policy(Path(args.path), args.robot)}")
    return 0


def cmd_baselines(args: argparse.Namespace) -> int:
    from pathlib import Path

    from benchmark.baselines import run_baselines

    for name in args.sims:
        if name not in available_sims():
            raise UnknownNameError("simulator", name, available_sims())
    for name in args.robots:
        load_robot(name)
    for name in args.terrains:
        Terrain(name)
    command = "bench " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["baselines"] else "bench baselines"
    path = run_baselines(args.sims, args.robots, args.terrains, args.trials, args.duration, Path(args.out), command)
    print(path.read_text())
    return 0


def cmd_prompt(args: argparse.Namespace) -> int:
    from benchmark.control import ControlLoop
    from benchmark.llm.prompt import build_prompt, describe_robot
    from benchmark.llm.tokens import gpt4_tokens, server_tokens
    from benchmark.observation import llm_observation
    from benchmark.policies import RLPolicy

    robot = load_robot(args.robot)
    config = _llm_config(args)
    sim = make_sim("mujoco", robot, Terrain("flat"))
    seed_policy, loop, pairs = RLPolicy(robot), ControlLoop(sim, robot, Terrain("flat")), []
    loop.reset(args.seed)
    for _ in range(int(round(config.seed_start / loop.dt)) + config.prompt.history):
        action = seed_policy.act(loop.obs, loop.state) if loop.time >= config.seed_start - 1e-9 else np.zeros(12)
        if loop.time >= config.seed_start - 1e-9:
            pairs.append((llm_observation(loop.obs), action))
        loop.step(action)
    window = pairs[len(pairs) - config.prompt.history:] if config.prompt.history else []
    text = build_prompt(describe_robot(robot, config.prompt), window, llm_observation(loop.obs), config.prompt)
    if args.tokenizer == "gpt-4":
        tokens = gpt4_tokens(text)
    else:
        from benchmark.llm.models import EmbeddedModel

        model = EmbeddedModel(args.llm.partition(":")[2] or None, threads=args.threads)
        tokens = server_tokens(model.url, text)
        model.close()
    if args.json:
        print(json.dumps({"robot": args.robot, "history": config.prompt.history, "encoding": args.encoding,
                          "observation": args.observation, "prompt_parts": args.prompt_parts,
                          "tokenizer": args.tokenizer, "tokens": tokens, "prompt": text}))
    else:
        print(text)
        print(f"\n[{tokens} tokens ({args.tokenizer}), history {config.prompt.history}, encoding {args.encoding}]",
              file=sys.stderr)
    return 0


def cmd_latency(args: argparse.Namespace) -> int:
    from benchmark.llm.latency import measure

    rows = measure(args.llm, args.histories, args.modes, args.queries, args.threads, args.llm_url)
    if args.json:
        print(json.dumps({"model": args.llm, "rows": rows}))
        return 0
    print(f"{args.llm}: query latency, {args.queries} queries per cell, cache off")
    print(f"{'history':>7} {'mode':>8} {'tokens':>7} {'first s':>8} {'mean s':>7} {'p95 s':>6} {'after 1st s':>11}")
    for r in rows:
        after = f"{r['latency_after_first_s']:.2f}" if r["latency_after_first_s"] is not None else "-"
        print(f"{r['history']:>7} {r['mode']:>8} {r['prompt_tokens']:>7.0f} {r['latency_first_s']:>8.2f} "
              f"{r['latency_mean_s']:>7.2f} {r['latency_p95_s']:>6.2f} {after:>11}")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    listing = {"sims": available_sims(), "robots": available_robots(), "terrains": list(TERRAINS),
               "policies": available_policies()}
    if args.json:
        print(json.dumps(listing))
    else:
        for key, names in listing.items():
            print(f"{key:9} {', '.join(names)}")
    return 0


def _time_loops(stepper, targets, steps: int, rounds: int, physics_steps: int, reset) -> tuple[float, float]:
    """Best-of-`rounds` physics steps/s of the raw engine loop and of the framework's step."""
    raw, framework = [], []
    for _ in tqdm(range(rounds), desc="perf rounds", file=sys.stderr, disable=None, leave=False):
        reset()
        start = time.perf_counter()
        stepper.raw_loop(targets, steps)
        raw.append(physics_steps / (time.perf_counter() - start))
        reset()
        start = time.perf_counter()
        for _ in range(steps):
            stepper.step(targets)
        framework.append(physics_steps / (time.perf_counter() - start))
    return max(raw), max(framework)


class _BatchStepper:
    """Adapts a batched engine to _time_loops: a framework step also builds every world's state."""

    def __init__(self, worlds) -> None:
        self.worlds = worlds

    def raw_loop(self, targets, steps: int) -> None:
        self.worlds.raw_loop(targets, steps)

    def step(self, targets) -> None:
        self.worlds.step(targets)
        self.worlds.states()


def cmd_perf(args: argparse.Namespace) -> int:
    robot, terrain = _cell(args)
    rows = []
    sim = make_sim(args.sim, robot, terrain, device=args.device, solver=args.solver)
    try:
        steps = args.steps * sim.physics.substeps
        raw, framework = _time_loops(sim, robot.default_pose, args.steps, args.rounds, steps, lambda: sim.reset(0))
        rows.append({"worlds": 1, "raw_steps_per_s": raw, "framework_steps_per_s": framework})
    finally:
        sim.close()
    if args.worlds is not None and args.worlds > 1:
        worlds = make_worlds(args.sim, robot, terrain, args.worlds, device=args.device, solver=args.solver)
        targets = np.tile(robot.default_pose, (args.worlds, 1))
        steps = args.steps * worlds.physics.substeps * args.worlds  # env-steps: physics steps summed over worlds
        raw, framework = _time_loops(_BatchStepper(worlds), targets, args.steps, args.rounds, steps,
                                     lambda: worlds.reset(range(args.worlds)))
        rows.append({"worlds": args.worlds, "raw_steps_per_s": raw, "framework_steps_per_s": framework})
    for row in rows:
        row["ratio"] = row["framework_steps_per_s"] / row["raw_steps_per_s"]
    result = {"sim": args.sim, "robot": args.robot, "terrain": args.terrain, "control_steps": args.steps,
              "rounds": args.rounds, **rows[0], "by_worlds": rows}
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{args.sim} / {args.robot} / {args.terrain}: physics steps per second, summed over worlds "
              f"(best of {args.rounds} rounds of {args.steps} control steps)")
        print(f"{'worlds':>7} {'raw engine':>12} {'promptwalk':>12} {'ratio':>7}")
        for row in rows:
            print(f"{row['worlds']:>7} {row['raw_steps_per_s']:>12,.0f} {row['framework_steps_per_s']:>12,.0f} "
                  f"{row['ratio']:>7.3f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        argv = sys.argv[1:] if argv is None else argv
        args = parser.parse_args(argv)
        args.argv = argv  # recorded beside results, to re-run them
        return args.func(args)
    except (CliError, UnknownNameError, ValueError) as err:
        print(f"bench: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
