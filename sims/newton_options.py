"""Newton's own options, importable without importing warp or newton."""

from __future__ import annotations

from dataclasses import dataclass, field

SOLVERS = ("mujoco", "featherstone")


@dataclass(frozen=True)
class NewtonOptions:
    device: str | None = field(default=None, metadata={
        "help": "newton: cpu, cuda or cuda:N (default cuda when present, else cpu)"})
    solver: str = field(default="mujoco", metadata={
        "help": "newton: mujoco (SolverMuJoCo on mujoco_warp) or featherstone (faster, NaN on heightfields)",
        "choices": SOLVERS, "noun": "newton solver"})

    def __post_init__(self) -> None:
        from robots import UnknownNameError

        if self.solver not in SOLVERS:
            raise UnknownNameError("newton solver", self.solver, SOLVERS)
        d = self.device
        if d is not None and d not in ("cpu", "cuda") and not d.startswith("cuda:"):
            raise ValueError(f"unknown device '{d}'; valid: cpu, cuda, cuda:N")
