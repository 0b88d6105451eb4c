"""Names and codes shared by the host and the kernels: one source for each.

The kernels read these through `wp.constant` (see `kernels/constraints.py`, `kernels/assemble.py`), the host
through the enums, and the CLI offers the same tuples as its choices.
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import IntEnum

import numpy as np

Vec3 = Sequence[float] | np.ndarray
"""Three floats: a point or direction in metres, a velocity in m/s or rad/s, a force in N or torque in N m."""

Quat = Sequence[float] | np.ndarray
"""A rotation as a quaternion in (x, y, z, w) order, real part last, as in Warp (USD's `Gf.Quat*` constructors
take the real part first)."""

WORLD = -1
"""The body index of the world: a joint's parent may be the world (fixed, infinite mass)."""


class ConstraintKind(IntEnum):
    """The six basic constraints of sections 4.2 (translational) and 4.3 (rotational) of the method paper.

    The values are the codes the kernels switch on; `dim` is the number of removed degrees of freedom.
    """

    POINT = 0  # spherical: A = B
    LINE = 1  # B stays on a line through A, fixed to body0
    PLANE = 2  # B stays in a plane through A, fixed to body0
    ROTATION = 3  # fixed relative rotation
    AXIS = 4  # common rotation axis ("orientation joint")
    ANGLE = 5  # constant angle between an axis of each body

    @property
    def dim(self) -> int:
        return (3, 2, 1, 3, 2, 1)[self]

    @property
    def translational(self) -> bool:
        return self < ConstraintKind.ROTATION

    @property
    def needs_axis(self) -> bool:
        return self in (ConstraintKind.LINE, ConstraintKind.PLANE, ConstraintKind.AXIS, ConstraintKind.ANGLE)

    @classmethod
    def parse(cls, kind: ConstraintKind | str | int) -> ConstraintKind:
        if isinstance(kind, str):
            try:
                return cls[kind.upper()]
            except KeyError:
                names = [k.name.lower() for k in cls]
                raise ValueError(f"unknown constraint kind {kind!r}; expected one of {names}") from None
        return cls(kind)


class Slot(IntEnum):
    """What a 3x3 block of the augmented matrix [[M, J^T], [J, 0]] holds (`topology.body_pattern` writes the
    codes, `kernels/assemble.py` reads them)."""

    ZERO = 0
    MASS = 1  # m I of a body
    INERTIA = 2  # the world inertia tensor of a body
    JLIN = 3  # a constraint's linear Jacobian block on a body
    JANG = 4  # its angular block
    JLIN_T = 5  # the transposes, above the diagonal
    JANG_T = 6
    PAD = 7  # a constraint's diagonal: -1 on the rows a constraint of dimension < 3 does not use


SOLVERS = ("auto", "cholesky", "cg", "iterative")
"""`Simulator(solver=...)`. "auto" is "cholesky": one exact factorization a step serves the velocity correction
and the next step's joint correction, and a tree's factor is linear in its joints; "cg" iterates on the same K;
"iterative" is the paper's sweep over joints one at a time, without a system (the baseline)."""

FORMULATIONS = ("constraint", "body", "split")
"""The matrix the Cholesky solver factors: K = J M^-1 J^T ("constraint"), the augmented body-joint matrix
("body"), or K without its blocks between the tree's and the loop joints' constraints ("split": the method
paper's section 4.6, two systems solved side by side in each iteration of the common loop); see
`topology.Pattern`."""

COORDINATES = {"revolute": 0, "prismatic": 1}
"""The joint types with one coordinate, and its code in the kernels: 0 an angle (rad) about the axis, 1 an
offset (m) along it. Drives (joint springs, motors) and limits act on it."""

DISTANCE_COORDINATE = 2
"""The kernels' code of a distance constraint's coordinate (`SceneBuilder.add_distance`): the distance (m)
between two anchors, limited like a joint coordinate."""

DRIVE_MODES = ("position", "velocity", "effort")
"""`SceneBuilder.add_motor(mode=...)`; the index is the code the kernels read. "effort" is the target itself as
the torque (N m) or force (N), the gains unused: MuJoCo's `motor` actuator."""

SCHEDULES = ("auto", "fused", "parallel")
"""`Simulator(schedule=...)`: how a step's stages are launched. "fused" runs whole steps (many a launch) on one
thread, the stages' funcs in serial loops (`kernels/step.py`); "parallel" launches each stage over its bodies,
constraints or columns, replayed as captured graphs, the host deciding between them. "auto" is fused on a CPU
(where a launch is one thread anyway) and parallel on a GPU."""

NEWTON_BODIES = 16384
"""Bodies from which `Simulator(newton=None)` takes the first joint iteration's Newton step (scenes without
kinematic loops): below, a scene's arrays stay in cache and the correction costs about the iteration it saves;
about here it starts to pay (`benchmarks/step_breakdown.py`'s Newton table: the 65,535-body tree 0.89 of the
time, the 16,383-body tree faster in two of three runs, the 4,095-body tree not)."""

DIVERGENCE_GROWTH = 1.0e3
DIVERGENCE_AFTER = 3
"""A correction diverges when, after at least DIVERGENCE_AFTER iterations, its error has grown more than
DIVERGENCE_GROWTH-fold over the smallest it reached: it stops there (and the step is halved) instead of running
to its iteration limit. One rule for every correction loop: `kernels/loop.py` `diverging` on the device, its
host twin `diverging` in `warpimpulse/steps.py`."""

BodyRef = int | str | None
"""A body: its index, its name, or None for the world."""

Names = str | Sequence[str] | None
"""Names of rows added at once: None ("body<index>", "joint<index>"), a format template filled with each row's
index ("b{}"), or one name per row."""

REFACTOR_EVERY = 8
"""With `StepOptions.reuse_factor`, the most accepted (sub)steps one factor of K serves (`kernels/step.py`)."""

STALE_FACTOR_RATE = 0.25
"""With `StepOptions.reuse_factor`: a joint solve with an older factor of K that leaves more than this fraction
of the error before it has K factored at the stage's start (`kernels/step.py` `stale_rate`)."""
