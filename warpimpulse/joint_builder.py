"""Joints on the builder: each joint type a list of basic constraints, added one or many at a time.

A joint's anchor and axes are given in world coordinates at build time and stored in each body's frame; its basic
constraints (the method paper's sections 4.2-4.3) are rows of the builder's constraint table, checked when added
and named by the joint (`joints.py` has the catalogue)."""

from __future__ import annotations

import numpy as np

from . import checks
from .checks import SceneError
from .joints import JOINT_TYPES
from .transforms import mul_components, quat_conj, rotate_components
from .types import WORLD, BodyRef, ConstraintKind, Names, Vec3


def _rows(value, count: int, shape: tuple[int, ...], what: str) -> np.ndarray:
    """`value` as (count, *shape) floats: one row per item, or one value (or a single number) for all."""
    arr = checks.numbers(value, what)
    if arr.shape == (count, *shape):
        return arr
    if count == 1 and (arr.shape == shape or arr.ndim == 0):  # one row (add_body, add_joint): broadcast_to's
        return arr[None] if arr.shape == shape else np.full((1, *shape), arr)  # values, without its overhead
    if arr.shape == shape or arr.ndim == 0:
        return np.broadcast_to(arr, (count, *shape))
    if not shape:
        raise SceneError(f"{what} must be a single number or {count} numbers, got {value!r}")
    if len(shape) == 1:
        raise SceneError(f"{what} must have {shape[0]} components, got shape {arr.shape}")
    raise SceneError(f"{what} must have shape {shape} or {(count, *shape)}, got shape {arr.shape}")


def _dot(a: list, b: list) -> np.ndarray:
    """Row-wise dot products (n,) of 3-vectors given as `_parts`, component by component: a row gives the same
    bits in a batch of any size (a reduction might not)."""
    (ax, ay, az), (bx, by, bz) = a, b
    return np.asarray(ax * bx + ay * by + az * bz).reshape(-1)  # (np.reshape is slow on a float)


def _parts(rows: np.ndarray) -> list:
    """The components of rows (n, k): k Python floats for one row, else k arrays (n,). The joint geometry is
    written once over components; Python's float arithmetic is numpy's element-wise IEEE double arithmetic, so a
    joint added alone gets the bits it gets in a batch (tests/test_bulk_builder.py), without numpy's per-call
    cost on arrays of one row."""
    return rows[0].tolist() if len(rows) == 1 else [rows[:, k] for k in range(rows.shape[1])]


def _whole(parts) -> np.ndarray:
    """Rows (n, k) from components as `_parts` gives them."""
    return np.stack(parts, axis=-1) if isinstance(parts[0], np.ndarray) else np.array([parts])


def _norms(rows: np.ndarray) -> np.ndarray:
    """The length of each row (n, k), its squares summed component by component, left to right, as `_dot`
    does (on Python floats for one row: the same bits, fewer numpy calls)."""
    parts = _parts(rows)
    squares = parts[0] * parts[0]
    for x in parts[1:]:
        squares = squares + x * x
    return np.sqrt(np.asarray(squares).reshape(-1))


def _unit_rows(value, count: int, what: str, label, field: str) -> np.ndarray:
    """Directions (count, 3), any length but zero, normalised."""
    arr = _rows(value, count, (3,), what)
    checks.finite_rows({field: arr}, label)
    norm = _norms(arr)
    i = checks.first(norm < 1e-12)
    if i is not None:
        raise SceneError(f"{label(i)} {field} is a zero vector")
    return arr / norm[:, None]


