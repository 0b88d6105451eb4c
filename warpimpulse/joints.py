"""The joint catalogue: every joint type is a list of basic constraints (method paper, section 4.4).

The math of each basic constraint (error, projection, Jacobian) lives once, in `kernels/constraints.py`.
"""

from __future__ import annotations

from .types import ConstraintKind

C = ConstraintKind
JOINT_TYPES: dict[str, tuple[ConstraintKind, ...]] = {
    "ball": (C.POINT,),
    "revolute": (C.POINT, C.AXIS),
    "prismatic": (C.LINE, C.ROTATION),
    "cylindrical": (C.LINE, C.AXIS),
    "universal": (C.POINT, C.ANGLE),
    "fixed": (C.POINT, C.ROTATION),
    "planar": (C.PLANE, C.AXIS),
}
