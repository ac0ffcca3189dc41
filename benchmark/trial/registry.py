"""The policy registry: Gymnasium-style entry points ("module:Class"), loaded lazily.

A built-in policy is one line in POLICIES; another installed package adds its own through the
`promptwalk.policies` entry-point group (see `benchmark.plugins`). A policy with settings names
their dataclass; its fields become `bench run` options and experiment keys.
"""

from __future__ import annotations

from dataclasses import dataclass

from sims import PluginTable, load_entry_point


@dataclass(frozen=True)
class PolicyEntry:
    name: str
    entry_point: str  # "module:Class" implementing Policy
    help: str
    settings: str | None = None  # "module:Dataclass" of its settings, if any
    duration: float = 10.0  # s, the default episode of a cell with this policy

    def settings_class(self) -> type | None:
        return load_entry_point(self.settings) if self.settings else None


POLICIES: PluginTable = PluginTable({e.name: e for e in (
    PolicyEntry("llm", "benchmark.llm.controller:LLMPolicy",
                "the paper's protocol: seed policy fills the prompt history, then the LLM drives",
                settings="benchmark.llm.controller:LLMSettings", duration=20.0),
    PolicyEntry("stand", "benchmark.trial.policies:StandPolicy", "holds the default pose; cannot walk"),
    PolicyEntry("rl", "benchmark.trial.policies:SeedPolicy", "the robot's shipped PPO seed policy (or --policy-file)",
                settings="benchmark.trial.policies:SeedSettings"),
)}, "promptwalk.policies", "policy", kind=PolicyEntry)


def available_policies() -> list[str]:
    return POLICIES.names()


def policy_entry(name: str) -> PolicyEntry:
    return POLICIES.get_named(name)
