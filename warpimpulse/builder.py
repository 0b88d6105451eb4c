"""SceneBuilder: bodies, joints and forces described on the host, validated, then finalized to a Model.

Anchors and axes are given in world coordinates at build time and stored in each body's frame.
Every joint is a list of basic constraints (method paper, sections 4.2-4.4; `joints.py`, `joint_builder.py`);
force elements and rows are `mechanisms.py`.

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
from .joint_builder import JointBuilder, _norms, _rows
from .mechanisms import Actuator, Distance, Drive, Force, Limit, Mechanisms, Spring
from .model import Model
from .shapes import SHAPE_CODES, Colliders, Shape
from .tables import Body, Constraint, Joint, Rows, Table
from .transforms import quat_conj, quat_mul, quat_rotate
from .types import WORLD, BodyRef, Names, Quat, Vec3

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


@dataclass
class Ground:
    """A collision plane {x : normal . x = height}, solid on the side opposite the normal."""

    normal: np.ndarray
    height: float
    friction: float
    restitution: float


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


def _axis(value, what: str) -> np.ndarray:
    arr = _vec(value, what)
    norm = float(np.linalg.norm(arr))
    if norm < 1e-12:
        raise SceneError(f"{what} is a zero vector")
    return arr / norm


class SceneBuilder(Mechanisms, JointBuilder):
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
    # ---------------------------------------------------------------- forces
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
