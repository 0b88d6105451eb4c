"""The builder's storage: columns of numpy arrays that grow by doubling, and light views of one row.

A scene of a million bodies is a few arrays, not a million Python objects: `SceneBuilder` keeps its bodies,
joints and basic constraints in `Table`s, adds many rows at once (`add_bodies`, `add_joints`) or one
(`add_body`, `add_joint`, the same code with one row), and hands the columns to the `Model` as they are.
`builder.bodies[i]` is a `Body` view of row i: reading a field gives the stored value (a vector is a view
into the column, so `body.linear_velocity[:] = v` writes through, until rows are added: the columns may then
move, so take the vector again), and setting a field checks it first.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from . import checks
from .checks import SceneError
from .types import ConstraintKind

if TYPE_CHECKING:
    from .shapes import Shape


class Table:
    """Named columns of equal length (rows), stored in arrays that double when full, so that adding n rows one
    at a time costs O(n) copies in all. `table["mass"]` is the live column (a view of the filled rows)."""

    def __init__(self, **columns: tuple[tuple[int, ...], Any]) -> None:
        self.count = 0
        self._arrays = {k: np.zeros((0, *shape), dtype=dtype) for k, (shape, dtype) in columns.items()}

    def __getitem__(self, column: str) -> np.ndarray:
        return self._arrays[column][: self.count]

    def __len__(self) -> int:
        return self.count

    def row_bytes(self) -> int:
        """The bytes of one row over all columns."""
        return sum(a.itemsize * int(np.prod(a.shape[1:])) for a in self._arrays.values())

    def grow(self, count: int) -> slice:
        """Append `count` rows (zeros) and return their slice."""
        stop = self.count + count
        capacity = len(next(iter(self._arrays.values())))
        if stop > capacity:
            capacity = max(stop, 2 * capacity, 8)
            for k, a in self._arrays.items():
                grown = np.zeros((capacity, *a.shape[1:]), dtype=a.dtype)
                grown[: self.count] = a[: self.count]
                self._arrays[k] = grown
        rows = slice(self.count, stop)
        self.count = stop
        return rows

    def append(self, count: int, values: dict[str, Any]) -> slice:
        """Append `count` rows, each column given (broadcast to the rows) or left zero; return their slice."""
        rows = self.grow(count)
        for k, v in values.items():
            self._arrays[k][rows] = v
        return rows

    def view(self, rows: slice) -> dict[str, np.ndarray]:
        """Every column's `rows`, as views."""
        return {k: a[rows] for k, a in self._arrays.items()}

    def truncate(self, count: int) -> None:
        """Forget every row from `count` on (a refused addition leaves nothing behind)."""
        self.count = count

    def columns(self) -> dict[str, np.ndarray]:
        """Copies of the filled columns."""
        return {k: a[: self.count].copy() for k, a in self._arrays.items()}

    def set_columns(self, columns: dict[str, np.ndarray]) -> None:
        """Replace every row by `columns` (each the same length)."""
        self.count = 0
        rows = self.grow(len(next(iter(columns.values()))))
        for k, values in columns.items():
            self._arrays[k][rows] = values


class Rows:
    """A read-only sequence of row views (`builder.bodies`, `builder.joints`, `builder.constraints`)."""

    def __init__(self, count: Callable[[], int], view: Callable[[int], Any]) -> None:
        self._count, self._view = count, view

    def __len__(self) -> int:
        return self._count()

    def __getitem__(self, i):
        n = self._count()
        if isinstance(i, slice):
            return [self._view(k) for k in range(*i.indices(n))]
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
            raise TypeError(f"row indices must be integers, got {i!r}")
        k = int(i) + n if i < 0 else int(i)
        if not 0 <= k < n:
            raise IndexError(f"row {i} does not exist ({n} rows)")
        return self._view(k)

    def __iter__(self) -> Iterator:
        return (self._view(k) for k in range(self._count()))

    def __eq__(self, other) -> bool:
        if isinstance(other, (list, tuple, Rows)):
            return len(self) == len(other) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    def __repr__(self) -> str:
        return f"<{len(self)} rows>"


class _View:
    __slots__ = ("_builder", "index")

    def __init__(self, builder, index: int) -> None:  # a SceneBuilder (not imported: it imports this module)
        self._builder, self.index = builder, index

    def __eq__(self, other) -> bool:
        return type(other) is type(self) and other._builder is self._builder and other.index == self.index

    def __hash__(self) -> int:
        return hash((id(self._builder), self.index))


def _column(name: str):
    """A row's field of a Table column: a Python scalar, or a view into the column for a vector."""

    def get(self):
        value = self._table()[name][self.index]
        return value.item() if value.ndim == 0 else value

    return property(get)


