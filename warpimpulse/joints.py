"""The joint catalogue: every joint type is a list of basic constraints (method paper, section 4.4).

The math of each basic constraint (error, projection, Jacobian) lives once, in `kernels/constraints.py`.
"""

from __future__ import annotations

from enum import IntEnum


class ConstraintKind(IntEnum):
    """The six basic constraints of sections 4.2 (translational) and 4.3 (rotational).

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
