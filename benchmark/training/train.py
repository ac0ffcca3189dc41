"""Train a seed policy with stable-baselines3 PPO (CPU, deterministic for a seed).

    bench train --robot a1 --steps 1000000 --seed 0

Eight environments in one process (DummyVecEnv: on 2 cores it beats subprocesses), by default half on
flat ground and half on rough terrain of different seeds (`--rough-share`), all domain-randomized;
`--sim mujoco pybullet` spreads them over engines (pairs of environments per engine). Every
`--eval-every` steps the deterministic actor walks one 10 s trial through the benchmark's
own runner; the row goes to `train_log.csv` and the actor to `policy.npz` in `--out`.
With `--ship`, the final actor is also written to `robots/<robot>/policy.npz`.
"""

from __future__ import annotations

import csv
import json
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from benchmark.trial.cell import CellSpec
from benchmark.trial.trials import run_cell
from benchmark.trial.mlp import MlpActor
from benchmark.trial.policies import SeedSettings
from benchmark.training.rewards import RewardWeights
from benchmark.common.settings import setting
from robots import load_robot


@dataclass(frozen=True)
class PPOSettings:
    """stable-baselines3 PPO settings of the shipped policies (fast and stable on 2 CPU cores)."""

    n_steps: int = 256
    batch_size: int = 512
    n_epochs: int = 5
    gamma: float = 0.97
    gae_lambda: float = 0.95
    learning_rate: float = 3e-4
    clip_range: float = 0.2
    ent_coef: float = 0.0
    max_grad_norm: float = 1.0


@dataclass(frozen=True)
class TrainConfig:
    """One training run; its fields are `bench train`'s options."""

    robot: str = setting("a1", "robot: a shipped name, or a folder holding robot.toml")
    sim: tuple[str, ...] = setting(("mujoco",), "engine(s) to train in; several share the 8 environments")
    steps: int = setting(1_000_000, "environment steps", positive=True)
    seed: int = setting(0, "seed of PPO and the environments")
    out: str | None = setting(None, "folder for train_log.csv and policy.npz (default runs/train-ROBOT)")
    eval_every: int = setting(50_000, "steps between evaluations (a 10 s trial through run_cell)", positive=True)
    ship: bool = setting(False, "also write robots/ROBOT/policy.npz and policy.json")
    init_from: str | None = setting(None, "warm start the actor from a policy.npz (fine-tuning)")
    rough_share: float = setting(0.5, "fraction of the 8 environments on rough terrain", minimum=0)
    eval_terrain: str = setting("flat", "terrain of the periodic evaluation trial", choices=("flat", "rough"))
    mirror: bool = setting(True, "mirrored-state augmentation: every transition is also learnt reflected left/right, "
                                 "so the policy has no turning bias (--no-mirror: as the earlier policies)")
    mirror_loss: float = setting(0.0, "weight of the symmetry loss |mu(s) - M mu(M s)|^2, a few epochs after each "
                                      "PPO update (with --mirror); it makes the actor itself equivariant", minimum=0)
    symmetric_actor: bool = setting(False, "train the symmetric actor itself: its mean is the average of its answer and "
                                           "the mirror of its answer to the mirrored observation, exactly as symmetric "
                                           "inference runs it, so it is equivariant while it learns (no turning bias)")
    rewards: RewardWeights = RewardWeights()
    ppo: PPOSettings = PPOSettings()
    num_envs: int = 8
    net: tuple[int, ...] = (256, 128)  # actor and critic hidden layers
    exploration_rad: float = setting(0.25, "initial action noise (std) in joint radians, the same for every robot; "
                                           "a fine-tune may start lower", positive=True)

    @property
    def out_dir(self) -> Path:
        return Path(self.out or f"runs/train-{load_robot(self.robot).name}")


def _actor_layers(model) -> list:
    """The linear layers of an SB3 ActorCriticPolicy's actor, input to output."""
    import torch.nn as nn

    return [m for m in model.policy.mlp_extractor.policy_net if isinstance(m, nn.Linear)] + [model.policy.action_net]


def export_actor(model, meta: dict) -> MlpActor:
    """The deterministic actor of an SB3 ActorCriticPolicy as numpy arrays."""
    from benchmark.training.envs import ACTION_LIMIT

    linears = _actor_layers(model)
    return MlpActor(tuple(m.weight.detach().numpy().copy() for m in linears),
                    tuple(m.bias.detach().numpy().copy() for m in linears), "elu", ACTION_LIMIT, meta)


