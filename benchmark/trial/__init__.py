"""One trial, robot -> engine -> observation -> policy -> targets -> engine: the cell that describes
it (`cell`), the policy registry and the built-in policies (`registry`, `policy`, `policies`, `mlp`,
`symmetry`), the 10 Hz control loop, falls and the realtime clock (`control`, `falls`, `clock`),
the episode runner and its metrics (`runner`), `run_cell` (`trials`) and Rerun recordings
(`recorder`). May import `benchmark.common`, `sims` and `robots`; nothing above it."""
