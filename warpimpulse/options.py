"""`StepOptions`: how a step is carried out, for experts and benchmarks.

A user decides what to simulate and how exactly (`Simulator(model, dt, tolerance=..., solver=..., order=...)`);
how the step is then scheduled and which shortcuts it takes are chosen from the scene and the machine. Each
switch here defaults to that choice ("auto" or None); setting one pins it, and a pinned switch the scene cannot
honour is refused at construction with one line naming why (`capabilities.py`).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass


@dataclass(frozen=True)
class StepOptions:
    """Performance switches of `Simulator`; every default chooses itself.

    Attributes:
        schedule: "auto", "fused" or "parallel" (`types.SCHEDULES`). "fused" runs whole steps (many a launch) as
            one kernel on a CPU; "parallel" launches each stage, what a GPU runs. "auto": parallel on a GPU,
            fused on a CPU wherever the scene allows (`capabilities.TABLE`).
        formulation: "auto", "constraint", "body" or "split": the matrix the Cholesky solver factors
            (`topology.Pattern`). "auto" takes the augmented body-joint matrix only where a body has many joints
            and the scene has no loops; it never takes "split" (the paper's section 4.6, about 10x the iterations
            of one matrix on the four-bar, docs/mechanisms.md).
        scheme: the composition of `order` 4 or 6 by name (`composition.SCHEMES`); None takes the measured best.
        newton: the first joint iteration of each step takes a Newton step: its impulses solved again with the
            right-hand side less E lambda, E the change of the Jacobian and of the bodies' turn over the step
            (`constraints.arm_correction`), so that the error falls quadratically. It costs a solve and two passes
            and saves about one iteration where a step takes two: it pays where a prediction costs more than a
            solve. None: on scenes of
            `types.NEWTON_BODIES` bodies or more without loops (whose redundant rows it leaves inconsistent), with
            the cholesky solver; threads never take it.
        carry: the first joint iteration adds to its right-hand side what the first iteration of the last step of
            the same size left unsolved (about -E lambda, which changes little from step to step;
            `kernels/carry.py`); later iterations solve for the residual they measure, so the tolerance holds the
            same. None: on with the cholesky solver without contacts (True elsewhere is a ValueError).
            Checkpoints keep it; `reset` and `set_state` forget it.
        defer_velocities: correct the velocities (the paper's section 4.2) only where they are handed out: when
            they are first read (`Simulator.state`, `linear_velocities`, ...; positions and orientations need
            none; a checkpoint keeps them due). The velocity
            correction's impulse acts through the Jacobians of the next step's t0, as the joint correction's do,
            so the next joint correction reaches the same state ("not absolutely necessary ... because the joint
            impulse of the next simulation step will solve the problem as well"); steps taken one `step()` a
            call then reach the state of one `step(n)` bit for bit. A deferred step's StepStats counts no
            velocity iteration and its `max_velocity_error` is NaN. None: on with the cholesky solver in scenes
            without force elements (velocity-dependent), rows, contacts, batched worlds or the split formulation
            (True there is a ValueError).
        reuse_factor: factor K = J M^-1 J^T only where the factor in use no longer serves, not at every accepted
            (sub)step (the fused schedule; `kernels/step.py`). The joint correction then solves with K of an earlier
            state: a quasi-Newton iteration whose error is measured on the real prediction and whose impulses act
            through the current Jacobians, so the tolerance holds the same and only the solve count changes. The kernel
            decides on the device (`older_factor`): K is factored where the velocities are corrected (where they are
            read, `Simulator.state`, or every step without `defer_velocities`: their one solve is exact only with K of
            that state), at every `types.REFACTOR_EVERY`-th stage, at a stage's start when a solve with the older factor
            left more than `types.STALE_FACTOR_RATE` of the error, and where a stage took more solves with the older
            factor than with K of its own start (for a doubling hold of stages where the factor had not paid). Measured
            (benchmarks/reuse_factor.py, docs/history.md), `step(240)` at tolerance 1e-6: at order 4 and h = 1/480,
            0.68-0.81 of the time on chains of 20 and 50 and the paper's tree, 0.94-0.96 on the arm and the humanoid; at
            order 2 and h = 1/480 0.71 on the tree; at h = 1/120 1.00-1.05 on serial scenes (0.95 on the tree at order
            4). None: on at order 4 and 6 (whose stages go back and forth about the step), off at order 2. True is a
            ValueError where it is not taken: the parallel schedule, threads' split step (threads > 1), another solver,
            the split formulation, rows (limits, stiff motors, distance constraints: their system S is formed with K^-1)
            and loops (the factorization decides their redundant rows).
        split_forces: force elements that depend on the poses alone (springs without dampers, joint springs,
            position drives without kd or ki, effort motors) act as two half kicks about each base step,
            dv = M^-1 F(q) h / 2 before its prediction and again at its accepted poses (Strang's splitting: the
            step stays symmetric, so orders 4 and 6 compose from it), and the prediction is each body's own
            instead of the coupled RK4 that evaluates every element at each of its stages for every joint
            iteration. None: wherever every element allows it (one world; no element stiff for dt, whose
            kick would be unstable from h omega = 2); True elsewhere is a ValueError naming what stands in the way.
        specialize: compile the constraint kernels for the scene's constraint kinds only (one module per set of
            kinds, cached on disk); False shares one module for all kinds.
        max_rotation: a step in which some body would turn further than this (rad) is taken as 2, 4, ... equal
            substeps (the method is second order in the rotation per step); None takes every step whole.
        max_substep_depth: a failing step is halved down to dt / 2**max_substep_depth before it fails.
        broad_phase: "bvh" or "all_pairs" (`contacts.BROAD_PHASES`).
        contact_sweeps: Gauss-Seidel sweeps over the contacts at most per position solve ("pgs").
    """

    schedule: str = "auto"
    formulation: str = "auto"
    scheme: str | None = None
    newton: bool | None = None
    carry: bool | None = None
    defer_velocities: bool | None = None
    reuse_factor: bool | None = None
    split_forces: bool | None = None
    specialize: bool = True
    max_rotation: float | None = 0.5
    max_substep_depth: int = 7
    broad_phase: str = "bvh"
    contact_sweeps: int = 30

    def replace(self, **changes) -> StepOptions:
        """A copy with `changes` (field names as keywords)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def fold(cls, settings: dict) -> dict:
        """`Simulator` keywords kept as one mapping (a sweep's point, a benchmark's variant) with the switches
        among them folded into `options` (over those of an `options` already there)."""
        switches = {k: v for k, v in settings.items() if k in NAMES}
        rest = {k: v for k, v in settings.items() if k not in NAMES}
        if switches:
            rest["options"] = (rest.get("options") or cls()).replace(**switches)
        return rest


NAMES = frozenset(f.name for f in dataclasses.fields(StepOptions))


def resolve(options: StepOptions | None, legacy: dict, owner: str = "Simulator") -> StepOptions:
    """`options` with the switches passed the old way, as keywords of `owner` (deprecated: a
    DeprecationWarning names each and its new spelling); any other keyword is a TypeError, as Python's own."""
    if options is not None and not isinstance(options, StepOptions):
        raise TypeError(f"options must be a warpimpulse.StepOptions, got {type(options).__name__}")
    unknown = sorted(set(legacy) - NAMES)
    if unknown:
        raise TypeError(f"{owner}() got an unexpected keyword argument {unknown[0]!r}")
    options = options or StepOptions()
    if legacy:
        spelled = ", ".join(f"{k}={v!r}" for k, v in legacy.items())
        warnings.warn(
            f"{owner}({spelled}) is deprecated and will be removed in the next release: pass "
            f"options=warpimpulse.StepOptions({spelled})",
            DeprecationWarning,
            stacklevel=3,
        )
        options = options.replace(**legacy)
    return options


def take(settings: dict, owner: str) -> StepOptions:
    """Pop `options` and any switch passed the old way out of a wrapper's `settings` (keywords it hands on to
    `Simulator`), resolved as `resolve` does."""
    legacy = {name: settings.pop(name) for name in list(settings) if name in NAMES}
    return resolve(settings.pop("options", None), legacy, owner)