def ppo_settings(overrides: dict[str, float] | None = None) -> PPOSettings:
    """The shipped PPO settings with `overrides` (e.g. {"learning_rate": 1e-4}) applied; counts stay ints."""
    known = {f.name: f for f in fields(PPOSettings)}
    unknown = sorted(set(overrides or {}) - set(known))
    if unknown:
        raise ValueError(f"unknown PPO setting '{unknown[0]}'; valid: {', '.join(sorted(known))}")
    typed = {k: int(v) if isinstance(getattr(PPOSettings(), k), int) else float(v) for k, v in (overrides or {}).items()}
    return replace(PPOSettings(), **typed)


def reward_weights(overrides: dict[str, float] | None = None) -> RewardWeights:
    """The default reward weights with `overrides` (e.g. {"yaw_rate": -2.0}) applied."""
    known = {f.name for f in fields(RewardWeights)}
    unknown = sorted(set(overrides or {}) - known)
    if unknown:
        raise ValueError(f"unknown reward term '{unknown[0]}'; valid: {', '.join(sorted(known))}")
    return replace(RewardWeights(), **(overrides or {}))


def load_actor_into(model, actor: MlpActor) -> None:
    """Warm start: copy a saved actor's weights into a fresh PPO policy (the critic starts anew)."""
    import torch

    linears = _actor_layers(model)
    if [tuple(m.weight.shape) for m in linears] != [w.shape for w in actor.weights]:
        raise ValueError("the saved actor's layer sizes differ from this training's network")
    with torch.no_grad():
        for layer, w, b in zip(linears, actor.weights, actor.biases):
            layer.weight.copy_(torch.as_tensor(w))
            layer.bias.copy_(torch.as_tensor(b))


def mirrored_rollout(buffer, policy):
    """The rollout with every environment's transitions also reflected left/right, as extra environments.

    A mirrored transition keeps its reward, value, return and advantage (the task is symmetric);
    its old log-probability is the current policy's, on the mirrored observation and action,
    computed before the update, as PPO's ratio needs."""
    import torch
    from stable_baselines3.common.buffers import RolloutBuffer

    from benchmark.trial.symmetry import mirror_joints, mirror_rl_observation

    steps, envs = buffer.buffer_size, buffer.n_envs
    out = RolloutBuffer(steps, buffer.observation_space, buffer.action_space, device=buffer.device,
                        gae_lambda=buffer.gae_lambda, gamma=buffer.gamma, n_envs=2 * envs)
    observations = mirror_rl_observation(buffer.observations).astype(np.float32)
    actions = mirror_joints(buffer.actions).astype(np.float32)
    with torch.no_grad():
        _, log_probs, _ = policy.evaluate_actions(torch.as_tensor(observations.reshape(steps * envs, -1)),
                                                  torch.as_tensor(actions.reshape(steps * envs, -1)))
    out.observations = np.concatenate([buffer.observations, observations], axis=1)
    out.actions = np.concatenate([buffer.actions, actions], axis=1)
    out.log_probs = np.concatenate([buffer.log_probs, log_probs.numpy().reshape(steps, envs)], axis=1)
    for name in ("rewards", "returns", "episode_starts", "values", "advantages"):
        setattr(out, name, np.concatenate([getattr(buffer, name)] * 2, axis=1))
    out.full, out.pos = True, steps
    return out


def mirror_tensors(obs_dim: int, joints: int):
    """The left/right mirrors of observations and actions as float32 tensors, x -> x @ M (`mirror_matrices`)."""
    import torch

    from benchmark.trial.symmetry import mirror_matrices

    return tuple(torch.as_tensor(m, dtype=torch.float32) for m in mirror_matrices(obs_dim, joints))