class JointBuilder:
    """The joint methods of a `SceneBuilder` (a part of it: they add rows to its joint and constraint tables)."""

    def add_joint_ball(self, parent: BodyRef, child: BodyRef, anchor: Vec3, name: str | None = None) -> int:
        """A spherical joint: the anchor stays common to both bodies (3 translational DOF removed)."""
        return self.add_joint("ball", parent, child, anchor, None, None, name)

    def add_joint_revolute(
        self, parent: BodyRef, child: BodyRef, anchor: Vec3, axis: Vec3, name: str | None = None
    ) -> int:
        """A hinge: the anchor is common and the bodies turn about `axis` only (5 DOF removed)."""
        return self.add_joint("revolute", parent, child, anchor, axis, None, name)

    def add_joint_prismatic(
        self, parent: BodyRef, child: BodyRef, anchor: Vec3, axis: Vec3, name: str | None = None
    ) -> int:
        """A slider: the child's anchor moves along `axis` (fixed to the parent) without turning (5 DOF)."""
        return self.add_joint("prismatic", parent, child, anchor, axis, None, name)

    def add_joint_cylindrical(
        self, parent: BodyRef, child: BodyRef, anchor: Vec3, axis: Vec3, name: str | None = None
    ) -> int:
        """A slider that may also turn about its `axis` (4 DOF removed)."""
        return self.add_joint("cylindrical", parent, child, anchor, axis, None, name)

    def add_joint_universal(
        self,
        parent: BodyRef,
        child: BodyRef,
        anchor: Vec3,
        axis_parent: Vec3,
        axis_child: Vec3,
        name: str | None = None,
    ) -> int:
        """A Cardan joint: the anchor is common and the angle between `axis_parent` (fixed to the parent) and
        `axis_child` (fixed to the child) stays as built (4 DOF removed); the axes must not be parallel."""
        return self.add_joint("universal", parent, child, anchor, axis_parent, axis_child, name)

    def add_joint_fixed(self, parent: BodyRef, child: BodyRef, anchor: Vec3, name: str | None = None) -> int:
        """A weld: the relative pose stays as built (6 DOF removed)."""
        return self.add_joint("fixed", parent, child, anchor, None, None, name)

    def add_joint_planar(
        self, parent: BodyRef, child: BodyRef, anchor: Vec3, normal: Vec3, name: str | None = None
    ) -> int:
        """The child's anchor stays in the plane through the anchor normal to `normal` (fixed to the parent),
        and the child turns only about the normal (3 DOF removed)."""
        return self.add_joint("planar", parent, child, anchor, normal, None, name)

    def add_constraint(self, kind, parent, child, anchor, axis=None, axis_child=None, name=None) -> int:
        """A joint made of one basic constraint (`ConstraintKind` or its name, e.g. "line").

        Combine several on the same pair of bodies to build custom joints. Returns the joint index.
        """
        try:
            kind = ConstraintKind.parse(kind)
        except (ValueError, TypeError) as exc:
            raise SceneError(f"joint {name or f'joint{len(self.joints)}'!r}: {exc}") from None
        return self.add_joint(kind.name.lower(), parent, child, anchor, axis, axis_child, name, (kind,))

    def _body_index(self, index, what: str) -> int:
        if index is None:
            return WORLD
        if isinstance(index, (bool, np.bool_)):  # True would silently mean body 1
            raise SceneError(f"{what}: a body index or name is expected, got {index!r}")
        if isinstance(index, str):
            if index not in self._body_names:
                raise SceneError(f"{what}: no body named {index!r}")
            return self._body_names[index]
        if not isinstance(index, (int, np.integer)):
            raise SceneError(f"{what}: a body index (an integer) or name is expected, got {index!r}")
        if not 0 <= int(index) < len(self.bodies):
            raise SceneError(f"{what}: body index {index!r} does not exist ({len(self.bodies)} bodies)")
        return int(index)

    def add_joint(self, kind, parent, child, anchor, axis=None, axis_child=None, name=None, kinds=None) -> int:
        """A joint of a catalogue type (`joints.JOINT_TYPES`) by name; the typed add_joint_* call this
        (`add_joints` with one joint)."""
        name = self._new_name(name, "joint", self._joints.count)
        what = f"joint {name!r}"
        self._open(what)
        p = self._body_index(parent, f"{what} parent")
        c = self._body_index(child, f"{what} child")
        return int(self._add_joints(kind, np.array([p]), np.array([c]), anchor, axis, axis_child, [name], kinds)[0])

    def add_joints(
        self, kind: str, parent, child, anchor, axis=None, axis_child=None, name: Names = None
    ) -> np.ndarray:
        """Add n joints of one catalogue type at once and return their indices (n,); as `add_joint`, per joint.

        Args:
            kind: the type (`joints.JOINT_TYPES`), for all n.
            parent: (n,) body indices, WORLD (-1) for the world. child: (n,) body indices; its length is n.
            anchor: (n, 3) world points (m), or one for all. axis, axis_child: (n, 3) or one for all, where the
                type takes them.
            name: `Names`: None ("joint<index>"), a template such as "j{}", or n names.
        The checks are those of `add_joint`, vectorised; the first bad joint is named, and nothing is added.
        """
        p, c = (np.asarray(x) for x in (parent, child))
        for side, x in (("parent", p), ("child", c)):
            if x.ndim != 1 or (len(x) and x.dtype.kind not in "iu"):
                raise SceneError(f"add_joints: {side} must be a 1-D array of body indices, got {x!r}")
        if len(p) != len(c):
            raise SceneError(f"add_joints: {len(p)} parents for {len(c)} children")
        names = self._names(name, "joint", self._joints.count, len(c))
        return self._add_joints(kind, p.astype(np.int64), c.astype(np.int64), anchor, axis, axis_child, names)

    def _add_joints(self, kind, p, c, anchor, axis, axis_child, names, kinds=None) -> np.ndarray:
        """Append joints between bodies p and c (WORLD = -1), each made of the basic constraints `kinds` (by
        default the catalogue's for `kind`): the one path of add_joint and add_joints."""
        count, nb = len(c), self._bodies.count
        batch = f"joint {names[0]!r}" if count == 1 else f"joints {names[0]!r}..{names[-1]!r}"
        self._open(batch)
        if count == 0:
            return np.zeros(0, dtype=np.int64)

        def label(i: int) -> str:
            return f"joint {names[i]!r}"

        ends = np.concatenate([p, c])  # parents, then children
        i = checks.first((ends < WORLD) | (ends >= nb))
        if i is not None:
            side = "parent" if i < count else "child"
            raise SceneError(f"{label(i % count)} {side}: body index {ends[i]} does not exist ({nb} bodies)")
        i = checks.first(c == WORLD)
        if i is not None:
            raise SceneError(f"{label(i)}: the child must be a body, not the world")
        i = checks.first(p == c)
        if i is not None:
            raise SceneError(f"{label(i)}: connects body {self._body_name[c[i]]!r} to itself")
        static = self._bodies["static"]
        i = checks.first(((p == WORLD) | static[np.maximum(p, 0)]) & static[c])
        if i is not None:
            raise SceneError(f"{label(i)}: both bodies are static; the joint constrains nothing")
        if kinds is None:
            if not isinstance(kind, str) or kind not in JOINT_TYPES:
                raise SceneError(f"{batch}: unknown joint type {kind!r}; expected one of {sorted(JOINT_TYPES)}")
            kinds = JOINT_TYPES[kind]
        needs_axis = any(k.needs_axis for k in kinds)
        needs_child_axis = any(k == ConstraintKind.ANGLE for k in kinds)
        anchor = _rows(anchor, count, (3,), f"{batch} anchor")
        checks.finite_rows({"anchor": anchor}, label)
        none = np.full((count, 3), np.nan)  # no axis
        has_axis = needs_axis or axis is not None
        axis = _unit_rows(axis, count, f"{batch} axis", label, "axis") if has_axis else none
        if needs_child_axis:
            axis_child = _unit_rows(axis_child if axis_child is not None else axis, count, f"{batch} child axis",
                                    label, "child axis")  # fmt: skip
            i = checks.first(np.abs(_dot(_parts(axis), _parts(axis_child))) > 1.0 - 1e-9)
            if i is not None:
                raise SceneError(f"{label(i)}: the two axes of an angle constraint are parallel")
        else:
            axis_child = none
        kind = kind if isinstance(kind, str) else str(kind)
        if kind not in self._joint_kinds:
            self._joint_kinds.append(kind)
        per = len(kinds)
        first_joint, first_constraint = self._joints.count, self._constraints.count
        joint = np.arange(first_joint, first_joint + count)
        self._joints.append(count, dict(kind=self._joint_kinds.index(kind), parent=p, child=c, anchor=anchor, axis=axis,
                                        axis_child=axis_child, first=first_constraint + per * np.arange(count),
                                        constraint_count=per))  # fmt: skip
        self._joint_name.extend(names)
        # The constraints, joint by joint: the axis where the joint has none is z, the child axis the axis.
        a0 = axis if has_axis else np.broadcast_to(np.array([0.0, 0.0, 1.0]), (count, 3))
        a1 = axis_child if needs_child_axis else a0
        columns = self._constraint_geometry(p, c, anchor, a0, a1)
        columns["joint"] = joint
        rows = self._constraints.view(self._constraints.grow(per * count))
        for k, values in columns.items():  # each joint's values on its `per` rows, through (count, per, ...) views
            rows[k].reshape(count, per, *values.shape[1:])[:] = values[:, None]
        rows["kind"].reshape(count, per)[:] = [int(k) for k in kinds]
        return joint

    def _frames(self, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and orientations of bodies `b` (the world's origin and identity for WORLD)."""
        if not self._bodies.count:  # only the world yet
            return np.zeros((len(b), 3)), np.tile([0.0, 0.0, 0.0, 1.0], (len(b), 1))
        at = np.maximum(b, 0)
        x, q = self._bodies["position"][at], self._bodies["orientation"][at]
        world = b == WORLD
        if world.any():
            x, q = np.where(world[:, None], 0.0, x), np.where(world[:, None], (0.0, 0.0, 0.0, 1.0), q)
        return x, q

    def _frame(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        x, q = self._frames(np.array([b]))
        return x[0], q[0]

    def _constraint_geometry(self, p, c, anchor, a0, a1) -> dict[str, np.ndarray]:
        """The anchor and axes of a constraint between bodies p and c in each body's frame, q0^-1 q1 and the
        angle between the axes, as built (element-wise: a joint gets the same bits alone or in a batch)."""
        n = len(p)
        x, q = self._frames(np.concatenate([p, c]))
        inverse = quat_conj(q)
        inverse0, inverse1 = _parts(inverse[:n]), _parts(inverse[n:])
        anchor, a0, a1 = _parts(anchor), _parts(a0), _parts(a1)
        arm0, arm1 = ([a - o for a, o in zip(anchor, _parts(origin))] for origin in (x[:n], x[n:]))
        anchor0, axis0 = rotate_components(inverse0, arm0, a0)
        anchor1, axis1 = rotate_components(inverse1, arm1, a1)
        # All in one array (n, 16), handed out as column views.
        out = _whole(anchor0 + anchor1 + axis0 + axis1 + mul_components(inverse0, _parts(q[n:])))
        return dict(
            body0=p,
            body1=c,
            anchor0=out[:, 0:3],
            anchor1=out[:, 3:6],
            axis0=out[:, 6:9],
            axis1=out[:, 9:12],
            rest_rotation=out[:, 12:16],
            rest_angle=np.arccos(np.minimum(np.maximum(_dot(a0, a1), -1.0), 1.0)),  # np.clip's bits, cheaper
        )
