"""SceneBuilder: bodies, joints and forces described on the host, validated, then finalized to a Model.

Anchors and axes are given in world coordinates at build time and stored in each body's frame.
Every joint is a list of basic constraints (method paper, sections 4.2-4.4); see `joints.py`.
"""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import checks
from .checks import SceneError
from .joints import JOINT_TYPES
from .model import Model
from .shapes import SHAPE_CODES, Colliders, Shape
from .transforms import quat_conj, quat_mul, quat_rotate
from .types import COORDINATES, DRIVE_MODES, WORLD, ConstraintKind, Quat, Vec3

BodyRef = int | str | None
"""A body: its index, its name, or None for the world."""


@dataclass
class Body:
    name: str
    mass: float  # 0 for static bodies
    inertia: np.ndarray  # 3x3, body frame, about the centre of mass
    position: np.ndarray
    orientation: np.ndarray  # (x, y, z, w)
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray  # world frame
    shape: Shape | None = None
    static: bool = False
    friction: float = 0.5
    restitution: float = 0.0


@dataclass
class Ground:
    """A collision plane {x : normal . x = height}, solid on the side opposite the normal."""

    normal: np.ndarray
    height: float
    friction: float
    restitution: float


@dataclass
class Constraint:
    """One basic constraint between body0 (parent side, may be WORLD) and body1 (child side)."""

    kind: ConstraintKind
    body0: int
    body1: int
    anchor0: np.ndarray  # point on body0, body0 frame (world frame when body0 is WORLD)
    anchor1: np.ndarray  # point on body1, body1 frame
    axis0: np.ndarray  # body0 frame: line direction, plane normal, common axis, or first angle axis
    axis1: np.ndarray  # body1 frame: common axis or second angle axis
    rest_rotation: np.ndarray  # q0^-1 q1 at build time, for FIXED_ROTATION
    rest_angle: float  # angle between axis0 and axis1 at build time, for ANGLE
    joint: int


@dataclass
class Joint:
    name: str
    kind: str
    parent: int
    child: int
    anchor: np.ndarray  # world, at build time
    axis: np.ndarray | None
    axis_child: np.ndarray | None
    constraints: list[int] = field(default_factory=list)
    loop: bool = False  # close a kinematic loop with this joint where there is a choice (mark_loop_joint)


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
    mode: int  # an index into DRIVE_MODES: 0 position, 1 velocity
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


_vec = checks.vector


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


