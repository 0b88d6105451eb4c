"""SceneBuilder: bodies, joints and forces described on the host, validated, then finalized to a Model.

Anchors and axes are given in world coordinates at build time and stored in each body's frame.
Every joint is a list of basic constraints (method paper, sections 4.2-4.4); see `joints.py`.

Bodies, joints and basic constraints are columns of arrays (`tables.Table`), added many at a time
(`add_bodies`, `add_joints`: numpy arrays in, index arrays out) or one at a time (`add_body`, `add_joint`: the
same code with one row). Every add is checked when it is called, vectorised, and a bad row is named ("body
'b17': mass must be positive") and leaves nothing behind. A one-row add pays numpy's per-call cost on arrays of
length 1, so the joint geometry and row norms are written over components (`_parts`): Python floats for one row,
arrays for a batch, one formula and the same bits (benchmarks/builder.py measures the one-row adds).
"""

from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import checks
from .checks import SceneError
from .joints import JOINT_TYPES
from .model import Model
from .shapes import SHAPE_CODES, Colliders, Shape
from .tables import Body, Constraint, Joint, Rows, Table
from .transforms import mul_components, quat_conj, quat_mul, quat_rotate, rotate_components
from .types import COORDINATES, DRIVE_MODES, WORLD, ConstraintKind, Quat, Vec3

__all__ = [
    "Actuator",
    "Body",
    "Constraint",
    "Joint",
    "SceneBuilder",
    "SceneError",
    "Visual",
    "WORLD",
    "checked_material",
]

BodyRef = int | str | None
"""A body: its index, its name, or None for the world."""

Names = str | Sequence[str] | None
"""Names of rows added at once: None ("body<index>", "joint<index>"), a format template filled with each row's
index ("b{}"), or one name per row."""


@dataclass
class Ground:
    """A collision plane {x : normal . x = height}, solid on the side opposite the normal."""

    normal: np.ndarray
    height: float
    friction: float
    restitution: float


@dataclass
class Force:
    """A constant world-frame force (at the centre of mass) and torque, active while t < until."""

    body: int
    force: np.ndarray
    torque: np.ndarray
    until: float = math.inf


@dataclass
class Spring:
    """A spring-damper between a point of body0 and a point of body1 (either may be WORLD), along the line
    joining them: force = -stiffness (length - rest_length) - damping d(length)/dt, in N (method paper,
    section 4.4: the car's wheel dampers)."""

    name: str
    body0: int
    body1: int
    anchor0: np.ndarray  # body0 frame (world frame for WORLD)
    anchor1: np.ndarray  # body1 frame
    stiffness: float  # N/m
    damping: float  # N s/m
    rest_length: float  # m


@dataclass
class Drive:
    """A torque about a revolute axis (N m) or a force along a prismatic axis (N) from the joint coordinate
    (rad or m, 0 as built) and its rate: a joint spring-damper, or a servo motor with a PID controller
    (method paper, section 4.4). Position mode: kp (target - x) + ki integral(target - x) - kd dx/dt;
    velocity mode: kp (target - dx/dt) + ki integral(target - dx/dt) - kd d2x/dt2 (kd is taken 0 there).
    The output is clamped to +-max_force. A joint spring is a position drive with ki = 0 and no clamp."""

    name: str
    joint: int
    mode: int  # an index into DRIVE_MODES: 0 position, 1 velocity, 2 effort
    target: float  # rad, m (position) or rad/s, m/s (velocity)
    kp: float
    ki: float
    kd: float
    max_force: float
    motor: bool  # False for a joint spring
    stiff: bool = False  # an impulse-level velocity constraint instead of a force (velocity mode only)


@dataclass
class Limit:
    """lower <= coordinate <= upper on a revolute (rad) or prismatic (m) joint: a push-only constraint."""

    joint: int
    lower: float
    upper: float


@dataclass
class Distance:
    """lower <= |B - A| <= upper (m) between a point A of body0 and a point B of body1 (either may be WORLD): a
    rope (upper) or a strut (lower), push-only like a joint limit, and no other constraint (a distance joint)."""

    name: str
    body0: int
    body1: int
    anchor0: np.ndarray  # body0 frame (world frame for WORLD)
    anchor1: np.ndarray  # body1 frame
    axis0: np.ndarray  # body0 frame: the push direction while A and B meet (the built one, else gravity's)
    lower: float
    upper: float


@dataclass
class Actuator:
    """A named control input that sets a motor's target as MuJoCo's `ctrl` does its actuator's:
    target = gain * clip(control, ctrl_range) + bias (rad, m, rad/s, m/s, or N m / N in effort mode), the
    control starting at 0. `Simulator.set_controls` sets them by name or index."""

    name: str
    drive: int  # an index into SceneBuilder.drives (a motor)
    gain: float
    bias: float
    ctrl_range: tuple[float, float] = (-math.inf, math.inf)


VISUAL_KINDS = ("box", "sphere", "cylinder", "capsule", "mesh")


@dataclass
class Visual:
    """Display-only geometry fixed to a body (or to the world), kept on the builder for USD output: no part of
    the motion, the mass or the contacts. Robot loaders (URDF, MJCF) fill `SceneBuilder.visuals` with these;
    the USD writer draws each with a UsdPreviewSurface material of its colour.

    body: the body index, or WORLD (-1) for geometry fixed to the world.
    kind: one of `VISUAL_KINDS`. size (m): box (full edges x, y, z); sphere (radius, 0, 0); cylinder and capsule
        (radius, length, 0), along the local z axis (a capsule's length is its cylinder part); mesh: the scale
        applied to the vertices along the local x, y, z (a negative one mirrors).
    position, orientation: the geometry's frame in the body's frame (the centre of mass frame: m, (x, y, z, w)).
    rgba: colour and opacity in [0, 1].
    mesh_path: the file the mesh came from (for a mesh; reported, not read again).
    vertices (k, 3), faces (f, 3): a mesh's triangles in its own frame, before the scale.
    """

    body: int
    kind: str
    size: tuple[float, float, float]
    position: np.ndarray
    orientation: np.ndarray
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    name: str = ""
    mesh_path: str | None = None
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None


_vec = checks.vector
WORLD_COPIES = 3
"""The copies of a world's rows that replicating and finalizing make (the builder's tiled columns, the model's
host arrays, its device arrays): with NAME_BYTES a name (the string, its list and dict slots), what
`SceneBuilder.replicate` estimates a world to take before it refuses a count the memory cannot hold."""
NAME_BYTES = 150


