"""Newton's own options, importable without importing warp or newton."""

from __future__ import annotations

from dataclasses import dataclass, field

SOLVERS = ("mujoco", "featherstone")
CONTACTS = ("newton", "mujoco")


@dataclass(frozen=True)
class NewtonOptions:
    device: str | None = field(default=None, metadata={
        "help": "newton: cpu, cuda or cuda:N (default cuda when present, else cpu)"})
    solver: str = field(default="mujoco", metadata={
        "help": "newton: mujoco (SolverMuJoCo on mujoco_warp) or featherstone (faster, NaN on heightfields)",
        "choices": SOLVERS, "noun": "newton solver"})
    contacts: str = field(default="newton", metadata={
        "help": "newton: collision detection: newton (Newton's own CollisionPipeline; right on heightfields) or "
                "mujoco (mujoco_warp's; drops foot contacts on heightfields, mujoco_warp issue #1083)",
        "choices": CONTACTS, "noun": "newton contact pipeline"})

    def __post_init__(self) -> None:
        from robots import UnknownNameError

        if self.solver not in SOLVERS:
            raise UnknownNameError("newton solver", self.solver, SOLVERS)
        if self.contacts not in CONTACTS:
            raise UnknownNameError("newton contact pipeline", self.contacts, CONTACTS)
        d = self.device
        if d is not None and d not in ("cpu", "cuda") and not d.startswith("cuda:"):
            raise ValueError(f"unknown device '{d}'; valid: cpu, cuda, cuda:N")