class Body(_View):
    """Row `index` of a builder's bodies. Fields: name, mass (kg, 0 if static), inertia (3x3 kg m^2, body frame
    about the centre of mass), position (m), orientation (x, y, z, w), linear_velocity (m/s), angular_velocity
    (rad/s, world frame), shape, static, friction, restitution. Setting a field checks its type and shape; the
    values (mass > 0, finite, positive definite inertia) are checked again, vectorised, by `finalize`."""

    __slots__ = ()

    def _table(self) -> Table:
        return self._builder._bodies

    @property
    def name(self) -> str:
        return self._builder._body_name[self.index]

    @property
    def static(self) -> bool:
        return bool(self._table()["static"][self.index])

    @property
    def shape(self) -> Shape | None:
        k = int(self._table()["shape"][self.index])
        return None if k < 0 else self._builder._shapes[k]

    @shape.setter
    def shape(self, shape: Shape | None) -> None:
        self._table()["shape"][self.index] = self._builder._shape_slot(shape, f"body {self.name!r}")

    def _set_vector(self, field: str, value, n: int) -> None:
        self._table()[field][self.index] = checks.vector(value, f"body {self.name!r} {field}", n)

    def _set_number(self, field: str, value) -> None:
        sep = ":" if field == "mass" else ""
        self._table()[field][self.index] = checks.real(value, f"body {self.name!r}{sep} {field}")

    def _set_inertia(self, value) -> None:
        what = f"body {self.name!r} inertia"
        arr = checks.numbers(value, what)
        if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
            raise SceneError(f"{what} must be a finite 3x3 tensor, got {arr.tolist()}")
        self._table()["inertia"][self.index] = arr

    mass = property(_column("mass").fget, lambda self, v: self._set_number("mass", v))
    friction = property(_column("friction").fget, lambda self, v: self._set_number("friction", v))
    restitution = property(_column("restitution").fget, lambda self, v: self._set_number("restitution", v))
    inertia = property(_column("inertia").fget, _set_inertia)
    position = property(_column("position").fget, lambda self, v: self._set_vector("position", v, 3))
    orientation = property(_column("orientation").fget, lambda self, v: self._set_vector("orientation", v, 4))
    linear_velocity = property(
        _column("linear_velocity").fget, lambda self, v: self._set_vector("linear_velocity", v, 3)
    )
    angular_velocity = property(
        _column("angular_velocity").fget, lambda self, v: self._set_vector("angular_velocity", v, 3)
    )

    def __repr__(self) -> str:
        return f"Body({self.name!r}, mass={self.mass:g}{', static' if self.static else ''})"


class Joint(_View):
    """Row `index` of a builder's joints: name, kind (the catalogue type, `joints.JOINT_TYPES`, or a basic
    constraint's name), parent (WORLD = -1) and child body, anchor (world, m, at build time), axis and
    axis_child (world, unit; None where the joint has none), constraints (its basic constraints' indices,
    consecutive) and loop (close a kinematic loop with it where there is a choice)."""

    __slots__ = ()

    def _table(self) -> Table:
        return self._builder._joints

    @property
    def name(self) -> str:
        return self._builder._joint_name[self.index]

    @property
    def kind(self) -> str:
        return self._builder._joint_kinds[int(self._table()["kind"][self.index])]

    parent = property(_column("parent").fget)
    child = property(_column("child").fget)
    anchor = property(_column("anchor").fget)

    def _optional(self, field: str) -> np.ndarray | None:
        value = self._table()[field][self.index]
        return None if np.isnan(value[0]) else value

    @property
    def axis(self) -> np.ndarray | None:
        return self._optional("axis")

    @property
    def axis_child(self) -> np.ndarray | None:
        return self._optional("axis_child")

    @property
    def constraints(self) -> list[int]:
        t = self._table()
        first = int(t["first"][self.index])
        return list(range(first, first + int(t["constraint_count"][self.index])))

    @property
    def loop(self) -> bool:
        return bool(self._table()["loop"][self.index])

    @loop.setter
    def loop(self, value: bool) -> None:
        self._table()["loop"][self.index] = bool(value)

    def __repr__(self) -> str:
        return f"Joint({self.name!r}, {self.kind}, parent={self.parent}, child={self.child})"


class Constraint(_View):
    """Row `index` of a builder's basic constraints, between body0 (parent side, may be WORLD) and body1: kind,
    anchor0 / axis0 in body0's frame (world frame for WORLD), anchor1 / axis1 in body1's frame, rest_rotation
    q0^-1 q1 and rest_angle (rad) at build time, and its joint."""

    __slots__ = ()

    def _table(self) -> Table:
        return self._builder._constraints

    @property
    def kind(self) -> ConstraintKind:
        return ConstraintKind(int(self._table()["kind"][self.index]))

    body0 = property(_column("body0").fget)
    body1 = property(_column("body1").fget)
    anchor0 = property(_column("anchor0").fget)
    anchor1 = property(_column("anchor1").fget)
    axis0 = property(_column("axis0").fget)
    axis1 = property(_column("axis1").fget)
    rest_rotation = property(_column("rest_rotation").fget)
    rest_angle = property(_column("rest_angle").fget)
    joint = property(_column("joint").fget)

    def __repr__(self) -> str:
        return f"Constraint({self.kind.name}, {self.body0}, {self.body1}, joint={self.joint})"