def checked_material(friction, restitution, what: str) -> tuple[float, float]:
    """A checked (friction >= 0, restitution in [0, 1]) pair."""
    friction, restitution = checks.real(friction, f"{what}: friction"), checks.real(restitution, f"{what}: restitution")
    if not (math.isfinite(friction) and friction >= 0.0):
        raise SceneError(f"{what}: friction must be a finite number >= 0, got {friction}")
    if not 0.0 <= restitution <= 1.0:
        raise SceneError(f"{what}: restitution must be in [0, 1], got {restitution}")
    return friction, restitution


def _finite(value, what: str) -> float:
    x = checks.real(value, what)
    if not math.isfinite(x):
        raise SceneError(f"{what} must be finite, got {x}")
    return x


def _nonnegative(value, what: str) -> float:
    x = _finite(value, what)
    if x < 0.0:
        raise SceneError(f"{what} must be >= 0, got {x}")
    return x


def _axis(value, what: str) -> np.ndarray:
    arr = _vec(value, what)
    norm = float(np.linalg.norm(arr))
    if norm < 1e-12:
        raise SceneError(f"{what} is a zero vector")
    return arr / norm


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


class SceneBuilder:
    """Collects a scene. Call `finalize()` to get the device-side `Model`."""

    def __init__(self, gravity=(0.0, 0.0, -9.81)) -> None:
        self.gravity = _vec(gravity, "gravity")
        f8 = np.float64
        self._bodies = Table(mass=((), f8), inertia=((3, 3), f8), position=((3,), f8), orientation=((4,), f8),
                             linear_velocity=((3,), f8), angular_velocity=((3,), f8), static=((), bool),
                             friction=((), f8), restitution=((), f8), shape=((), np.int32))  # fmt: skip
        # A joint's axis and axis_child are NaN where it has none; its constraints are first..first+count-1.
        self._joints = Table(kind=((), np.int32), parent=((), np.int64), child=((), np.int64), anchor=((3,), f8),
                             axis=((3,), f8), axis_child=((3,), f8), first=((), np.int64),
                             constraint_count=((), np.int32), loop=((), bool))  # fmt: skip
        self._constraints = Table(kind=((), np.int32), body0=((), np.int64), body1=((), np.int64),
                                  anchor0=((3,), f8), anchor1=((3,), f8), axis0=((3,), f8), axis1=((3,), f8),
                                  rest_rotation=((4,), f8), rest_angle=((), f8), joint=((), np.int64))  # fmt: skip
        self._body_name: list[str] = []
        self._body_names: dict[str, int] = {}
        self._joint_name: list[str] = []
        self._joint_kinds: list[str] = []  # the joint kinds' names, indexed by the joints' kind column
        self._shapes: list[Shape] = []  # the distinct shapes, indexed by the bodies' shape column (-1: none)
        self._shape_slots: dict[int, int] = {}  # id(shape) -> its index (the list keeps the shape alive)
        self.forces: list[Force] = []
        self.grounds: list[Ground] = []
        self.collision_filters: set[tuple[int, int]] = set()
        self.springs: list[Spring] = []
        self.drives: list[Drive] = []
        self.limits: list[Limit] = []
        self.distances: list[Distance] = []
        self.visuals: list[Visual] = []  # display-only geometry (`add_visual`)
        self.actuators: list[Actuator] = []  # named control inputs of motors (`add_actuator`)
        self.chains: list[tuple[int, ...]] = []  # joints in series through light bodies (`chain_joints`)
        self.world_count = 1  # > 1 after replicate(): the scene is closed to additions

    @property
    def bodies(self) -> Rows:
        """The bodies as `tables.Body` views: `builder.bodies[i].mass`, `len(builder.bodies)`, iteration."""
        return Rows(lambda: self._bodies.count, lambda i: Body(self, i))

    @property
    def joints(self) -> Rows:
        """The joints as `tables.Joint` views."""
        return Rows(lambda: self._joints.count, lambda i: Joint(self, i))

    @property
    def constraints(self) -> Rows:
        """The basic constraints as `tables.Constraint` views, each joint's consecutive."""
        return Rows(lambda: self._constraints.count, lambda i: Constraint(self, i))

    def replicate(self, count: int) -> SceneBuilder:
        """A builder of `count` independent copies of this scene, "world0/..." to "world{count-1}/...", finalized
        to one Model that the simulator steps as batched worlds (every launch covers all of them; each world
        converges, and fails, on its own). Per-world masses, loads and states are set on the Simulator
        afterwards, without rebuilding. The copies are laid out world-major; the result takes no additions."""
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise SceneError(f"replicate: count must be an integer >= 1, got {count!r}")
        if self.world_count > 1:
            raise SceneError("replicate: this builder is already replicated; replicate the original scene")
        if not self._bodies.count:
            raise SceneError("replicate: the scene has no bodies")
        if self.grounds or self._colliding().any():
            raise SceneError(
                "replicate: the scene has colliding shapes or grounds; batched worlds do not take contacts yet "
                "(Shape(..., collide=False) keeps a shape for display and mass)"
            )
        # Limits, distance constraints and stiff motors are rows of one dense system over the whole model
        # (`kernels/limits.py`): batched, the worlds would share it, so they are refused.
        rows = [(len(self.limits), "limits"), (len(self.distances), "distance constraints"),
                (sum(d.stiff for d in self.drives), "stiff motors")]  # fmt: skip
        for n, what in rows:
            if n:
                raise SceneError(f"replicate: the scene has {n} {what}; batched worlds do not take {what} yet")
        count = int(count)
        nb, nj, nc = self._bodies.count, self._joints.count, self._constraints.count
        rows = self._bodies.row_bytes() * nb + self._joints.row_bytes() * nj + self._constraints.row_bytes() * nc
        checks.affordable(count, WORLD_COPIES * rows + NAME_BYTES * (nb + nj), "replicate", "world")
        out = SceneBuilder(self.gravity)
        out._joint_kinds, out._shapes, out._shape_slots = (
            list(self._joint_kinds),
            list(self._shapes),
            dict(self._shape_slots),
        )
        world = np.arange(count)

        def tiled(table: Table, shifts: dict[str, int]) -> dict[str, np.ndarray]:
            """The table's columns repeated per world, each index column shifted by its per-world size (WORLD stays
            WORLD; no other index is negative)."""
            columns = table.columns()
            for k, col in columns.items():
                tiled = np.concatenate([col] * count)
                if k in shifts:
                    tiled += np.where(tiled == WORLD, 0, np.repeat(world * shifts[k], len(col)))
                columns[k] = tiled
            return columns

        out._bodies.set_columns(tiled(self._bodies, {}))
        if nj:
            out._joints.set_columns(tiled(self._joints, {"parent": nb, "child": nb, "first": nc}))
        if nc:
            out._constraints.set_columns(tiled(self._constraints, {"body0": nb, "body1": nb, "joint": nj}))

        def named(names: list[str]) -> list[str]:
            return [f"world{w}/{n}" for w in range(count) for n in names] if count > 1 else list(names)

        out._body_name, out._joint_name = named(self._body_name), named(self._joint_name)
        out._body_names = dict(zip(out._body_name, range(len(out._body_name))))
        for w in range(count):
            for f in copy.deepcopy(self.forces):
                f.body += w * nb
                out.forces.append(f)
            for spring in copy.deepcopy(self.springs):
                spring.name = f"world{w}/{spring.name}" if count > 1 else spring.name
                spring.body0, spring.body1 = (b if b == WORLD else b + w * nb for b in (spring.body0, spring.body1))
                out.springs.append(spring)
            for drive in copy.deepcopy(self.drives):
                drive.name = f"world{w}/{drive.name}" if count > 1 else drive.name
                drive.joint += w * nj
                out.drives.append(drive)
            for actuator in copy.deepcopy(self.actuators):
                actuator.name = f"world{w}/{actuator.name}" if count > 1 else actuator.name
                actuator.drive += w * len(self.drives)
                out.actuators.append(actuator)
            out.chains += [tuple(j + w * nj for j in chain) for chain in self.chains]
            for visual in copy.deepcopy(self.visuals):
                visual.body = visual.body if visual.body == WORLD else visual.body + w * nb
                out.visuals.append(visual)
        out.world_count = count
        return out

    def _open(self, what: str) -> None:
        if self.world_count > 1:
            raise SceneError(f"{what}: a replicated scene takes no additions; add to the scene before replicate()")

    # ---------------------------------------------------------------- bodies
    def add_body(
        self,
        mass: float,
        inertia: Vec3 | np.ndarray,
        position: Vec3,
        orientation: Quat = (0.0, 0.0, 0.0, 1.0),
        linear_velocity: Vec3 | float = 0.0,
        angular_velocity: Vec3 | float = 0.0,
        name: str | None = None,
        shape: Shape | None = None,
        friction: float = 0.5,
        restitution: float = 0.0,
    ) -> int:
        """Add a dynamic body and return its index (`add_bodies` with one body).

        Args:
            mass: kg, positive.
            inertia: kg m^2 about the centre of mass in the body frame: a 3x3 symmetric positive definite
                tensor, or its 3 principal moments (then the body frame is the principal frame).
            position: the centre of mass, world frame (m).
            orientation: body to world, (x, y, z, w). A zero quaternion is refused; one whose norm differs from 1
                by more than 1e-6 is normalised with a UserWarning (a rounded quaternion is still meant as one).
            linear_velocity: of the centre of mass, world frame (m/s); a scalar fills all three.
            angular_velocity: world frame (rad/s); a scalar fills all three.
            name: unique; defaults to "body<index>". Errors and outputs name the body by it.
            shape: for display, and for collision unless `shape.collide` is False; centred on the centre of mass.
            friction: Coulomb's coefficient (>= 0) of the body's surface; a contact takes the geometric mean of
                its two bodies' coefficients.
            restitution: Newton's coefficient in [0, 1]; a contact takes the larger of its two bodies'.
        """
        name = self._new_name(name, "body", self._bodies.count)
        return int(self._add_bodies(1, [name], mass, inertia, position, orientation, linear_velocity,
                                    angular_velocity, shape, None, False, friction, restitution)[0])  # fmt: skip

    def add_bodies(
        self,
        mass,
        inertia,
        position,
        orientation=(0.0, 0.0, 0.0, 1.0),
        linear_velocity=0.0,
        angular_velocity=0.0,
        name: Names = None,
        shape: Shape | Sequence[Shape] | None = None,
        shape_index=None,
        friction=0.5,
        restitution=0.0,
    ) -> np.ndarray:
        """Add n dynamic bodies at once and return their indices (n,); every argument as in `add_body`, per body.

        Args:
            mass: (n,) kg; its length is n.
            inertia: (n, 3) principal moments or (n, 3, 3) tensors (kg m^2); for one body, its (3,) / (3, 3)
                alone (not broadcast to n bodies: a (3, 3) for three bodies would be ambiguous).
            position, linear_velocity, angular_velocity: (n, 3), or one vector (or number) for all.
            orientation: (n, 4) (x, y, z, w), or one for all.
            name: `Names`: None, a template such as "b{}" (filled with each body's index), or n names.
            shape: one Shape (or None) for all; or a list of shapes, each body's picked by `shape_index` (n,).
            friction, restitution: (n,) or one number for all.
        The checks are those of `add_body`, vectorised; the first bad body is named, and nothing is added.
        """
        arr = checks.numbers(mass, "add_bodies: mass")
        if arr.ndim != 1:
            raise SceneError(f"add_bodies: mass must be a 1-D array of the n bodies' masses, got shape {arr.shape}")
        count = len(arr)
        names = self._names(name, "body", self._bodies.count, count)
        return self._add_bodies(count, names, arr, inertia, position, orientation, linear_velocity,
                                angular_velocity, shape, shape_index, False, friction, restitution)  # fmt: skip

    def add_static_body(
        self,
        position,
        orientation=(0.0, 0.0, 0.0, 1.0),
        name: str | None = None,
        shape: Shape | None = None,
        friction: float = 0.5,
        restitution: float = 0.0,
    ) -> int:
        """Add a body that never moves (infinite mass); joints may attach to it like to the world, and bodies
        collide with its shape (a wall, a slope)."""
        name = self._new_name(name, "body", self._bodies.count)
        return int(self._add_bodies(1, [name], 0.0, np.zeros((3, 3)), position, orientation, 0.0, 0.0, shape,
                                    None, True, friction, restitution)[0])  # fmt: skip

    def _add_bodies(self, count, names, mass, inertia, position, orientation, v, w, shape, shape_index, static,
                    friction, restitution) -> np.ndarray:  # fmt: skip
        """Append `count` bodies named `names`: the one path of add_body, add_bodies and add_static_body. Shapes
        and types are checked on the input, values on the stored rows (`_check_bodies`, as finalize does)."""
        batch = f"body {names[0]!r}" if count == 1 else f"bodies {names[0]!r}..{names[-1]!r}"
        self._open(batch)
        if count == 0:
            return np.zeros(0, dtype=np.int64)
        if not self._body_names.keys().isdisjoint(names) or len(set(names)) < count:
            seen = set(self._body_names)
            for n in names:
                if n in seen:
                    raise SceneError(f"body {n!r}: a body of that name already exists")
                seen.add(n)
        first = self._bodies.count

        def label(i: int) -> str:
            return f"body {names[i]!r}"

        slots = self._shape_index(shape, shape_index, count, batch)
        mass = _rows(mass, count, (), f"{batch}: mass")
        inertia = checks.numbers(inertia, f"{batch}: inertia")
        if count == 1 and inertia.shape in ((3,), (3, 3)):  # add_body's one body
            inertia = inertia[None]
        if inertia.shape == (count, 3):  # principal moments: a diagonal tensor
            moments, inertia = inertia, np.zeros((count, 3, 3))
            inertia.reshape(count, 9)[:, ::4] = moments  # the diagonal, by a strided view
        if inertia.shape != (count, 3, 3):
            raise SceneError(f"{batch}: inertia must be 3 moments or a 3x3 tensor per body, got shape {inertia.shape}")
        q = _rows(orientation, count, (4,), f"{batch} orientation")
        norm = _norms(q)
        i = checks.first(norm < 1e-9)
        if i is not None:
            raise SceneError(f"{label(i)}: orientation quaternion is zero")
        off = np.abs(norm - 1.0) > 1e-6
        if off.any():
            off = np.flatnonzero(off)
            more = f" (and {len(off) - 1} more bodies)" if len(off) > 1 else ""
            warnings.warn(f"{label(off[0])}: orientation quaternion has norm {norm[off[0]]:.6g}; normalised{more}",
                          stacklevel=3)  # fmt: skip
        columns = dict(
            mass=mass, inertia=inertia, position=_rows(position, count, (3,), f"{batch} position"),
            orientation=q / norm[:, None], linear_velocity=_rows(v, count, (3,), f"{batch} linear_velocity"),
            angular_velocity=_rows(w, count, (3,), f"{batch} angular_velocity"), static=static, shape=slots,
            friction=_rows(friction, count, (), f"{batch}: friction"),
            restitution=_rows(restitution, count, (), f"{batch}: restitution"),
        )  # fmt: skip
        rows = self._bodies.append(count, columns)
        self._body_name.extend(names)
        self._body_names.update(zip(names, range(first, first + count)))
        try:
            self._check_bodies(rows)
        except SceneError:
            self._bodies.truncate(first)
            del self._body_name[first:]
            for n in names:
                del self._body_names[n]
            raise
        stored = self._bodies["inertia"][rows]
        stored[:] = 0.5 * (stored + stored.transpose(0, 2, 1))  # symmetric to the last bit
        return np.arange(first, first + count)

    def _check_bodies(self, rows: slice) -> None:
        """The values of bodies `rows`, vectorised, naming the first bad body: finite vectors, and for dynamic
        bodies a positive finite mass and a symmetric positive definite inertia whose principal moments obey the
        triangle inequality (a + b >= c); a finite friction >= 0 and a restitution in [0, 1]."""
        t, start = self._bodies.view(rows), rows.start

        def label(i: int) -> str:
            return f"body {self._body_name[start + i]!r}"

        checks.finite_rows({f: t[f] for f in ("position", "orientation", "linear_velocity", "angular_velocity")}, label)
        checks.mass_properties(t["mass"], t["inertia"], ~t["static"], label)
        friction, restitution = t["friction"], t["restitution"]
        i = checks.first(~(np.isfinite(friction) & (friction >= 0.0)))
        if i is not None:
            raise SceneError(f"{label(i)}: friction must be a finite number >= 0, got {friction[i]}")
        i = checks.first(~((restitution >= 0.0) & (restitution <= 1.0)))
        if i is not None:
            raise SceneError(f"{label(i)}: restitution must be in [0, 1], got {restitution[i]}")

    def _shape_slot(self, shape: Shape | None, what: str) -> int:
        """The index of `shape` among the builder's distinct shapes (added if new), -1 for None."""
        if shape is None:
            return -1
        if not isinstance(shape, Shape):
            raise SceneError(f"{what}: shape must be a warpimpulse Shape or None, got {shape!r}")
        if shape.collide and shape.zero_size():
            raise SceneError(f"{what}: collision shape {shape.kind} has zero size ({shape})")
        if id(shape) not in self._shape_slots:
            self._shape_slots[id(shape)] = len(self._shapes)
            self._shapes.append(shape)
        return self._shape_slots[id(shape)]

    def _shape_index(self, shape, shape_index, count: int, what: str) -> np.ndarray:
        """Each of `count` new bodies' index among the distinct shapes (-1: none)."""
        if shape_index is None:
            return np.full(count, self._shape_slot(shape, what), dtype=np.int32)
        if isinstance(shape, Shape) or shape is None:
            raise SceneError(f"{what}: shape_index needs a list of shapes to index, got {shape!r}")
        index = np.asarray(shape_index)
        if index.shape != (count,) or index.dtype.kind not in "iu":
            raise SceneError(f"{what}: shape_index must be {count} integers, got {shape_index!r}")
        i = checks.first((index < -1) | (index >= len(shape)))
        if i is not None:
            raise SceneError(f"{what}: shape_index {int(index[i])} is not one of the {len(shape)} shapes")
        slots = np.array([self._shape_slot(s, what) for s in shape] + [-1], dtype=np.int32)
        return slots[index]

    def _colliding(self) -> np.ndarray:
        """Whether each body has a colliding shape."""
        collide = np.array([s.collide for s in self._shapes] + [False], dtype=bool)
        return collide[self._bodies["shape"]]

    def add_visual(
        self, body: BodyRef, kind: str, size, position: Vec3, orientation: Quat = (0.0, 0.0, 0.0, 1.0),
        rgba=(0.7, 0.7, 0.7, 1.0), name: str = "", mesh_path: str | None = None, vertices=None, faces=None,
    ) -> int:  # fmt: skip
        """Display-only geometry (`Visual`) on `body` (index, name, or None for the world), its frame given in
        world coordinates at build time (m, (x, y, z, w)) like the joints' anchors, stored in the body's frame.
        A mesh needs `vertices` (k, 3) and `faces` (f, 3) of triangles. Returns its index in `visuals`."""
        what = f"visual {name or len(self.visuals)!r}"
        self._open(what)
        b = self._body_index(body, f"{what} body")
        if kind not in VISUAL_KINDS:
            raise SceneError(f"{what}: kind must be one of {VISUAL_KINDS}, got {kind!r}")
        size = _vec(size, f"{what} size")
        if not (np.isfinite(size).all() and (kind == "mesh" or (size >= 0.0).all())):  # a mesh's scale may mirror
            raise SceneError(f"{what}: size must be finite and >= 0, got {size.tolist()}")
        rgba = checks.numbers(rgba, f"{what} rgba")
        if rgba.shape != (4,) or not ((rgba >= 0.0) & (rgba <= 1.0)).all():
            raise SceneError(f"{what}: rgba must be 4 numbers in [0, 1], got {rgba.tolist()}")
        q = checks.numbers(orientation, f"{what} orientation")
        if q.shape != (4,) or not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
            raise SceneError(f"{what}: orientation must be a nonzero quaternion (x, y, z, w), got {q.tolist()}")
        if kind == "mesh":
            vertices = checks.numbers(vertices, f"{what} vertices") if vertices is not None else None
            faces = np.asarray(faces) if faces is not None else None
            if (
                vertices is None
                or faces is None
                or vertices.ndim != 2
                or vertices.shape[1] != 3
                or faces.ndim != 2
                or faces.shape[1] != 3
                or not len(faces)
            ):
                raise SceneError(f"{what}: a mesh needs vertices (k, 3) and triangle faces (f, 3)")
            if faces.dtype.kind not in "iu" or faces.min() < 0 or faces.max() >= len(vertices):
                raise SceneError(f"{what}: faces must index the {len(vertices)} vertices")
            faces = faces.astype(np.int64)
        x, qb = self._frame(b)
        local = quat_rotate(quat_conj(qb), _vec(position, f"{what} position") - x)
        lq = quat_mul(quat_conj(qb), q / np.linalg.norm(q))
        self.visuals.append(Visual(b, kind, tuple(size.tolist()), local, lq, tuple(rgba.tolist()), name, mesh_path,
                                   vertices, faces))  # fmt: skip
        return len(self.visuals) - 1

    def add_ground(
        self, height: float = 0.0, normal: Vec3 = (0.0, 0.0, 1.0), friction: float = 0.5, restitution: float = 0.0
    ) -> int:
        """A collision plane {x : normal . x = height} (m), solid on the side opposite `normal` (world frame, any
        length but zero). Returns its index. Several planes may be added (a floor and a slope)."""
        what = f"ground {len(self.grounds)}"
        self._open(what)
        normal = _axis(normal, f"{what} normal")
        height = checks.real(height, f"{what} height")
        if not math.isfinite(height):
            raise SceneError(f"{what}: height must be finite, got {height}")
        friction, restitution = checked_material(friction, restitution, what)
        self.grounds.append(Ground(normal, height, friction, restitution))
        return len(self.grounds) - 1

    def filter_collision(self, a: BodyRef, b: BodyRef) -> None:
        """Bodies a and b never collide with each other (jointed bodies never do anyway)."""
        self._open("filter_collision")
        i, j = self._body_index(a, "filter_collision"), self._body_index(b, "filter_collision")
        if WORLD in (i, j) or i == j:
            raise SceneError(f"filter_collision: needs two different bodies, got {a!r} and {b!r}")
        self.collision_filters.add((min(i, j), max(i, j)))

    @staticmethod
    def _new_name(name, kind: str, index: int) -> str:
        return f"{kind}{index}" if name is None else checks.name(name, f"{kind} {index} name")

    @staticmethod
    def _names(names: Names, kind: str, first: int, count: int) -> list[str]:
        """The names of `count` new rows from index `first` (`Names`)."""
        if names is None:
            names = f"{kind}{{}}"
        if isinstance(names, str):
            if "{}" not in names:
                raise SceneError(f"{kind} names: a template such as '{kind}{{}}' is expected, got {names!r}")
            return list(map(names.format, range(first, first + count)))
        names = list(names)
        if len(names) != count:
            raise SceneError(f"{kind} names: {count} are expected, got {len(names)}")
        if not all(isinstance(n, str) and n for n in names):
            for i, n in enumerate(names):
                checks.name(n, f"{kind} {first + i} name")
        return names

    # ---------------------------------------------------------------- joints
    # Every add_joint_* takes, in world coordinates at build time (the bodies' poses as added):
    #   parent: the parent body's index or name, or None for the world; child: the child body.
    #   anchor: the joint point (m). axis: the joint axis or plane normal (any length but zero).
    # and returns the joint's index. The joint holds the relative pose the bodies have when it is added.
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

    # ---------------------------------------------------------------- forces
    def add_force(self, body, force=0.0, torque=0.0, until: float = math.inf) -> int:
        """A constant world-frame force and torque on `body`, applied while the simulated time < `until`."""
        self._open("force")
        b = self._body_index(body, "force")
        if b == WORLD or self.bodies[b].static:
            raise SceneError(f"force: body {body!r} is not dynamic")
        what = f"force on body {self.bodies[b].name!r}"
        until = checks.real(until, f"{what}: until")
        if math.isnan(until):
            raise SceneError(f"{what}: until is NaN")
        self.forces.append(Force(b, _vec(force, f"{what}: force"), _vec(torque, f"{what}: torque"), until))
        return len(self.forces) - 1

    def add_spring(
        self, body0, body1, anchor0, anchor1, stiffness: float, damping: float = 0.0, rest_length=None, name=None
    ) -> int:
        """A spring-damper between `anchor0` on `body0` and `anchor1` on `body1` (world points at build time; a
        body of None is the world). `rest_length` (m) defaults to the built distance. Returns its index."""
        name = name or f"spring{len(self.springs)}"
        what = f"spring {name!r}"
        self._open(what)
        b0 = self._body_index(body0, f"{what} body0")
        b1 = self._body_index(body1, f"{what} body1")
        if b0 == b1:
            raise SceneError(f"{what}: both ends are on the same body")
        a0, a1 = _vec(anchor0, f"{what} anchor0"), _vec(anchor1, f"{what} anchor1")
        stiffness = _nonnegative(stiffness, f"{what}: stiffness")
        damping = _nonnegative(damping, f"{what}: damping")
        rest = float(np.linalg.norm(a1 - a0))
        if rest_length is not None:
            rest = _nonnegative(rest_length, f"{what}: rest_length")
        (x0, q0), (x1, q1) = self._frame(b0), self._frame(b1)
        local0, local1 = quat_rotate(quat_conj(q0), a0 - x0), quat_rotate(quat_conj(q1), a1 - x1)
        self.springs.append(Spring(name, b0, b1, local0, local1, stiffness, damping, rest))
        return len(self.springs) - 1

    def add_joint_spring(self, joint, stiffness: float, damping: float = 0.0, rest: float = 0.0) -> int:
        """A spring-damper on a revolute angle (N m/rad, N m s/rad, rest in rad) or a prismatic offset (N/m,
        N s/m, rest in m), the coordinate being 0 as built. Returns its index among the joint springs."""
        j = self._coordinate_joint(joint, "a joint spring")
        what = f"joint {self.joints[j].name!r}: joint spring"
        stiffness = _nonnegative(stiffness, f"{what} stiffness")
        damping = _nonnegative(damping, f"{what} damping")
        rest = _finite(rest, f"{what} rest")
        return self._add_drive(Drive(f"{self.joints[j].name}.spring", j, 0, rest, stiffness, 0.0, damping,
                                     math.inf, motor=False))  # fmt: skip

    def add_motor(
        self, joint, mode: str = "position", target: float = 0.0, kp: float = 1.0, ki: float = 0.0, kd: float = 0.0,
        max_force: float = math.inf, stiff: bool = False,
    ) -> int:  # fmt: skip
        """A servo motor on a revolute (torque, N m) or prismatic (force, N) joint, driven by a PID controller on
        the joint's angle/offset ("position", target in rad or m) or its rate ("velocity", rad/s or m/s), and
        clamped to +-max_force. The torque acts on both bodies, equal and opposite. Returns the motor index
        for `Simulator.set_motor_target`.

        The PID torque is a force inside the prediction (explicit RK4, each body predicted alone): stable while
        kp h / I, kd h / I (velocity, position mode) and h sqrt(kp / I) stay below about 2, with I the inertia
        about the axis of the lighter body of the joint, alone; a light crank or steering knuckle driven hard
        breaks that. `stiff=True` (the gains unused) makes the motor an impulse-level constraint instead: each
        step the joint turns by h target exactly (velocity mode) or reaches the target (position mode), with an
        impulse of at most max_force h, solved with the joints and limits (`kernels/limits.py`), stable at any
        stiffness. Use the PID for compliant, tuned servos on bodies heavy enough; `stiff` for a speed or
        angle that must hold, or a light body. "effort" mode applies the target itself as the torque or force
        (the gains unused, still clamped to +-max_force): a plain motor, MuJoCo's `motor` actuator."""
        j = self._coordinate_joint(joint, "a motor")
        what = f"joint {self.joints[j].name!r}: motor"
        if mode not in DRIVE_MODES:
            raise SceneError(f"{what} mode must be one of {DRIVE_MODES}, got {mode!r}")
        if stiff and mode == "effort":
            raise SceneError(f"{what}: an effort motor is a force, not a stiff constraint")
        kp, ki, kd = (_nonnegative(g, f"{what} {n}") for g, n in ((kp, "kp"), (ki, "ki"), (kd, "kd")))
        max_force = checks.real(max_force, f"{what} max_force")
        if not max_force > 0.0:
            raise SceneError(f"{what} max_force must be positive, got {max_force}")
        target = _finite(target, f"{what} target")
        drive = Drive(f"{self.joints[j].name}.motor", j, DRIVE_MODES.index(mode), target, kp, ki, kd, max_force,
                      motor=True, stiff=bool(stiff))  # fmt: skip
        return self._add_drive(drive)

    def add_actuator(self, motor: int, gain: float = 1.0, bias: float = 0.0, ctrl_range=None, name=None) -> int:
        """A named control input of motor `motor` (`add_motor`'s index): its target becomes
        gain * clip(control, ctrl_range) + bias, and is that at control 0 from the start (`Actuator`). Returns
        its index for `Simulator.set_controls`."""
        name = name or f"actuator{len(self.actuators)}"
        what = f"actuator {name!r}"
        self._open(what)
        motors = [i for i, d in enumerate(self.drives) if d.motor]
        if isinstance(motor, bool) or not isinstance(motor, (int, np.integer)) or not 0 <= motor < len(motors):
            raise SceneError(f"{what}: motor {motor!r} does not exist ({len(motors)} motors)")
        if any(a.name == name for a in self.actuators):
            raise SceneError(f"{what}: an actuator of that name already exists")
        gain, bias = _finite(gain, f"{what} gain"), _finite(bias, f"{what} bias")
        low, high = (-math.inf, math.inf) if ctrl_range is None else (checks.real(x, f"{what} ctrl_range")
                                                                      for x in ctrl_range)  # fmt: skip
        if not low <= high:
            raise SceneError(f"{what}: ctrl_range [{low}, {high}] is empty")
        drive = motors[motor]
        self.drives[drive].target = gain * min(max(0.0, low), high) + bias
        self.actuators.append(Actuator(name, drive, gain, bias, (low, high)))
        return len(self.actuators) - 1

    def chain_joints(self, joints: Sequence[int]) -> None:
        """Joints in series between two bodies through light bodies (each joint's child the next one's parent), as
        MJCF's several joints in one body: a joint spring or PID motor on one of them acts on the chain's two end
        bodies, not on the light bodies, along the direction that does work on its own coordinate only (the
        reciprocal of the chain's axes of its kind; a force at the hinges' common anchor). With the light bodies
        massless that is the same motion, and no force falls on a body of almost no inertia (which would make
        the explicit prediction unstable)."""
        self._open("chain_joints")
        chain = tuple(int(j) for j in joints)
        if len(chain) < 2 or not all(0 <= j < len(self.joints) for j in chain):
            raise SceneError(f"chain_joints: two or more existing joints are expected, got {joints!r}")
        for a, b in zip(chain, chain[1:]):
            if self.joints[a].child != self.joints[b].parent:
                raise SceneError(f"chain_joints: joint {self.joints[b].name!r} does not start where "
                                 f"{self.joints[a].name!r} ends")  # fmt: skip
        if any(set(chain) & set(c) for c in self.chains):
            raise SceneError(f"chain_joints: joint {self.joints[chain[0]].name!r} is in a chain already")
        self.chains.append(chain)

    def _drive_chains(self) -> tuple[np.ndarray, np.ndarray]:
        """Each drive's (sibling joint, sibling joint, anchor joint) and (body, body) for `Model` (drive_chain,
        drive_ends): for a drive on a chained joint, the chain's other joints of its kind, the hinge whose
        anchor a force acts at, and the chain's ends; checked that the direction exists."""
        j = self._joints
        chain = np.array([(-1, -1, d.joint) for d in self.drives], dtype=np.int64).reshape(-1, 3)
        ends = np.array([(j["parent"][d.joint], j["child"][d.joint]) for d in self.drives], dtype=np.int64)
        of = {joint: c for c in self.chains for joint in c}
        kinds = self.joint_types()
        for i, drive in enumerate(self.drives):
            links = of.get(drive.joint)
            if links is None or drive.stiff:  # a stiff motor is a row of the correction loop, not a force
                continue
            what = f"drive {drive.name!r} on chain {[kinds[k] for k in links]}"
            if "ball" in (kinds[k] for k in links):
                raise SceneError(f"{what}: a chain with a ball joint takes no joint springs or motors")
            same = [k for k in links if kinds[k] == kinds[drive.joint] and k != drive.joint]
            hinges = [k for k in links if kinds[k] == "revolute"]
            if len(same) > 2:
                raise SceneError(f"{what}: more than three joints of one kind")
            axes = j["axis"][[drive.joint, *same]]
            if abs(np.linalg.det(axes @ axes.T)) < 1e-9:
                raise SceneError(f"{what}: the chain's axes of its kind are dependent")
            if kinds[drive.joint] == "prismatic" and hinges:
                anchors = j["anchor"][hinges]
                if np.abs(anchors - anchors[0]).max() > 1e-9:
                    raise SceneError(f"{what}: a force along a chain needs its hinges' anchors to coincide")
            chain[i] = (*(same + [-1, -1])[:2], hinges[0] if kinds[drive.joint] == "prismatic" and hinges else
                        drive.joint)  # fmt: skip
            ends[i] = (j["parent"][links[0]], j["child"][links[-1]])
        return chain, ends.reshape(-1, 2)

    def mark_loop_joint(self, joint) -> None:
        """Close a kinematic loop with `joint` where the spanning tree has a choice (method paper, section 4.6;
        USD's physics:excludeFromArticulation): its constraints go to the loop part of the system."""
        if isinstance(joint, str):
            names = [j.name for j in self.joints]
            if joint not in names:
                raise SceneError(f"mark_loop_joint: no joint named {joint!r}")
            joint = names.index(joint)
        if not isinstance(joint, (int, np.integer)) or not 0 <= int(joint) < len(self.joints):
            raise SceneError(f"mark_loop_joint: joint {joint!r} does not exist ({len(self.joints)} joints)")
        self._open("mark_loop_joint")
        self.joints[int(joint)].loop = True

    def add_joint_limit(self, joint, lower: float, upper: float) -> int:
        """Keep a revolute angle (rad) or prismatic offset (m), 0 as built, within [lower, upper]."""
        j = self._coordinate_joint(joint, "a limit")
        what = f"joint {self.joints[j].name!r}: limit"
        lower, upper = checks.real(lower, f"{what} lower"), checks.real(upper, f"{what} upper")
        if math.isnan(lower) or math.isnan(upper):
            raise SceneError(f"{what} is NaN")
        self._open(what)
        if lower > upper:
            raise SceneError(f"{what} lower {lower} > upper {upper}")
        if not lower <= 0.0 <= upper:
            raise SceneError(f"{what} [{lower}, {upper}] excludes the built pose (coordinate 0)")
        if any(limit.joint == j for limit in self.limits):
            raise SceneError(f"{what}: the joint already has a limit")
        if COORDINATES[self.joints[j].kind] == 0 and upper - lower >= 2.0 * math.pi:
            # The angle is measured within the turn about the range's middle (kernels/limits.py, limit_error):
            # a range of a turn or more holds all of it, so the limit never binds.
            warnings.warn(f"{what} [{lower:.6g}, {upper:.6g}] rad spans a full turn or more: an angle is measured "
                          "within one turn, so it never binds", stacklevel=2)  # fmt: skip
        self.limits.append(Limit(j, lower, upper))
        return len(self.limits) - 1

    def add_distance(
        self, body0, body1, anchor0, anchor1, min_distance: float = 0.0, max_distance: float = math.inf, name=None
    ) -> int:
        """Keep the distance between `anchor0` on `body0` and `anchor1` on `body1` (world points at build time; a
        body of None is the world) within [min_distance, max_distance] (m), by push-only impulses in the
        correction loop (`kernels/limits.py`): a rope of length max_distance, a strut of min_distance, or both.
        The built distance may lie outside; the first step brings it in. Returns its index."""
        name = name or f"distance{len(self.distances)}"
        what = f"distance {name!r}"
        self._open(what)
        b0 = self._body_index(body0, f"{what} body0")
        b1 = self._body_index(body1, f"{what} body1")
        if b0 == b1:
            raise SceneError(f"{what}: both ends are on the same body")
        if (b0 == WORLD or self.bodies[b0].static) and (b1 == WORLD or self.bodies[b1].static):
            raise SceneError(f"{what}: both ends are static")
        a0, a1 = _vec(anchor0, f"{what} anchor0"), _vec(anchor1, f"{what} anchor1")
        lower = _nonnegative(min_distance, f"{what}: min_distance")
        upper = checks.real(max_distance, f"{what}: max_distance")
        if math.isnan(upper) or upper < lower:
            raise SceneError(f"{what}: max_distance {upper} must be >= min_distance {lower}")
        (x0, q0), (x1, q1) = self._frame(b0), self._frame(b1)
        # The push direction while A and B meet: B - A as built, else gravity's (B hangs below A), else x.
        gap = a1 - a0
        for direction in (gap, np.asarray(self.gravity, dtype=np.float64), np.array([1.0, 0.0, 0.0])):
            if np.linalg.norm(direction) > 1e-12:
                direction = direction / np.linalg.norm(direction)
                break
        local0, local1 = quat_rotate(quat_conj(q0), a0 - x0), quat_rotate(quat_conj(q1), a1 - x1)
        self.distances.append(Distance(name, b0, b1, local0, local1, quat_rotate(quat_conj(q0), direction), lower,
                                       upper))  # fmt: skip
        return len(self.distances) - 1

    def _add_drive(self, drive: Drive) -> int:
        """Append a drive; its index among the drives of its kind (motors, or joint springs)."""
        self._open(f"joint {self.joints[drive.joint].name!r}: {'motor' if drive.motor else 'joint spring'}")
        self.drives.append(drive)
        return sum(d.motor == drive.motor for d in self.drives) - 1

    def _coordinate_joint(self, joint, what: str) -> int:
        """The index of `joint` (index or name), which must have one coordinate (revolute or prismatic)."""
        if isinstance(joint, str):
            matches = [j for j, jt in enumerate(self.joints) if jt.name == joint]
            if not matches:
                raise SceneError(f"{what}: no joint named {joint!r}")
            joint = matches[0]
        if isinstance(joint, (bool, np.bool_)) or not isinstance(joint, (int, np.integer)):
            raise SceneError(f"{what}: a joint index or name is expected, got {joint!r}")
        if not 0 <= int(joint) < len(self.joints):
            raise SceneError(f"{what}: joint index {joint} does not exist ({len(self.joints)} joints)")
        jt = self.joints[int(joint)]
        if jt.kind not in COORDINATES:
            raise SceneError(
                f"joint {jt.name!r} ({jt.kind}) has no single coordinate for {what}; only revolute and prismatic do"
            )
        return int(joint)

    # ---------------------------------------------------------------- output
    @property
    def body_count(self) -> int:
        return self._bodies.count

    def finalize(self, device: str | None = "cpu") -> Model:
        """The scene as a `Model` on `device` ("cpu", "cuda", "cuda:0" or a Warp device), checked once more."""
        if not self._bodies.count:
            raise SceneError("the scene has no bodies")
        self._check_arrays()
        b, j, c = self._bodies.columns(), self._joints.columns(), self._constraints.columns()
        f = self.forces
        return Model(
            device,
            gravity=self.gravity,
            body_name=list(self._body_name),
            body_mass=b["mass"],
            body_inertia=b["inertia"],
            body_static=b["static"],
            body_x=b["position"],
            body_q=b["orientation"],
            body_v=b["linear_velocity"],
            body_w=b["angular_velocity"],
            **{
                f"constraint_{k}": c[k]
                for k in (
                    "kind",
                    "body0",
                    "body1",
                    "anchor0",
                    "anchor1",
                    "axis0",
                    "axis1",
                    "rest_rotation",
                    "rest_angle",
                    "joint",
                )
            },  # fmt: skip
            joint_name=list(self._joint_name),
            joint_type=self.joint_types(),
            joint_parent=j["parent"],
            joint_child=j["child"],
            joint_constraint_start=np.append(j["first"], self._constraints.count),
            force_body=np.array([x.body for x in f], dtype=np.int64),
            force_force=np.array([x.force for x in f]).reshape(-1, 3),
            force_torque=np.array([x.torque for x in f]).reshape(-1, 3),
            force_until=np.array([x.until for x in f]),
            colliders=self._colliders(),
            **self._mechanism_arrays(),
            world_count=self.world_count,
        )

    def joint_types(self) -> list[str]:
        """Every joint's kind (`Joint.kind`), in joint order."""
        return np.array(self._joint_kinds, dtype=object)[self._joints["kind"]].tolist()

    def _colliders(self) -> Colliders | None:
        """The collision geometry, or None for a scene where nothing collides (then the step has no contact
        stage at all)."""
        colliding = self._colliding()
        if not colliding.any() or (not self.grounds and np.count_nonzero(colliding) < 2):
            return None
        parent, child = self._joints["parent"], self._joints["child"]
        jointed = np.stack([np.minimum(parent, child), np.maximum(parent, child)], axis=1)[parent != WORLD]
        pairs = np.concatenate([jointed, np.array(sorted(self.collision_filters), dtype=np.int64).reshape(-1, 2)])
        slot = np.where(colliding, self._bodies["shape"], -1)  # -1 picks the last entry: no collision shape
        shapes = self._shapes
        planes = self.grounds
        return Colliders(
            shape_kind=np.array([SHAPE_CODES[s.kind] for s in shapes] + [-1], dtype=np.int64)[slot],
            shape_size=np.array([s.collision_size() for s in shapes] + [(0.0, 0.0, 0.0)], dtype=np.float64)[slot],
            bound=np.array([s.bounding_radius() for s in shapes] + [0.0], dtype=np.float64)[slot],
            friction=self._bodies["friction"].copy(),
            restitution=self._bodies["restitution"].copy(),
            plane_normal=np.array([g.normal for g in planes]).reshape(-1, 3),
            plane_offset=np.array([g.height for g in planes]),
            plane_friction=np.array([g.friction for g in planes]),
            plane_restitution=np.array([g.restitution for g in planes]),
            filter_pairs=np.unique(pairs, axis=0).astype(np.int64).reshape(-1, 2),
        )

    def _mechanism_arrays(self) -> dict:
        """The springs, drives, limits and distances as `Model` arguments."""
        springs, drives, limits = self.springs, self.drives, self.limits
        return dict(
            spring_name=[s.name for s in springs],
            spring_body0=np.array([s.body0 for s in springs], dtype=np.int64),
            spring_body1=np.array([s.body1 for s in springs], dtype=np.int64),
            spring_anchor0=np.array([s.anchor0 for s in springs]).reshape(-1, 3),
            spring_anchor1=np.array([s.anchor1 for s in springs]).reshape(-1, 3),
            spring_params=np.array([(s.stiffness, s.damping, s.rest_length) for s in springs]).reshape(-1, 3),
            drive_name=[x.name for x in drives],
            drive_joint=np.array([x.joint for x in drives], dtype=np.int64),
            drive_mode=np.array([x.mode for x in drives], dtype=np.int32),
            drive_target=np.array([x.target for x in drives]),
            drive_gains=np.array([(x.kp, x.ki, x.kd) for x in drives]).reshape(-1, 3),
            drive_max_force=np.array([x.max_force for x in drives]),
            drive_motor=np.array([x.motor for x in drives], dtype=bool),
            drive_stiff=np.array([x.stiff for x in drives], dtype=bool),
            **dict(zip(("drive_chain", "drive_ends"), self._drive_chains())),
            limit_joint=np.array([x.joint for x in limits], dtype=np.int64),
            limit_bounds=np.array([(x.lower, x.upper) for x in limits]).reshape(-1, 2),
            joint_loop=self._joints["loop"].copy(),
            distance_name=[x.name for x in self.distances],
            distance_body=np.array([(x.body0, x.body1) for x in self.distances], dtype=np.int64).reshape(-1, 2),
            distance_anchor=np.array([(x.anchor0, x.anchor1, x.axis0) for x in self.distances]).reshape(-1, 3, 3),
            distance_bounds=np.array([(x.lower, x.upper) for x in self.distances]).reshape(-1, 2),
            actuator_name=[a.name for a in self.actuators],
            actuator_drive=np.array([a.drive for a in self.actuators], dtype=np.int64),
            actuator_map=np.array([(a.gain, a.bias, *a.ctrl_range) for a in self.actuators]).reshape(-1, 4),
        )

    def _check_arrays(self) -> None:
        """The add_* calls check their input, but the stored body columns stay mutable (scenes set velocities
        after adding bodies, in place): check them once more, vectorised, naming the first bad body, so that no
        NaN, Inf or bad mass reaches the device. Constraint data is derived from checked input at add time and
        is not re-checked."""
        self.gravity = _vec(self.gravity, "gravity")
        self._check_bodies(slice(0, self._bodies.count))
        for force in self.forces:
            if not (np.all(np.isfinite(force.force)) and np.all(np.isfinite(force.torque))):
                raise SceneError(f"force on body {self._body_name[force.body]!r} contains NaN or Inf")