def mirror_loss_step(policy, observations: np.ndarray, weight: float, batch_size: int, epochs: int) -> float:
    """Pull the actor toward left/right equivariance: minimise weight * |mu(s) - M mu(M s)|^2 over the
    rollout's observations (a symmetry loss, Mittal et al. 2024), with PPO's own optimizer. Without it,
    augmentation alone left a fine-tuned A1 actor asymmetric, so that its symmetric inference (the mean of
    both answers) walked at half speed. Returns the RMS of mu(s) - M mu(M s) before the step (actions)."""
    import torch

    obs_mirror, action_mirror = mirror_tensors(observations.shape[-1], policy.action_space.shape[0])
    obs = torch.as_tensor(observations, dtype=torch.float32)
    mirrored = obs @ obs_mirror

    def gap(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        mean = lambda x: policy.get_distribution(x).distribution.mean  # noqa: E731
        return mean(a) - mean(b) @ action_mirror

    with torch.no_grad():
        before = float(gap(obs, mirrored).pow(2).mean().sqrt())
    for _ in range(epochs):
        for batch in torch.randperm(len(obs)).split(batch_size):
            loss = weight * gap(obs[batch], mirrored[batch]).pow(2).sum(dim=1).mean()
            policy.optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
            policy.optimizer.step()
    return before


def symmetric_actor_policy():
    """An SB3 ActorCriticPolicy whose Gaussian mean is mu_sym(s) = (mu(s) + M mu(M s)) / 2.

    The shipped runner answers with the same mean (`MlpActor.symmetric`), so PPO optimises exactly the
    policy that is run, and it is mirror-equivariant at every update: unlike a symmetry loss, nothing
    pulls the plain actor toward a gait that is its own mirror image (a bound); a trot stays allowed."""
    from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy

    class SymmetricActorPolicy(ActorCriticPolicy):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            obs_mirror, action_mirror = mirror_tensors(self.observation_space.shape[0], self.action_space.shape[0])
            self.register_buffer("obs_mirror", obs_mirror, persistent=False)
            self.register_buffer("action_mirror", action_mirror, persistent=False)

        def _plain_mean(self, obs):
            features = BasePolicy.extract_features(self, obs, self.pi_features_extractor)
            return self.action_net(self.mlp_extractor.forward_actor(features))

        def _distribution(self, obs):
            obs = obs.float()
            mean = 0.5 * (self._plain_mean(obs) + self._plain_mean(obs @ self.obs_mirror) @ self.action_mirror)
            return self.action_dist.proba_distribution(mean, self.log_std)

        def forward(self, obs, deterministic: bool = False):
            distribution = self._distribution(obs)
            actions = distribution.get_actions(deterministic=deterministic)
            return actions.reshape((-1, *self.action_space.shape)), self.predict_values(obs), \
                distribution.log_prob(actions)

        def evaluate_actions(self, obs, actions):
            distribution = self._distribution(obs)
            return self.predict_values(obs), distribution.log_prob(actions), distribution.entropy()

        def get_distribution(self, obs):
            return self._distribution(obs)

    return SymmetricActorPolicy


def symmetric_ppo(mirror_loss: float = 0.0):
    """stable-baselines3's PPO, updating on each rollout and its mirror image (`mirrored_rollout`), then,
    when `mirror_loss` > 0, on the symmetry loss (`mirror_loss_step`); `mirror_error` holds the RMS
    asymmetry of the actor before the last such step."""
    from stable_baselines3 import PPO

    class SymmetricPPO(PPO):
        mirror_error: float | None = None

        def train(self) -> None:
            rollout = self.rollout_buffer
            self.rollout_buffer = mirrored_rollout(rollout, self.policy)
            try:
                super().train()
            finally:
                self.rollout_buffer = rollout
            observations = rollout.observations.reshape(-1, rollout.observations.shape[-1])
            self.mirror_error = mirror_loss_step(self.policy, observations, mirror_loss, self.batch_size,
                                                 self.n_epochs if mirror_loss > 0 else 0)

    return SymmetricPPO


def train(config: TrainConfig, stop: Callable[[], bool] = lambda: False, command: str = "bench train") -> Path:
    """Train, evaluating every `eval_every` steps and once at the end; returns the policy.npz path.
    Training ends early (saved and evaluated as usual) once `stop()` is true; `command` is recorded
    in policy.json as the line that made it."""
    import torch
    import torch.nn as nn
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor
    from tqdm import tqdm

    from benchmark.training.envs import LocomotionEnv

    c = config
    robot, sims, steps, seed, out, eval_every, rewards = c.robot, list(c.sim), c.steps, c.seed, c.out_dir, \
        c.eval_every, c.rewards
    init_from = Path(c.init_from) if c.init_from else None
    rough_share, eval_terrain = c.rough_share, c.eval_terrain
    torch.set_num_threads(1)  # two threads collapse throughput on a 2-core machine
    out.mkdir(parents=True, exist_ok=True)

    def make(i: int):
        # spread the rough environments evenly; at 0.5 they alternate flat, rough, flat, ...
        terrain = "rough" if int((i + 1) * rough_share) > int(i * rough_share) else "flat"
        sim = sims[(i // 2) % len(sims)]  # engines in pairs of environments, so each sees both terrains
        return lambda: LocomotionEnv(robot, sim, terrain, terrain_seed=i, rewards=rewards)

    vec = VecMonitor(DummyVecEnv([make(i) for i in range(c.num_envs)]))
    vec.seed(seed)
    log_std = float(np.log(c.exploration_rad / load_robot(robot).action_scale))
    net = list(c.net)
    algorithm = symmetric_ppo(c.mirror_loss) if c.mirror else PPO
    policy = symmetric_actor_policy() if c.symmetric_actor else "MlpPolicy"
    model = algorithm(policy, vec, seed=seed, device="cpu", verbose=0, **asdict(c.ppo),
                policy_kwargs=dict(net_arch=dict(pi=net, vf=net), activation_fn=nn.ELU, log_std_init=log_std))
    if init_from is not None:
        load_actor_into(model, MlpActor.load(init_from))
    started = time.perf_counter()

    def meta(done: int) -> dict:
        import gymnasium
        import mujoco
        import stable_baselines3

        return {"robot": robot, "trained_in": "+".join(sims), "env_steps": done, "seed": seed,
                "wall_s": round(time.perf_counter() - started, 1), "command": command,
                "versions": {"python": platform.python_version(), "torch": torch.__version__,
                             "stable_baselines3": stable_baselines3.__version__, "gymnasium": gymnasium.__version__,
                             "mujoco": mujoco.__version__}, "ppo": asdict(c.ppo), "mirror": c.mirror, "mirror_loss": c.mirror_loss,
                "symmetric": c.mirror or c.symmetric_actor,
                "symmetric_actor": c.symmetric_actor, "net": net, "rewards": asdict(rewards),
                "init_from": None if init_from is None else {"path": str(init_from),
                                                             **MlpActor.load(init_from).meta}}

    log_path = out / "train_log.csv"
    fields = ["env_steps", "wall_s", "ep_reward_mean", "ep_len_mean", "eval_nwt", "eval_distance_m", "eval_vx",
              "eval_drift_m", "mirror_error"]

    class Progress(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(total=steps, unit="step", desc=f"PPO {robot}/{'+'.join(sims)}", file=sys.stderr, disable=None)
            self.next_eval, self.evaluated_at = eval_every, None
            with log_path.open("w", newline="") as f:
                csv.writer(f).writerow(fields)

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            if self.num_timesteps >= self.next_eval:
                self.next_eval += eval_every
                self._evaluate()
            return not stop()

        def _evaluate(self) -> None:
            self.evaluated_at = self.num_timesteps
            actor = export_actor(self.model, meta(self.num_timesteps))
            actor.save(out / "policy.npz")
            cell = CellSpec(sim=sims[0], robot=robot, terrain=eval_terrain, policy="rl",
                            settings=SeedSettings(policy_file=str(out / "policy.npz")))
            trial = run_cell(cell, [0])[0]
            episodes = list(self.model.ep_info_buffer)
            row = [self.num_timesteps, round(time.perf_counter() - started, 1),
                   round(float(np.mean([e["r"] for e in episodes])), 2) if episodes else "",
                   round(float(np.mean([e["l"] for e in episodes])), 1) if episodes else "",
                   round(trial.nwt, 3), round(trial.distance_m, 2), round(trial.mean_vx, 3),
                   round(trial.lateral_drift_m, 2),
                   "" if getattr(self.model, "mirror_error", None) is None else round(self.model.mirror_error, 4)]
            with log_path.open("a", newline="") as f:
                csv.writer(f).writerow(row)
            self.bar.set_postfix(nwt=row[4], vx=row[6], rew=row[2])
            if self.bar.disable:  # not a terminal: one line per evaluation instead of a bar
                print(f"train: {row[0]} steps, {row[1]} s, reward {row[2]}, eval nwt {row[4]} vx {row[6]}",
                      file=sys.stderr, flush=True)

        def _on_training_end(self) -> None:
            if self.evaluated_at != self.num_timesteps:  # the final policy, evaluated once
                self._evaluate()
            self.bar.close()

    model.learn(total_timesteps=steps, callback=Progress())
    actor = export_actor(model, meta(model.num_timesteps))
    actor.save(out / "policy.npz")
    model.save(out / "ppo_model.zip")  # the full SB3 model (optimizer included), to resume; not shipped
    vec.close()
    if c.ship:
        ship_policy(out / "policy.npz", robot)
    return out / "policy.npz"


def ship_policy(path: Path, robot: str) -> Path:
    """Install a trained actor as `robots/<robot>/policy.npz`, its metadata beside it as policy.json."""
    actor = MlpActor.load(path)
    if actor.meta.get("robot") != robot:
        raise ValueError(f"{path} was trained for robot '{actor.meta.get('robot')}', not '{robot}'")
    folder = load_robot(robot).folder
    target = folder / "policy.npz"
    actor.save(target)
    (folder / "policy.json").write_text(json.dumps(actor.meta, indent=2) + "\n")
    return target
