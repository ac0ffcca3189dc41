"""Experiments: the TOML grids beside this file (`experiment`), the resumable parallel sweep into a
results store (`sweep`) and the reports made from a store (`report`, `report_latency`). May import
`benchmark.llm`, `benchmark.trial` and `benchmark.common`."""
