"""Seed-policy training: the Gymnasium environment over the trial's own control loop (`envs`), the
walking rewards (`rewards`) and stable-baselines3 PPO with the mirror symmetry (`train`). May import
`benchmark.trial` and `benchmark.common`; nothing imports it but the CLI."""
