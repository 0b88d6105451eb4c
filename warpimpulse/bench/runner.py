"""What the harness asks of every engine it measures (ours and the peers), and how a run fails."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class StepFailed(RuntimeError):
    """The engine diverged or gave up (did not converge); the configuration is reported as failed."""


class Runner(Protocol):
    """One engine on one scene at one step size, from the scene's initial state."""

    def step(self) -> None:
        """Advance one step of 1/rate seconds; raise StepFailed where the engine reports a failure itself."""

    # Optional: `run(steps)`, the engine's own call for many steps (ours `Simulator.step(n)`, MuJoCo `mj_step`'s
    # nstep), which the timed loop uses where an engine has one (`advance`): each engine is timed through its
    # fastest public call, not through one Python call a step.

    def check(self) -> None:
        """Raise StepFailed if the state has diverged (called at the sampling points, outside timed loops)."""

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres of mass (N, 3, m, world) and orientations (N, 4, quaternions (x, y, z, w)), builder order."""

    def energy(self) -> tuple[float, float]:
        """(total, kinetic) in J; kinetic is NaN where the engine does not report it apart."""


def advance(runner: Runner, steps: int) -> None:
    """`steps` steps of a runner: its `run` where it has one, else one step() at a time."""
    run = getattr(runner, "run", None)
    if run is not None:
        run(steps)
        return
    for _ in range(steps):
        runner.step()
