"""What a step reports: its StepStats, and the SimulationError that ends a run (kept apart from the
simulator so that the batched worlds' step, `worlds.py`, reports the same way without importing it)."""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass

from .types import DIVERGENCE_AFTER, DIVERGENCE_GROWTH


def diverging(error: float, best: float, iterations: int) -> bool:
    """Whether a correction diverges: the host twin of `kernels/loop.py` `diverging` (`types.DIVERGENCE_GROWTH`),
    for the loops the host decides."""
    return iterations >= DIVERGENCE_AFTER and error > DIVERGENCE_GROWTH * best


class SimulationError(RuntimeError):
    """The simulation cannot go on: divergence (NaN/Inf) or joints that did not converge."""


@dataclass(eq=False)
class StepStats:
    joint_iterations: int  # linear solves (or sweeps) of the joint correction
    velocity_iterations: int
    max_joint_error: float  # after the joint correction, in m or rad
    # After the velocity correction, in m/s or rad/s; NaN where the step deferred it to the next step's joint
    # correction (`Simulator.defer_velocities`: its velocities were not handed out, nor measured).
    max_velocity_error: float
    converged: bool = True
    linear_iterations: int = 0  # linear solves (Cholesky) or inner CG iterations, summed over the step
    substeps: int = 1  # > 1 when a fast spin split the step, or a failing step was redone as smaller ones
    order: int = 2  # the order in time the step was taken at (Simulator's `order`, unless it fell back)
    fallback: str = ""  # why a step asked at order 4 or 6 was taken at order 2 (a non-reversible event)
    contacts: int = 0  # contact points detected (in the last substep)
    max_penetration: float = 0.0  # m, the deepest contact after the position correction
    contact_sweeps: int = 0  # Gauss-Seidel sweeps over the contacts, both phases, summed over the step
    # s: with `Simulator(accuracy=...)`, the step the controller took (the smallest of combined steps); NaN with
    # fixed steps, whose size is `Simulator.dt`.
    step_size: float = math.nan
    # m: with `Simulator(accuracy=...)`, the estimated trajectory error of the body centres at the step's end
    # (`accuracy.Controller`: the gap to a shadow run at twice the step over 2^order - 1, read every few
    # intervals); NaN without.
    error_estimate: float = math.nan

    def __eq__(self, other: object) -> bool:
        """Every figure the same, a velocity error not measured (NaN) like another."""
        if not isinstance(other, StepStats):
            return NotImplemented
        return _figures(self) == _figures(other)


def _figures(stats: StepStats) -> tuple:
    return tuple("NaN" if isinstance(v, float) and math.isnan(v) else v for v in astuple(stats))


ROWS_FALLBACK = "joint limits, stiff motors or distance rows (impacts and saturation are not reversible)"
"""Why a scene with such rows takes its steps at order 2 whatever order was asked: a composed step would run
them backwards in its negative substeps (`StepStats.fallback`)."""


def combined(parts: list[StepStats]) -> StepStats:
    """The stats of one step taken as consecutive substeps."""
    return StepStats(
        sum(p.joint_iterations for p in parts),
        sum(p.velocity_iterations for p in parts),
        max(p.max_joint_error for p in parts),
        parts[-1].max_velocity_error,
        all(p.converged for p in parts),
        sum(p.linear_iterations for p in parts),
        sum(p.substeps for p in parts),
        min(p.order for p in parts),
        next((p.fallback for p in parts if p.fallback), ""),
        parts[-1].contacts,
        max(p.max_penetration for p in parts),
        sum(p.contact_sweeps for p in parts),
        min((p.step_size for p in parts if not math.isnan(p.step_size)), default=math.nan),
        sum(p.error_estimate for p in parts),
    )