class SceneBuilder:
    """Collects a scene. Call `finalize()` to get the device-side `Model`."""

    def __init__(self, gravity=(0.0, 0.0, -9.81)) -> None:
        self.gravity = _vec(gravity, "gravity")
        self.bodies: list[Body] = []
        self.joints: list[Joint] = []
        self.constraints: list[Constraint] = []
        self.forces: list[Force] = []
        self.grounds: list[Ground] = []
        self.collision_filters: set[tuple[int, int]] = set()
        self.springs: list[Spring] = []
        self.drives: list[Drive] = []
        self.limits: list[Limit] = []
        self.distances: list[Distance] = []
        self._body_names: dict[str, int] = {}
        self.world_count = 1  # > 1 after replicate(): the scene is closed to additions

    def replicate(self, count: int) -> SceneBuilder:
        """A builder of `count` independent copies of this scene, "world0/..." to "world{count-1}/...", finalized
        to one Model that the simulator steps as batched worlds (every launch covers all of them; each world
        converges, and fails, on its own). Per-world masses, loads and states are set on the Simulator
        afterwards, without rebuilding. The copies are laid out world-major; the result takes no additions."""
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise SceneError(f"replicate: count must be an integer >= 1, got {count!r}")
        if self.world_count > 1:
            raise SceneError("replicate: this builder is already replicated; replicate the original scene")
        if not self.bodies:
            raise SceneError("replicate: the scene has no bodies")
        if self.grounds or any(b.shape is not None and b.shape.collide for b in self.bodies):
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
        out = SceneBuilder(self.gravity)
        nb, nj, nc = len(self.bodies), len(self.joints), len(self.constraints)
        prefix = count > 1

        def body(b: int, w: int) -> int:
            return b if b == WORLD else b + w * nb

        for w in range(int(count)):
            bodies, joints, cons, forces = copy.deepcopy((self.bodies, self.joints, self.constraints, self.forces))
            for b in bodies:
                b.name = f"world{w}/{b.name}" if prefix else b.name
                out._body_names[b.name] = len(out.bodies)
                out.bodies.append(b)
            for j in joints:
                j.name = f"world{w}/{j.name}" if prefix else j.name
                j.parent, j.child = body(j.parent, w), body(j.child, w)
                j.constraints = [c + w * nc for c in j.constraints]
                out.joints.append(j)
            for c in cons:
                c.body0, c.body1, c.joint = body(c.body0, w), body(c.body1, w), c.joint + w * nj
                out.constraints.append(c)
            for f in forces:
                f.body = body(f.body, w)
                out.forces.append(f)
            for spring in copy.deepcopy(self.springs):
                spring.name = f"world{w}/{spring.name}" if prefix else spring.name
                spring.body0, spring.body1 = body(spring.body0, w), body(spring.body1, w)
                out.springs.append(spring)
            for drive in copy.deepcopy(self.drives):
                drive.name = f"world{w}/{drive.name}" if prefix else drive.name
                drive.joint += w * nj
                out.drives.append(drive)
        out.world_count = int(count)
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
        """Add a dynamic body and return its index.

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
        name = self._new_name(name, "body", len(self.bodies))
        what = f"body {name!r}"
        mass = checks.real(mass, f"{what}: mass")
        if not math.isfinite(mass) or mass <= 0.0:
            raise SceneError(f"{what}: mass must be positive and finite, got {mass}")
        return self._append_body(
            name, mass, self._inertia(inertia, what), position, orientation,
            linear_velocity, angular_velocity, shape, False, friction, restitution,
        )  # fmt: skip

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
        name = self._new_name(name, "body", len(self.bodies))
        return self._append_body(
            name, 0.0, np.zeros((3, 3)), position, orientation, 0.0, 0.0, shape, True, friction, restitution
        )

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

    def _append_body(self, name, mass, inertia, position, orientation, v, w, shape, static, friction, restitution):
        what = f"body {name!r}"
        self._open(what)
        if name in self._body_names:
            raise SceneError(f"{what}: a body of that name already exists")
        if shape is not None and not isinstance(shape, Shape):
            raise SceneError(f"{what}: shape must be a warpimpulse Shape or None, got {shape!r}")
        if shape is not None and shape.collide and shape.zero_size():
            raise SceneError(f"{what}: collision shape {shape.kind} has zero size ({shape})")
        friction, restitution = checked_material(friction, restitution, what)
        q = _vec(orientation, f"{what} orientation", 4)
        norm = float(np.linalg.norm(q))
        if norm < 1e-9:
            raise SceneError(f"{what}: orientation quaternion is zero")
        if abs(norm - 1.0) > 1e-6:
            warnings.warn(f"{what}: orientation quaternion has norm {norm:.6g}; normalised", stacklevel=3)
        self.bodies.append(
            Body(
                name=name,
                mass=mass,
                inertia=inertia,
                position=_vec(position, f"{what} position"),
                orientation=q / norm,
                linear_velocity=_vec(v, f"{what} linear_velocity"),
                angular_velocity=_vec(w, f"{what} angular_velocity"),
                shape=shape,
                static=static,
                friction=friction,
                restitution=restitution,
            )
        )
        self._body_names[name] = len(self.bodies) - 1
        return len(self.bodies) - 1

    @staticmethod
    def _inertia(inertia, what: str) -> np.ndarray:
        arr = checks.numbers(inertia, f"{what}: inertia")
        if arr.shape == (3,):
            arr = np.diag(arr)
        if arr.shape != (3, 3):
            raise SceneError(f"{what}: inertia must be 3 moments or a 3x3 tensor, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise SceneError(f"{what}: inertia contains NaN or Inf")
        scale = max(float(np.abs(arr).max()), 1e-300)
        if np.abs(arr - arr.T).max() > 1e-9 * scale:
            raise SceneError(f"{what}: inertia tensor is not symmetric")
        moments = np.linalg.eigvalsh(arr)
        if moments.min() <= 0.0:
            raise SceneError(f"{what}: inertia tensor is not positive definite (moments {moments.tolist()})")
        a, b, c = moments
        if a + b < c * (1.0 - 1e-9):
            raise SceneError(f"{what}: principal moments {moments.tolist()} break the triangle inequality")
        return 0.5 * (arr + arr.T)

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
        """A joint of a catalogue type (`joints.JOINT_TYPES`) by name; the typed add_joint_* call this."""
        name = self._new_name(name, "joint", len(self.joints))
        what = f"joint {name!r}"
        self._open(what)
        p = self._body_index(parent, f"{what} parent")
        c = self._body_index(child, f"{what} child")
        if c == WORLD:
            raise SceneError(f"{what}: the child must be a body, not the world")
        if p == c:
            raise SceneError(f"{what}: connects body {self.bodies[c].name!r} to itself")
        if (p == WORLD or self.bodies[p].static) and self.bodies[c].static:
            raise SceneError(f"{what}: both bodies are static; the joint constrains nothing")
        if kinds is None:
            if not isinstance(kind, str) or kind not in JOINT_TYPES:
                raise SceneError(f"{what}: unknown joint type {kind!r}; expected one of {sorted(JOINT_TYPES)}")
            kinds = JOINT_TYPES[kind]
        needs_axis = any(k.needs_axis for k in kinds)
        needs_child_axis = any(k == ConstraintKind.ANGLE for k in kinds)
        anchor = _vec(anchor, f"{what} anchor")
        axis = _axis(axis, f"{what} axis") if needs_axis or axis is not None else None
        if needs_child_axis:
            axis_child = _axis(axis_child if axis_child is not None else axis, f"{what} child axis")
            if abs(float(np.dot(axis, axis_child))) > 1.0 - 1e-9:
                raise SceneError(f"{what}: the two axes of an angle constraint are parallel")
        else:
            axis_child = None
        joint = Joint(name, kind, p, c, anchor, axis, axis_child)
        self.joints.append(joint)
        for k in kinds:
            joint.constraints.append(len(self.constraints))
            self.constraints.append(self._make_constraint(k, p, c, anchor, axis, axis_child, len(self.joints) - 1))
        return len(self.joints) - 1

    def _frame(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        if b == WORLD:
            return np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
        return self.bodies[b].position, self.bodies[b].orientation

    def _make_constraint(self, kind, p, c, anchor, axis, axis_child, joint) -> Constraint:
        x0, q0 = self._frame(p)
        x1, q1 = self._frame(c)
        a0 = axis if axis is not None else np.array([0.0, 0.0, 1.0])
        a1 = axis_child if axis_child is not None else a0
        return Constraint(
            kind=kind,
            body0=p,
            body1=c,
            anchor0=quat_rotate(quat_conj(q0), anchor - x0),
            anchor1=quat_rotate(quat_conj(q1), anchor - x1),
            axis0=quat_rotate(quat_conj(q0), a0),
            axis1=quat_rotate(quat_conj(q1), a1),
            rest_rotation=quat_mul(quat_conj(q0), q1),
            rest_angle=float(np.arccos(np.clip(np.dot(a0, a1), -1.0, 1.0))),
            joint=joint,
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
        angle that must hold, or a light body."""
        j = self._coordinate_joint(joint, "a motor")
        what = f"joint {self.joints[j].name!r}: motor"
        if mode not in DRIVE_MODES:
            raise SceneError(f"{what} mode must be one of {DRIVE_MODES}, got {mode!r}")
        kp, ki, kd = (_nonnegative(g, f"{what} {n}") for g, n in ((kp, "kp"), (ki, "ki"), (kd, "kd")))
        max_force = checks.real(max_force, f"{what} max_force")
        if not max_force > 0.0:
            raise SceneError(f"{what} max_force must be positive, got {max_force}")
        target = _finite(target, f"{what} target")
        drive = Drive(f"{self.joints[j].name}.motor", j, DRIVE_MODES.index(mode), target, kp, ki, kd, max_force,
                      motor=True, stiff=bool(stiff))  # fmt: skip
        return self._add_drive(drive)

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
        return len(self.bodies)

    def finalize(self, device: str | None = "cpu") -> Model:
        """The scene as a `Model` on `device` ("cpu", "cuda", "cuda:0" or a Warp device), checked once more."""
        if not self.bodies:
            raise SceneError("the scene has no bodies")
        self._check_arrays()
        bodies, cons, joints, forces = self.bodies, self.constraints, self.joints, self.forces
        starts = [j.constraints[0] if j.constraints else len(cons) for j in joints]
        return Model(
            device,
            gravity=self.gravity,
            body_name=[b.name for b in bodies],
            body_mass=np.array([b.mass for b in bodies]),
            body_inertia=np.array([b.inertia for b in bodies]),
            body_static=np.array([b.static for b in bodies], dtype=bool),
            body_x=np.array([b.position for b in bodies]),
            body_q=np.array([b.orientation for b in bodies]),
            body_v=np.array([b.linear_velocity for b in bodies]),
            body_w=np.array([b.angular_velocity for b in bodies]),
            constraint_kind=np.array([int(c.kind) for c in cons], dtype=np.int32),
            constraint_body0=np.array([c.body0 for c in cons], dtype=np.int64),
            constraint_body1=np.array([c.body1 for c in cons], dtype=np.int64),
            constraint_anchor0=np.array([c.anchor0 for c in cons]).reshape(-1, 3),
            constraint_anchor1=np.array([c.anchor1 for c in cons]).reshape(-1, 3),
            constraint_axis0=np.array([c.axis0 for c in cons]).reshape(-1, 3),
            constraint_axis1=np.array([c.axis1 for c in cons]).reshape(-1, 3),
            constraint_rest_rotation=np.array([c.rest_rotation for c in cons]).reshape(-1, 4),
            constraint_rest_angle=np.array([c.rest_angle for c in cons]),
            constraint_joint=np.array([c.joint for c in cons], dtype=np.int64),
            joint_name=[j.name for j in joints],
            joint_type=[j.kind for j in joints],
            joint_parent=np.array([j.parent for j in joints], dtype=np.int64),
            joint_child=np.array([j.child for j in joints], dtype=np.int64),
            joint_constraint_start=np.array([*starts, len(cons)], dtype=np.int64),
            force_body=np.array([f.body for f in forces], dtype=np.int64),
            force_force=np.array([f.force for f in forces]).reshape(-1, 3),
            force_torque=np.array([f.torque for f in forces]).reshape(-1, 3),
            force_until=np.array([f.until for f in forces]),
            colliders=self._colliders(),
            **self._mechanism_arrays(),
            world_count=self.world_count,
        )

    def _colliders(self) -> Colliders | None:
        """The collision geometry, or None for a scene where nothing collides (then the step has no contact
        stage at all)."""
        colliding = [b.shape is not None and b.shape.collide for b in self.bodies]
        if not any(colliding) or (not self.grounds and sum(colliding) < 2):
            return None
        pairs = {(min(j.parent, j.child), max(j.parent, j.child)) for j in self.joints if j.parent != WORLD}
        pairs |= self.collision_filters
        planes = self.grounds
        return Colliders(
            shape_kind=np.array([SHAPE_CODES[b.shape.kind] if c else -1 for b, c in zip(self.bodies, colliding)]),
            shape_size=np.array([b.shape.collision_size() if c else (0, 0, 0) for b, c in zip(self.bodies, colliding)]),
            bound=np.array([b.shape.bounding_radius() if c else 0.0 for b, c in zip(self.bodies, colliding)]),
            friction=np.array([b.friction for b in self.bodies]),
            restitution=np.array([b.restitution for b in self.bodies]),
            plane_normal=np.array([g.normal for g in planes]).reshape(-1, 3),
            plane_offset=np.array([g.height for g in planes]),
            plane_friction=np.array([g.friction for g in planes]),
            plane_restitution=np.array([g.restitution for g in planes]),
            filter_pairs=np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2),
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
            limit_joint=np.array([x.joint for x in limits], dtype=np.int64),
            limit_bounds=np.array([(x.lower, x.upper) for x in limits]).reshape(-1, 2),
            joint_loop=np.array([j.loop for j in self.joints], dtype=bool),
            distance_name=[x.name for x in self.distances],
            distance_body=np.array([(x.body0, x.body1) for x in self.distances], dtype=np.int64).reshape(-1, 2),
            distance_anchor=np.array([(x.anchor0, x.anchor1, x.axis0) for x in self.distances]).reshape(-1, 3, 3),
            distance_bounds=np.array([(x.lower, x.upper) for x in self.distances]).reshape(-1, 2),
        )

    def _check_arrays(self) -> None:
        """The add_* calls check their input, but the stored body arrays stay mutable (scenes set velocities
        after adding bodies): check once more that no wrong type, NaN, Inf or bad mass reaches the device,
        vectorised, and body by body (to name the culprit) only when something is wrong. Constraint data is
        derived from checked input at add time and is not re-checked."""
        self.gravity = _vec(self.gravity, "gravity")
        n = len(self.bodies)
        for f, shape in _BODY_ARRAYS.items():
            try:
                values = np.array([getattr(b, f) for b in self.bodies], dtype=np.float64)
                ok = values.shape == (n, *shape) and np.abs(values).max(initial=0.0) <= checks.LARGEST
            except (TypeError, ValueError):
                ok = False
            if not ok:  # NaN fails the comparison too
                for b in self.bodies:
                    what = f"body {b.name!r} {f}"
                    if f == "inertia":
                        arr = checks.numbers(b.inertia, what)
                        if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
                            raise SceneError(f"{what} must be a finite 3x3 tensor, got {arr.tolist()}")
                    else:
                        _vec(getattr(b, f), what, shape[0])
        for b in self.bodies:
            if isinstance(b.mass, (bool, np.bool_)) or not isinstance(b.mass, (float, int, np.number)):
                raise SceneError(f"body {b.name!r}: mass must be a number, got {b.mass!r}")
        mass = np.array([b.mass for b in self.bodies], dtype=np.float64)
        bad = np.flatnonzero(~np.array([b.static for b in self.bodies]) & ~(np.isfinite(mass) & (mass > 0.0)))
        if bad.size:
            raise SceneError(f"body {self.bodies[bad[0]].name!r}: mass must be positive and finite, got {mass[bad[0]]}")
        for force in self.forces:
            if not (np.all(np.isfinite(force.force)) and np.all(np.isfinite(force.torque))):
                raise SceneError(f"force on body {self.bodies[force.body].name!r} contains NaN or Inf")


_BODY_ARRAYS = {"position": (3,), "orientation": (4,), "linear_velocity": (3,), "angular_velocity": (3,),
                "inertia": (3, 3)}  # fmt: skip
