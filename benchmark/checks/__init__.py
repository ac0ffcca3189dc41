"""Checks of engines, robots and seed policies, each writing a report: joint responses against a
one-joint model (`validate`), gait posture and contact pattern (`gait`), walking straight
(`straight`) and the framework's speed against the raw engine (`perf`). May import
`benchmark.trial` and `benchmark.common`."""
