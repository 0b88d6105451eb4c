"""USD in, USD out: UsdPhysics scenes to SceneBuilders, simulated motion to time-sampled USD.

Import (`load_stage`) reads rigid bodies, mass and joints with `UsdPhysics.UsdPhysicsLoadStageFromPrimRange`,
but takes transforms from `UsdGeom.XformCache` in double precision (the parser's poses are float).
Export (`AnimationWriter`) streams frames into an Sdf layer with the Sdf API (about 4x faster than
`attr.Set`, DESIGN.md) and writes the file atomically. A scene read from a file is exported as a small
layer that sublayers the input and holds `over`s on the body prims; a procedural scene is written whole,
with geometry and UsdPhysics schemas, so that the output reads back with `load_stage`.

Units: the simulator is SI. Inputs are converted with metersPerUnit / kilogramsPerUnit; angles in USD are
degrees. A layered output keeps the input's units and up axis (it composes with the input's geometry).
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from itertools import chain, cycle, repeat
from typing import Any

import numpy as np

from .builder import WORLD, SceneBuilder, SceneError
from .joints import JOINT_TYPES
from .shapes import Shape
from .transforms import quat_conj, quat_mul, quat_rotate

# Above this many bodies a procedural export uses a PointInstancer unless told otherwise. Measured with
# benchmarks/usd_export.py (10,000 bodies x 100 frames): per-body prims hold ~0.7 KB of memory and take
# ~10 us of writing per body and frame, the instancer ~30 B and ~0.2 us. A default run (10 s at 30 fps) of
# 5,000 bodies would hold ~1 GB and write for ~15 s; beyond that the instancer (float positions, half
# orientations, display only) is the better default.
INSTANCER_AUTO_BODIES = 5000

# Per-body frames are buffered attribute-major in numpy (at most this many bytes, or frames) and authored
# one attribute at a time: a run of samples into one attribute's sample map stays in cache, which makes
# authoring 1.5-2x faster than frame by frame (benchmarks/usd_export.py). The buffer is all the Python side
# holds; the samples themselves live in the Sdf layer until it is written.
_CHUNK_BYTES = 32 * 2**20
_CHUNK_FRAMES = 512

_WORLD_PATH = "/World"
_INSTANCER_PATH = "/World/Instancer"
_MODE_KEY = "warpimpulse:mode"
_DOFS = ("transX", "transY", "transZ", "rotX", "rotY", "rotZ")


class UsdSceneError(SceneError):
    """A USD file that cannot be simulated as it is; the message names the file or prim at fault."""


class UnsupportedFeatureError(UsdSceneError):
    """A drive, limit or other authored feature the simulator does not model (see `ignore_unsupported`)."""


def _pxr():
    """Import pxr lazily: `import warpimpulse` must not pay for USD."""
    from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt

    return Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt


# ---------------------------------------------------------------------------------------------- math
def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix (column vectors), w >= 0."""
    m = np.asarray(m, dtype=np.float64).tolist()
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s]
    elif m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = [0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s]
    elif m[1][1] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = [(m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = [(m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s, (m[1][0] - m[0][1]) / s]
    n = math.sqrt(sum(c * c for c in q))
    sign = -1.0 if q[3] < 0.0 else 1.0
    return np.array([sign * c / n for c in q])


def _rot(q) -> np.ndarray:
    """Rotation matrix of one unit quaternion (x, y, z, w); a scalar version of transforms.quat_to_matrix
    (numpy's stacking costs ~50 us a call, which adds up over 10,000 bodies)."""
    x, y, z, w = (float(c) for c in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _qrot(q, v) -> np.ndarray:
    return _rot(q) @ np.asarray(v, dtype=np.float64)


def _qmul(a, b) -> np.ndarray:
    ax, ay, az, aw = (float(c) for c in a)
    bx, by, bz, bw = (float(c) for c in b)
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def _qconj(q) -> np.ndarray:
    return np.array([-float(q[0]), -float(q[1]), -float(q[2]), float(q[3])])


@dataclass
class _Similarity:
    """A decomposed USD matrix: x_world = t + R (s * x_local), s per axis (no shear)."""

    t: np.ndarray
    q: np.ndarray  # (x, y, z, w)
    s: np.ndarray

    @property
    def uniform(self) -> bool:
        return bool(np.ptp(self.s) <= 1e-9 * max(float(np.abs(self.s).max()), 1e-300))


def _decompose(m, what: str) -> _Similarity:
    """Split a USD (row-vector) 4x4 matrix into translation, rotation and per-axis scale."""
    m = np.asarray(m, dtype=np.float64)
    lin = m[:3, :3].T  # column-vector linear part
    s = np.sqrt((lin * lin).sum(axis=0))
    if s.min() < 1e-12:
        raise UsdSceneError(f"{what}: the transform has a zero scale")
    rot = lin / s
    if np.abs(rot.T @ rot - _EYE).max() > 1e-6:
        raise UsdSceneError(f"{what}: the transform has shear (non-uniform scale under a rotation); unsupported")
    (a, b, c), (d, e, f), (g, h, i) = rot.tolist()
    if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) < 0.0:
        raise UsdSceneError(f"{what}: the transform mirrors (negative scale); unsupported")
    return _Similarity(m[3, :3].copy(), quat_from_matrix(rot), s)


_EYE = np.eye(3)


def _gf_quat(q) -> np.ndarray:
    """Gf.Quat* -> (x, y, z, w) float64."""
    im = q.GetImaginary()
    return np.array([im[0], im[1], im[2], q.GetReal()], dtype=np.float64)


def _real(path: str, name: str, value: Any, infinite_ok: bool = False) -> np.ndarray:
    """Attribute `name` of prim `path` as float64 (a Gf quaternion as x, y, z, w). NaN, or infinity unless
    `infinite_ok`, is an error naming both: let through, it would surface later, after numpy RuntimeWarnings,
    as an error about something else (or as nothing at all)."""
    a = _gf_quat(value) if hasattr(value, "GetReal") else np.asarray(value, dtype=np.float64)
    if np.any(np.isnan(a)) or not (infinite_ok or np.all(np.isfinite(a))):
        raise UsdSceneError(f"{path}: {name} is not finite: {value}")
    return a


def _unit_quat(path: str, name: str, value: Any) -> np.ndarray:
    """A quaternion attribute, normalized. The zero quaternion is no rotation at all (XformCache reads it as
    the identity, placing the prim wrong without a word), so it is an error naming the prim."""
    q = _real(path, name, value)
    n = float(np.linalg.norm(q))
    if n == 0.0:
        raise UsdSceneError(
            f"{path}: {name} is the zero quaternion, which is no rotation (the identity is (1, 0, 0, 0))"
        )
    return q / n


class _Xforms:
    """World matrices from an XformCache, after checking the xformOps of the prim and its ancestors (each
    prim once): the cache reads a zero or NaN orient as the identity and drops a non-finite matrix op."""

    def __init__(self) -> None:
        _, _, _, Usd, UsdGeom, *_ = _pxr()
        self._cache = UsdGeom.XformCache(Usd.TimeCode.Default())
        self._xformable = UsdGeom.Xformable
        self._orient = UsdGeom.XformOp.TypeOrient
        self._checked: set[str] = set()

    def _check(self, prim) -> None:
        while prim and not prim.IsPseudoRoot() and str(prim.GetPath()) not in self._checked:
            path = str(prim.GetPath())
            if prim.IsA(self._xformable):
                for op in self._xformable(prim).GetOrderedXformOps():
                    value = op.Get()
                    if value is None:
                        continue
                    if op.GetOpType() == self._orient:
                        _unit_quat(path, op.GetName(), value)
                    else:
                        _real(path, op.GetName(), value)
            self._checked.add(path)
            prim = prim.GetParent()

    def world(self, prim) -> np.ndarray:
        """The prim's local-to-world matrix (USD row-vector convention)."""
        self._check(prim)
        return np.asarray(self._cache.GetLocalToWorldTransform(prim), dtype=np.float64)

    def parent(self, prim) -> np.ndarray:
        """The matrix of the prim's parent frame, in which its own xformOps and velocities are authored."""
        self._check(prim)
        return np.asarray(self._cache.GetParentToWorldTransform(prim), dtype=np.float64)


def _frame_axes(axis: np.ndarray, second: np.ndarray | None = None) -> np.ndarray:
    """A rotation matrix whose first column is `axis` (second column along `second` if given)."""
    x = axis / np.linalg.norm(axis)
    if second is None:
        second = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = second - np.dot(second, x) * x
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


# ---------------------------------------------------------------------------------------------- scene
@dataclass
class UsdScene:
    """A SceneBuilder plus what export needs to put simulated bodies back on their prims.

    Per body (builder order): prim path, centre-of-mass offset in the prim's rigid frame (stage units),
    the prim's own scale, and its parent frame: relative to the world (`parent_index` -1) or to an
    ancestor rigid body, as translation / rotation / uniform scale.
    """

    builder: SceneBuilder
    source_path: str | None
    body_paths: list[str]
    joint_paths: list[str]
    com_offsets: np.ndarray
    body_scales: np.ndarray
    parent_index: np.ndarray
    parent_pos: np.ndarray
    parent_quat: np.ndarray
    parent_scale: np.ndarray
    reset_xform_stack: np.ndarray
    meters_per_unit: float = 1.0
    kilograms_per_unit: float = 1.0
    up_axis: str = "Z"
    default_prim: str = ""
    xform_ops: list[tuple[str, str]] | None = None  # (translate, orient) op names per body; None: plain
    loop_joints: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    dt: float | None = None  # the step size the file asks for (customLayerData warpimpulse:dt), if any

    @property
    def body_count(self) -> int:
        return len(self.body_paths)


def scene_from_builder(builder: SceneBuilder) -> UsdScene:
    """The UsdScene of a procedural builder: bodies at /World/<name>, centre of mass at the prim origin."""
    _, _, Tf, *_ = _pxr()
    n = len(builder.bodies)
    paths, used = [], set()
    for b in builder.bodies:
        base = Tf.MakeValidIdentifier(b.name.strip("/").replace("/", "_") or "body")
        name, k = base, 1
        while name in used or name in ("Joints", "PhysicsScene", "Instancer"):
            name, k = f"{base}_{k}", k + 1
        used.add(name)
        paths.append(f"{_WORLD_PATH}/{name}")
    joint_paths, used = [], set()
    for j in builder.joints:
        base = Tf.MakeValidIdentifier(j.name.strip("/").replace("/", "_") or "joint")
        name, k = base, 1
        while name in used:
            name, k = f"{base}_{k}", k + 1
        used.add(name)
        joint_paths.append(f"{_WORLD_PATH}/Joints/{name}")
    ident = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    return UsdScene(
        builder=builder, source_path=None, body_paths=paths, joint_paths=joint_paths,
        com_offsets=np.zeros((n, 3)), body_scales=np.ones((n, 3)), parent_index=np.full(n, -1),
        parent_pos=np.zeros((n, 3)), parent_quat=ident, parent_scale=np.ones(n),
        reset_xform_stack=np.zeros(n, dtype=bool), default_prim="World",
    )  # fmt: skip


def _as_scene(scene: UsdScene | SceneBuilder | Any) -> UsdScene:
    if isinstance(scene, UsdScene):
        return scene
    if isinstance(scene, SceneBuilder):
        return scene_from_builder(scene)
    builder = getattr(scene, "builder", None)  # a Model
    if isinstance(builder, SceneBuilder):
        return scene_from_builder(builder)
    raise TypeError(f"expected a UsdScene, SceneBuilder or Model, got {type(scene).__name__}")


# ---------------------------------------------------------------------------------------------- import
def _open_stage(path: str):
    _, _, Tf, Usd, *_ = _pxr()
    if not os.path.isfile(path):
        raise UsdSceneError(f"{path}: no such file")
    try:
        stage = Usd.Stage.Open(path)
    except Tf.ErrorException as exc:
        first = str(exc).strip().splitlines()[-1] if str(exc).strip() else ""
        raise UsdSceneError(f"{path}: not a USD file that can be opened ({first.strip()})") from None
    if stage is None:
        raise UsdSceneError(f"{path}: not a USD file that can be opened")
    return stage


class _Reporter:
    """Unsupported features: an error naming the prim, or a warning when told to ignore them."""

    def __init__(self, ignore: bool, notes: list[str]) -> None:
        self.ignore = ignore
        self.notes = notes

    def unsupported(self, prim: str, what: str) -> None:
        if not self.ignore:
            raise UnsupportedFeatureError(
                f"{prim}: {what} is not simulated by warpimpulse (pass ignore_unsupported=True / "
                f"--ignore-unsupported to drop it with a warning)"
            )
        msg = f"{prim}: {what} is not simulated; ignored"
        self.notes.append(msg)
        warnings.warn(msg, stacklevel=4)

    def note(self, msg: str) -> None:
        self.notes.append(msg)
        warnings.warn(msg, stacklevel=4)


def _shape_mass_info(prim, body_frame: _Similarity, xforms: _Xforms, report: _Reporter):
    """MassInformation (unit density) of one collision prim, in the body's rigid frame."""
    Gf, _, _, _, UsdGeom, UsdPhysics, _ = _pxr()
    path = str(prim.GetPath())
    sim = _decompose(xforms.world(prim), path)
    kind, axis = None, 2

    def dim(name: str) -> float:
        value = float(_real(path, name, prim.GetAttribute(name).Get()))
        if value < 0.0:
            raise UsdSceneError(f"{path}: {name} must not be negative, got {value}")
        return value

    if prim.IsA(UsdGeom.Cube):
        shape, kind = Shape("box", size=tuple(float(v) for v in dim("size") * sim.s)), "box"
    elif prim.IsA(UsdGeom.Sphere):
        shape, kind = Shape("sphere", radius=dim("radius") * float(sim.s.max())), "sphere"
    elif prim.IsA(UsdGeom.Capsule) or prim.IsA(UsdGeom.Cylinder):
        kind = "capsule" if prim.IsA(UsdGeom.Capsule) else "cylinder"
        axis = "XYZ".index(str(prim.GetAttribute("axis").Get() or "Z"))
        others = [sim.s[i] for i in range(3) if i != axis]
        shape = Shape(kind, radius=dim("radius") * float(max(others)), length=dim("height") * float(sim.s[axis]))
    else:
        extent = prim.GetAttribute("extent").Get() if prim.HasAttribute("extent") else None
        if not extent or len(extent) != 2:
            raise UsdSceneError(f"{path}: cannot compute the mass of a {prim.GetTypeName()} collider without extent")
        lo, hi = _real(path, "extent", extent)
        size = (hi - lo) * sim.s
        report.note(f"{path}: mass of a {prim.GetTypeName()} collider approximated by its extent box")
        shape, kind = Shape("box", size=tuple(float(v) for v in size)), "box"
        sim.t = sim.t + _qrot(sim.q, 0.5 * (lo + hi) * sim.s)
    volume = shape.volume()
    inertia = shape.inertia(volume)  # density 1
    if kind in ("capsule", "cylinder") and axis != 2:
        perm = {0: [2, 1, 0], 1: [0, 2, 1]}[axis]  # move the symmetry axis (z moments) onto `axis`
        inertia = inertia[np.ix_(perm, perm)]
    info = UsdPhysics.RigidBodyAPI.MassInformation()
    info.volume = float(volume)
    info.inertia = Gf.Matrix3f(*[float(v) for v in inertia.reshape(-1)])
    info.centerOfMass = Gf.Vec3f(0.0, 0.0, 0.0)
    local_pos = _qrot(_qconj(body_frame.q), sim.t - body_frame.t)
    local_rot = _qmul(_qconj(body_frame.q), sim.q)
    info.localPos = Gf.Vec3f(*[float(v) for v in local_pos])
    info.localRot = Gf.Quatf(float(local_rot[3]), *[float(v) for v in local_rot[:3]])
    return info


def _body_mass(prim, desc, frame: _Similarity, xforms: _Xforms, report: _Reporter):
    """(mass, diagonal inertia, centre of mass in the rigid frame, principal axes xyzw), stage units."""
    _, _, _, _, _, UsdPhysics, _ = _pxr()
    path = str(prim.GetPath())
    mass_api = UsdPhysics.MassAPI(prim) if prim.HasAPI(UsdPhysics.MassAPI) else None
    mass = density = 0.0
    diag = np.zeros(3)
    com = None
    axes = None
    if mass_api:
        mass = float(mass_api.GetMassAttr().Get() or 0.0)
        density = float(mass_api.GetDensityAttr().Get() or 0.0)
        diag = _real(path, "physics:diagonalInertia", mass_api.GetDiagonalInertiaAttr().Get() or (0.0, 0.0, 0.0))
        c = mass_api.GetCenterOfMassAttr().Get()
        if c is not None and not np.all(np.isneginf(np.asarray(c, dtype=np.float64))):  # -inf's mean unset
            com = _real(path, "physics:centerOfMass", c) * frame.s
        pa = mass_api.GetPrincipalAxesAttr().Get()
        if pa is not None and np.any(_real(path, "physics:principalAxes", pa)):  # (0, 0, 0, 0) means unset
            axes = _unit_quat(path, "physics:principalAxes", pa)
    for name, value in (("physics:mass", mass), ("physics:density", density)):  # 0 means unset
        if not (value >= 0.0 and math.isfinite(value)):
            raise UsdSceneError(f"{path}: {name} must be positive and finite, got {value}")
    if np.any(diag != 0.0) and np.any(diag <= 0.0):
        raise UsdSceneError(f"{path}: the inertia (physics:diagonalInertia) must be positive, got {diag.tolist()}")
    shapes = [str(p) for p in desc.collisions]
    if not shapes:
        if mass <= 0.0:
            zero = mass_api is not None and mass_api.GetMassAttr().HasAuthoredValue()
            raise UsdSceneError(
                f"{path}: physics:mass = 0 means 'compute it from the collision shapes', and the body has none"
                if zero
                else f"{path}: rigid body with neither a mass (MassAPI physics:mass) nor collision shapes to compute it"
            )
        if np.all(diag == 0.0):
            raise UsdSceneError(
                f"{path}: rigid body has a mass but no physics:diagonalInertia and no collision shapes to compute it"
            )
    if mass > 0.0 and np.all(diag > 0.0) and (com is not None or not shapes):
        # Everything authored: read it in double precision, no shape traversal.
        return mass, diag, com if com is not None else np.zeros(3), axes if axes is not None else _IDENT_Q
    stage = prim.GetStage()

    def info_fn(shape_prim):
        return _shape_mass_info(shape_prim, frame, xforms, report)

    for s in shapes:  # fail here with the shape's own path rather than inside the callback
        _shape_mass_info(stage.GetPrimAtPath(s), frame, xforms, _Reporter(True, []))
    m, d, c, pa = UsdPhysics.RigidBodyAPI(prim).ComputeMassProperties(info_fn)
    diag = np.array(d, dtype=np.float64)
    if not (m > 0.0 and math.isfinite(m)):
        raise UsdSceneError(f"{path}: computed mass is not positive ({m})")
    if np.any(diag <= 0.0):
        raise UsdSceneError(f"{path}: inertia is not positive ({diag.tolist()})")
    return float(m), diag, np.array(c, dtype=np.float64), _gf_quat(pa) / max(pa.GetLength(), 1e-30)


_IDENT_Q = np.array([0.0, 0.0, 0.0, 1.0])
# Joint attributes that may be infinite (no limit, unbreakable) but not NaN: limits of every joint type
# (physics:lowerLimit, physics:coneAngle0Limit, limit:rotX:physics:low, ...) and break thresholds.
_JOINT_BOUNDS = ("Limit", ":physics:low", ":physics:high", "physics:breakForce", "physics:breakTorque")
# Under a non-uniform scale a rigid motion needs a shearing local matrix (a matrix op, or orient-scale-orient),
# not the translate / orient pair that is animated; such bodies (rare) are refused with this advice.
_NON_UNIFORM = "unsupported: move the body out from under the scale, or bake the scale into the geometry"


def _joint_frame(stage, joint_prim, side: int, xforms: _Xforms, mpu: float) -> tuple[np.ndarray, np.ndarray]:
    """World (anchor in metres, rotation xyzw) of a joint's frame on body `side` (0 or 1)."""
    jpath = str(joint_prim.GetPath())
    pos = joint_prim.GetAttribute(f"physics:localPos{side}").Get()
    rot = joint_prim.GetAttribute(f"physics:localRot{side}").Get()
    pos = np.zeros(3) if pos is None else _real(jpath, f"physics:localPos{side}", pos)
    rot = _IDENT_Q.copy() if rot is None else _unit_quat(jpath, f"physics:localRot{side}", rot)
    rel = joint_prim.GetRelationship(f"physics:body{side}")
    targets = rel.GetTargets() if rel else []
    if not targets:
        return pos * mpu, rot
    target = stage.GetPrimAtPath(targets[0])
    frame = _decompose(xforms.world(target), str(targets[0]))
    anchor = frame.t + _qrot(frame.q, frame.s * pos)
    return anchor * mpu, _qmul(frame.q, rot)


@dataclass
class _JointPlan:
    kind: str  # a JOINT_TYPES name, or a basic constraint name
    axis: np.ndarray | None = None  # world
    axis_child: np.ndarray | None = None


def _d6_plans(locked_t: set[int], locked_r: set[int], r0: np.ndarray, r1: np.ndarray) -> list[_JointPlan]:
    """Map a generic joint's locked axes to a combined joint, or to one or two basic constraints.

    r0 / r1: world rotation matrices of the joint frame on body0 / body1 (columns = joint X, Y, Z).
    """
    nt, nr = len(locked_t), len(locked_r)
    free_t = sorted({0, 1, 2} - locked_t)
    free_r = sorted({0, 1, 2} - locked_r)
    trans = rot = None
    if nt == 3:
        trans = _JointPlan("point")
    elif nt == 2:
        trans = _JointPlan("line", r0[:, free_t[0]])
    elif nt == 1:
        trans = _JointPlan("plane", r0[:, next(iter(locked_t))])
    if nr == 3:
        rot = _JointPlan("rotation")
    elif nr == 2:
        rot = _JointPlan("axis", r0[:, free_r[0]])
    elif nr == 1:
        k = next(iter(locked_r))  # twist about k locked: keep the angle between axes (k+1) of body0, (k+2) of body1
        rot = _JointPlan("angle", r0[:, (k + 1) % 3], r1[:, (k + 2) % 3])
    t_axis = free_t[0] if nt == 2 else (next(iter(locked_t)) if nt == 1 else None)
    r_axis = free_r[0] if nr == 2 else None
    if trans and trans.kind == "point":
        if rot is None:
            return [_JointPlan("ball")]
        if rot.kind == "rotation":
            return [_JointPlan("fixed")]
        if rot.kind == "axis":
            return [_JointPlan("revolute", rot.axis)]
        return [_JointPlan("universal", rot.axis, rot.axis_child)]
    if trans and rot and rot.kind == "rotation" and trans.kind == "line":
        return [_JointPlan("prismatic", trans.axis)]
    if trans and rot and rot.kind == "axis" and t_axis == r_axis:
        return [_JointPlan("cylindrical" if trans.kind == "line" else "planar", trans.axis)]
    return [p for p in (trans, rot) if p is not None]


def _check_limits_drives(desc, path: str, report: _Reporter) -> tuple[set[int], set[int]]:
    """Locked DOFs of a D6 joint; finite limits and drives are reported as unsupported."""
    _, _, _, _, _, UsdPhysics, _ = _pxr()
    dof_index = {
        UsdPhysics.JointDOF.TransX: 0, UsdPhysics.JointDOF.TransY: 1, UsdPhysics.JointDOF.TransZ: 2,
        UsdPhysics.JointDOF.RotX: 3, UsdPhysics.JointDOF.RotY: 4, UsdPhysics.JointDOF.RotZ: 5,
    }  # fmt: skip
    locked_t, locked_r = set(), set()
    for pair in desc.jointLimits:
        dof, limit = pair.first, pair.second
        if not limit.enabled:
            continue
        if dof not in dof_index:
            report.unsupported(path, f"a {dof.name} limit")
            continue
        i = dof_index[dof]
        if limit.lower > limit.upper or (limit.lower == limit.upper == 0.0):
            (locked_t if i < 3 else locked_r).add(i % 3)
        else:
            report.unsupported(path, f"a {_DOFS[i]} limit [{limit.lower}, {limit.upper}]")
    for pair in desc.jointDrives:
        if pair.second.enabled:
            report.unsupported(path, f"a {pair.first.name} drive")
    return locked_t, locked_r


def load_stage(path: str | os.PathLike, ignore_unsupported: bool = False) -> UsdScene:
    """Read a UsdPhysics scene into a SceneBuilder (SI units) plus what export needs.

    Body and joint names in the builder are their prim paths. Raises `UsdSceneError` (a `SceneError`)
    naming the prim for input that cannot be simulated; drives, limits and break forces raise
    `UnsupportedFeatureError` unless `ignore_unsupported`, which warns and drops them.
    """
    _, Sdf, _, _, UsdGeom, UsdPhysics, _ = _pxr()
    path = os.fspath(path)
    stage = _open_stage(path)
    notes: list[str] = []
    report = _Reporter(ignore_unsupported, notes)
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    kpu = float(UsdPhysics.GetStageKilogramsPerUnit(stage))
    for key, value in (("metersPerUnit", mpu), ("kilogramsPerUnit", kpu)):
        if not (value > 0.0 and math.isfinite(value)):
            raise UsdSceneError(f"{path}: the stage's {key} must be positive and finite, got {value}")
    up = str(UsdGeom.GetStageUpAxis(stage))
    try:
        parsed = UsdPhysics.UsdPhysicsLoadStageFromPrimRange(stage, [Sdf.Path("/")])
    except Exception as exc:  # noqa: BLE001 - the parser raises Tf errors of several kinds
        raise UsdSceneError(f"{path}: the UsdPhysics parser failed: {exc}") from None
    T = UsdPhysics.ObjectType
    get = lambda t: list(zip(*parsed[t])) if t in parsed else []  # noqa: E731

    # Gravity.
    scenes = get(T.Scene)
    up_vec = {"X": [1.0, 0, 0], "Y": [0, 1.0, 0], "Z": [0, 0, 1.0]}[up]
    if scenes:
        if len(scenes) > 1:
            report.note(f"{path}: {len(scenes)} PhysicsScene prims; using {scenes[0][0]}")
        spath, sd = str(scenes[0][0]), scenes[0][1]
        direction = _real(spath, "physics:gravityDirection", sd.gravityDirection)
        magnitude = float(_real(spath, "physics:gravityMagnitude", sd.gravityMagnitude))
        if np.linalg.norm(direction) < 1e-12:
            direction = -np.array(up_vec)
        gravity = direction / np.linalg.norm(direction) * magnitude * mpu
    else:
        gravity = -np.array(up_vec) * 9.81
        notes.append(f"{path}: no PhysicsScene; gravity 9.81 m/s^2 down the up axis ({up})")
    builder = SceneBuilder(gravity=gravity)

    xforms = _Xforms()
    order = {str(p.GetPath()): k for k, p in enumerate(stage.Traverse())}  # bodies and joints in file order
    bodies = sorted(get(T.RigidBody), key=lambda pd: order.get(str(pd[0]), len(order)))
    index: dict[str, int] = {}
    n = len(bodies)
    com_offsets, scales = np.zeros((n, 3)), np.ones((n, 3))
    parent_index = np.full(n, -1)
    parent_pos, parent_quat, parent_scale = np.zeros((n, 3)), np.tile(_IDENT_Q, (n, 1)), np.ones(n)
    reset = np.zeros(n, dtype=bool)
    xform_ops: list[tuple[str, str]] = []
    frames: list[_Similarity] = []
    for i, (p, desc) in enumerate(bodies):
        bpath = str(p)
        prim = stage.GetPrimAtPath(p)
        frame = _decompose(xforms.world(prim), bpath)
        frames.append(frame)
        scales[i] = frame.s
        xform_ops.append(_op_names(prim))
        static = bool(desc.kinematicBody) or not bool(desc.rigidBodyEnabled)
        if desc.kinematicBody:
            notes.append(f"{bpath}: kinematic body; held at its initial pose")
        if static:
            mass, diag, com, axes = 0.0, np.ones(3), np.zeros(3), _IDENT_Q
        else:
            mass, diag, com, axes = _body_mass(prim, desc, frame, xforms, report)
        com_offsets[i] = com
        position = (frame.t + _qrot(frame.q, com)) * mpu
        rpa = _rot(axes)
        inertia = rpa @ np.diag(diag) @ rpa.T * (kpu * mpu * mpu)
        # Velocities are authored in the space of the prim's xform, i.e. its parent's frame.
        pq = _decompose(xforms.parent(prim), bpath).q
        v = _qrot(pq, _real(bpath, "physics:velocity", desc.linearVelocity)) * mpu
        w = _qrot(pq, np.radians(_real(bpath, "physics:angularVelocity", desc.angularVelocity)))
        try:
            if static:
                index[bpath] = builder.add_static_body(position, frame.q, name=bpath)
            else:
                index[bpath] = builder.add_body(mass * kpu, inertia, position, frame.q, v, w, name=bpath)
        except SceneError as exc:
            raise UsdSceneError(str(exc) if bpath in str(exc) else f"{bpath}: {exc}") from None
        _read_forces(builder, prim, index[bpath], mpu, kpu)
    # Parent frames: the world, or the nearest ancestor rigid body (whose motion moves this prim).
    for i, (p, _desc) in enumerate(bodies):
        prim = stage.GetPrimAtPath(p)
        reset[i] = UsdGeom.Xformable(prim).GetResetXformStack() if prim.IsA(UsdGeom.Xformable) else False
        if reset[i]:
            continue
        anc = _rigid_ancestor(prim.GetParent(), index)
        parent_m = xforms.parent(prim)
        if anc is not None:
            a = index[str(anc.GetPath())]
            if not frames[a].uniform:
                raise UsdSceneError(f"{p}: rigid body under a non-uniformly scaled rigid body {anc.GetPath()}; "
                                    f"{_NON_UNIFORM}")  # fmt: skip
            anc_m = xforms.world(anc)
            rel = _decompose(parent_m @ np.linalg.inv(anc_m), f"{p} (relative to {anc.GetPath()})")
            parent_index[i] = a
        else:
            rel = _decompose(parent_m, f"{p} (parent transform)")
        if not rel.uniform:
            raise UsdSceneError(f"{p}: rigid body under a non-uniformly scaled parent (scale "
                                f"{np.round(rel.s, 9).tolist()}); {_NON_UNIFORM}")  # fmt: skip
        parent_pos[i], parent_quat[i], parent_scale[i] = rel.t, rel.q, rel.s[0]

    joint_paths: list[str] = []
    loop_joints: list[str] = []
    supported = {T.RevoluteJoint, T.PrismaticJoint, T.SphericalJoint, T.FixedJoint, T.D6Joint}
    all_joints = []
    for t, (paths, descs) in parsed.items():
        if "Joint" in t.name:
            all_joints += [(str(p), t, d) for p, d in zip(paths, descs)]
    for jpath, t, desc in sorted(all_joints, key=lambda x: order.get(x[0], len(order))):
        jprim = stage.GetPrimAtPath(jpath)
        if not desc.jointEnabled:
            notes.append(f"{jpath}: joint disabled (physics:jointEnabled = false); skipped")
            continue
        if t not in supported:
            report.unsupported(jpath, _joint_type_text(jprim.GetTypeName() or t.name))
            continue
        ends = []
        for side, rel in ((0, desc.rel0), (1, desc.rel1)):
            if rel.isEmpty:
                ends.append(None)
                continue
            target = stage.GetPrimAtPath(rel)
            if not target:
                raise UsdSceneError(f"{jpath}: physics:body{side} targets {rel}, which does not exist")
            # Not the parser's body0/body1: it leaves out bodies with physics:rigidBodyEnabled = false (static here).
            body = _rigid_ancestor(target, index)
            if body is None:
                raise UsdSceneError(
                    f"{jpath}: physics:body{side} targets {rel}, which is not a rigid body or inside one "
                    f"(leave physics:body{side} empty to attach the joint to the world)"
                )
            ends.append(index[str(body.GetPath())])
        if ends[0] is None and ends[1] is None:
            raise UsdSceneError(f"{jpath}: both physics:body0 and physics:body1 are empty")
        for attr in jprim.GetAuthoredAttributes():  # the parser reads a NaN limit as no limit
            if attr.GetName().endswith(_JOINT_BOUNDS) and attr.Get() is not None:
                _real(jpath, attr.GetName(), attr.Get(), infinite_ok=True)
        if math.isfinite(desc.breakForce) or math.isfinite(desc.breakTorque):
            report.unsupported(jpath, "a break force or torque")
        a0, q0 = _joint_frame(stage, jprim, 0, xforms, mpu)
        a1, q1 = _joint_frame(stage, jprim, 1, xforms, mpu)
        r0, r1 = _rot(q0), _rot(q1)
        if t in (T.RevoluteJoint, T.PrismaticJoint):
            token = jprim.GetAttribute("physics:axis").Get()
            if token not in ("X", "Y", "Z"):  # the parser reads any other token as X
                raise UsdSceneError(f"{jpath}: physics:axis must be X, Y or Z, got {token!r}")
            if desc.limit.enabled:
                report.unsupported(jpath, f"a limit [{desc.limit.lower}, {desc.limit.upper}]")
            if desc.drive.enabled:
                report.unsupported(jpath, "a drive")
            ax = r0[:, "XYZ".index(token)]
            plans = [_JointPlan("revolute" if t == T.RevoluteJoint else "prismatic", ax)]
        elif t == T.SphericalJoint:
            if desc.limit.enabled:
                report.unsupported(jpath, "a cone limit")
            plans = [_JointPlan("ball")]
        elif t == T.FixedJoint:
            plans = [_JointPlan("fixed")]
        else:
            locked_t, locked_r = _check_limits_drives(desc, jpath, report)
            plans = _d6_plans(locked_t, locked_r, r0, r1)
            if not plans:
                notes.append(f"{jpath}: generic joint with no locked axis constrains nothing; skipped")
                continue
        gap = float(np.linalg.norm(a0 - a1))
        if gap > 1e-5 * max(1.0, float(np.abs(a0).max())):
            notes.append(f"{jpath}: the joint frames of body0 and body1 are {gap:.3g} m apart; using body0's")
        parent, child = ends
        if child is None:  # body1 empty: the world is on the child side; swap so the child is a body
            parent, child = None, parent
            plans = [_JointPlan(p.kind, p.axis_child if p.axis_child is not None else p.axis,
                                p.axis if p.axis_child is not None else None) for p in plans]  # fmt: skip
        if desc.excludeFromArticulation:
            loop_joints.append(jpath)
        for plan in plans:
            try:
                if plan.kind in JOINT_TYPES:
                    builder.add_joint(plan.kind, parent, child, a0, plan.axis, plan.axis_child, jpath)
                else:
                    builder.add_constraint(plan.kind, parent, child, a0, plan.axis, plan.axis_child, jpath)
            except SceneError as exc:
                raise UsdSceneError(str(exc) if jpath in str(exc) else f"{jpath}: {exc}") from None
            joint_paths.append(jpath)
    parsed_joints = {j[0] for j in all_joints}
    for prim in stage.Traverse():  # typed joints the parser did not report (e.g. custom joint schemas)
        if prim.IsA(UsdPhysics.Joint) and str(prim.GetPath()) not in parsed_joints:
            report.unsupported(str(prim.GetPath()), _joint_type_text(prim.GetTypeName()))
    if not bodies:
        raise UsdSceneError(f"{path}: no rigid bodies (UsdPhysics RigidBodyAPI) in the stage")
    default_prim = stage.GetDefaultPrim()
    default_prim_name = default_prim.GetName() if default_prim else ""
    if not default_prim_name:  # give the output a default prim even if the input lacks one
        roots = [p for p in stage.GetPseudoRoot().GetChildren() if p.IsDefined()]
        default_prim_name = roots[0].GetName() if roots else ""
    return UsdScene(
        builder=builder, source_path=os.path.abspath(path), body_paths=[str(p) for p, _ in bodies],
        joint_paths=joint_paths, com_offsets=com_offsets, body_scales=scales, parent_index=parent_index,
        parent_pos=parent_pos, parent_quat=parent_quat, parent_scale=parent_scale, reset_xform_stack=reset,
        meters_per_unit=mpu, kilograms_per_unit=kpu, up_axis=up, default_prim=default_prim_name,
        xform_ops=xform_ops, loop_joints=loop_joints, notes=notes, dt=_recorded_dt(stage, path),
    )  # fmt: skip


def _rigid_ancestor(prim, index: dict[str, int]):
    """The nearest rigid body at or above `prim` (one whose motion moves it), or None."""
    while prim and not prim.IsPseudoRoot():
        if str(prim.GetPath()) in index:
            return prim
        prim = prim.GetParent()
    return None


def _recorded_dt(stage, path: str) -> float | None:
    """The step size a scene file records (our outputs and `save_scene` write it): some scenes need one."""
    dt = stage.GetRootLayer().customLayerData.get("warpimpulse:dt")
    if dt is None:
        return None
    if not (isinstance(dt, (int, float)) and not isinstance(dt, bool) and dt > 0.0 and math.isfinite(dt)):
        raise UsdSceneError(f"{path}: customLayerData warpimpulse:dt must be a positive number of seconds, got {dt!r}")
    return float(dt)


def _joint_type_text(type_name: str) -> str:
    return f"the joint type {type_name} (supported: revolute, prismatic, spherical, fixed and generic D6 joints)"


def _op_names(prim) -> tuple[str, str]:
    """xformOp names for the exported pose: the plain ones unless the input gave them other value types
    (an `over` of another type is a validation error), then ones with a `:warpimpulse` suffix."""
    ops = []
    for op, type_name in (("xformOp:translate", "double3"), ("xformOp:orient", "quatd")):
        attr = prim.GetAttribute(op)
        clash = attr and attr.HasAuthoredValue() and str(attr.GetTypeName()) != type_name
        ops.append(f"{op}:warpimpulse" if clash else op)
    return ops[0], ops[1]


def _read_forces(builder: SceneBuilder, prim, body: int, mpu: float, kpu: float) -> None:
    """Constant forces written by `save_scene` (custom warpimpulse:* attributes; UsdPhysics has none)."""
    attr = prim.GetAttribute("warpimpulse:forces")
    if not attr:
        return
    forces = np.array(attr.Get() or [], dtype=np.float64).reshape(-1, 3)
    torques = np.array(prim.GetAttribute("warpimpulse:torques").Get() or [], dtype=np.float64).reshape(-1, 3)
    until = np.array(prim.GetAttribute("warpimpulse:forceUntil").Get() or [], dtype=np.float64)
    if not len(forces) == len(torques) == len(until):
        raise UsdSceneError(f"{prim.GetPath()}: warpimpulse:forces, :torques and :forceUntil differ in length")
    for f, t, u in zip(forces, torques, until):
        builder.add_force(body, f * kpu * mpu, t * kpu * mpu * mpu, float(u))


# ---------------------------------------------------------------------------------------------- export
def _local_poses(scene: UsdScene, positions: np.ndarray, orientations: np.ndarray):
    """Simulated centres of mass (metres) -> local translate (stage units) and orient of each body prim."""
    pos = np.asarray(positions, dtype=np.float64) / scene.meters_per_unit
    q = np.asarray(orientations, dtype=np.float64)
    origin = pos - quat_rotate(q, scene.com_offsets) if scene.com_offsets.any() else pos
    a = scene.parent_index
    nested = a >= 0
    reset = scene.reset_xform_stack
    if not nested.any():
        pt, pq, ps = scene.parent_pos, scene.parent_quat, scene.parent_scale
        if not (pt.any() or reset.any() or (ps != 1.0).any() or (pq != _IDENT_Q).any()):
            return origin, q + 0.0  # every parent frame is the world's (procedural scenes); + 0.0: no -0 in files
    else:  # parent frame = ancestor body's simulated pose composed with the static relative transform
        anc = np.where(nested, a, 0)
        anc_t = np.where(nested[:, None], origin[anc], 0.0)
        anc_q = np.where(nested[:, None], q[anc], _IDENT_Q)
        anc_s = np.where(nested, scene.body_scales[anc, 0], 1.0)
        pt = anc_t + anc_s[:, None] * quat_rotate(anc_q, scene.parent_pos)
        pq = quat_mul(anc_q, scene.parent_quat)
        ps = anc_s * scene.parent_scale
    if reset.any():
        pt = np.where(reset[:, None], 0.0, pt)
        pq = np.where(reset[:, None], _IDENT_Q, pq)
        ps = np.where(reset, 1.0, ps)
    pq_conj = quat_conj(pq)
    local_t = quat_rotate(pq_conj, origin - pt) / ps[:, None]
    local_q = quat_mul(pq_conj, q)
    return local_t, local_q


def _body_display_shape(body) -> Shape:
    """The body's shape, or a sphere of matching mean inertia for bodies without one."""
    if body.shape is not None:
        return body.shape
    if body.static or body.mass <= 0.0:
        return Shape("sphere", radius=0.05, color=(0.5, 0.5, 0.5))
    moment = float(np.trace(body.inertia)) / 3.0
    return Shape("sphere", radius=max(math.sqrt(2.5 * moment / body.mass), 1e-3), color=(0.6, 0.6, 0.6))


class _Sdf:
    """Small helpers over Sdf specs (the fast, schema-free way to author)."""

    def __init__(self) -> None:
        Gf, Sdf, _, _, _, _, Vt = _pxr()
        self.Gf, self.Sdf, self.Vt = Gf, Sdf, Vt
        self.T = Sdf.ValueTypeNames

    def prim(self, layer, path: str, type_name: str = "", specifier=None, schemas: Iterable[str] = ()):
        Sdf = self.Sdf
        spec = Sdf.CreatePrimInLayer(layer, path)
        spec.specifier = Sdf.SpecifierDef if specifier is None else specifier
        if type_name:
            spec.typeName = type_name
        if schemas:
            spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=list(schemas)))
        return spec

    def attr(self, spec, name: str, type_name, value=None, uniform: bool = False, custom: bool = False):
        Sdf = self.Sdf
        var = Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying
        a = Sdf.AttributeSpec(spec, name, type_name, var, custom)
        if value is not None:
            a.default = value
        return a

    def rel(self, spec, name: str, targets: list[str]) -> None:
        r = self.Sdf.RelationshipSpec(spec, name, False)
        for t in targets:
            r.targetPathList.explicitItems.append(self.Sdf.Path(t))

    def vec3f(self, v) -> Any:
        return self.Gf.Vec3f(*[float(x) for x in v])

    def quatf(self, q) -> Any:
        return self.Gf.Quatf(float(q[3]), float(q[0]), float(q[1]), float(q[2]))

    def quatd(self, q) -> Any:
        return self.Gf.Quatd(float(q[3]), float(q[0]), float(q[1]), float(q[2]))


def _f(v: float) -> str:
    """A float as usda text that parses back to the same double."""
    return repr(float(v))


def _tup(v) -> str:
    return "(" + ", ".join(map(repr, map(float, v))) + ")"


def _quat_text(q) -> str:
    """(x, y, z, w) -> usda quaternion text, real part first."""
    return f"({_f(q[3])}, {_f(q[0])}, {_f(q[1])}, {_f(q[2])})"


def _geometry_usda(name: str, shape: Shape, indent: str) -> str:
    """One Capsule / Cube / Sphere / Cylinder prim (local z axis, centred) with a display colour, as usda."""
    r, ln = shape.radius, shape.length
    if shape.kind in ("capsule", "cylinder"):
        cap = r if shape.kind == "capsule" else 0.0
        type_name = "Capsule" if shape.kind == "capsule" else "Cylinder"
        body = [f"double radius = {_f(r)}", f"double height = {_f(ln)}", 'uniform token axis = "Z"']
        lo, hi = (-r, -r, -(0.5 * ln + cap)), (r, r, 0.5 * ln + cap)
    elif shape.kind == "sphere":
        type_name, body = "Sphere", [f"double radius = {_f(r)}"]
        lo, hi = (-r, -r, -r), (r, r, r)
    else:
        type_name = "Cube"
        body = ["double size = 1", f"double3 xformOp:scale = {_tup(shape.size)}",
                'uniform token[] xformOpOrder = ["xformOp:scale"]']  # fmt: skip
        lo, hi = (-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)
    body.append(f"float3[] extent = [{_tup(lo)}, {_tup(hi)}]")
    body.append(f'color3f[] primvars:displayColor = [{_tup(shape.color)}] (interpolation = "constant")')
    inner = "".join(f"{indent}    {line}\n" for line in body)
    return f'{indent}def {type_name} "{name}"\n{indent}{{\n{inner}{indent}}}\n'


def _joint_frames(j) -> tuple[np.ndarray, np.ndarray, str, list[str], str]:
    """World joint-frame rotations (body0 side, body1 side), USD type, locked D6 DOFs, axis token."""
    eye = np.eye(3)
    kind = j.kind
    if kind in ("ball", "point"):
        return eye, eye, "PhysicsSphericalJoint", [], ""
    if kind == "fixed":
        return eye, eye, "PhysicsFixedJoint", [], ""
    if kind in ("revolute", "prismatic"):
        f = _frame_axes(j.axis)
        return f, f, "PhysicsRevoluteJoint" if kind == "revolute" else "PhysicsPrismaticJoint", [], "X"
    if kind in ("universal", "angle"):
        a, b = j.axis, j.axis_child
        f0 = _frame_axes(np.cross(a, b), a)  # X = a x b, Y = a, Z ~ b
        f1 = _frame_axes(np.cross(a, b), None)
        f1 = np.column_stack([f1[:, 0], np.cross(b, f1[:, 0]), b])  # X = a x b, Z = b
        f1[:, 1] /= np.linalg.norm(f1[:, 1])
        locked = ["rotX"] + (["transX", "transY", "transZ"] if kind == "universal" else [])
        return f0, f1, "PhysicsJoint", locked, ""
    locked = {
        "cylindrical": ["transY", "transZ", "rotY", "rotZ"],
        "planar": ["transX", "rotY", "rotZ"],
        "line": ["transY", "transZ"],
        "plane": ["transX"],
        "rotation": ["rotX", "rotY", "rotZ"],
        "axis": ["rotY", "rotZ"],
    }[kind]
    f = eye if j.axis is None else _frame_axes(j.axis)
    return f, f, "PhysicsJoint", locked, ""


def _loop_joints(builder: SceneBuilder) -> set[int]:
    """Joints that close a loop (a spanning forest over bodies, the world and static bodies as one node)."""
    parent = list(range(len(builder.bodies) + 1))
    world = len(builder.bodies)

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    node = [world if b.static else i for i, b in enumerate(builder.bodies)]
    loops = set()
    for k, j in enumerate(builder.joints):
        a = find(world if j.parent == WORLD else node[j.parent])
        c = find(node[j.child])
        if a == c:
            loops.add(k)
        else:
            parent[a] = c
    return loops


def _physics_scene_usda(scene: UsdScene, poses: tuple[np.ndarray, np.ndarray] | None) -> str:
    """The whole procedural scene as usda: World, PhysicsScene, bodies (geometry, mass, initial pose and
    velocity) and joints. Text import is ~10x faster than authoring the same specs one Sdf call at a time.
    `poses`: local translate / orient defaults, or None to leave the bodies out (instancer mode)."""
    builder = scene.builder
    if poses is None:
        return '#usda 1.0\n\ndef Xform "World"\n{\n}\n'
    out = ['#usda 1.0\n\ndef Xform "World"\n{\n']
    g = np.asarray(builder.gravity, dtype=np.float64)
    mag = float(np.linalg.norm(g))
    out.append('    def PhysicsScene "PhysicsScene"\n    {\n')
    out.append(f"        vector3f physics:gravityDirection = {_tup(g / mag if mag > 0 else (0.0, 0.0, -1.0))}\n")
    out.append(f"        float physics:gravityMagnitude = {_f(mag)}\n    }}\n")
    forces: dict[int, list] = {}
    for f in builder.forces:
        forces.setdefault(f.body, []).append(f)
    local_t, local_q = poses[0].tolist(), poses[1].tolist()
    # Principal moments and axes of every body in one batched eigh; bodies often share axes, and a shape.
    moments, axes = np.linalg.eigh(np.array([b.inertia for b in builder.bodies], dtype=np.float64).reshape(-1, 3, 3))
    axes[np.linalg.det(axes) < 0.0, :, 0] *= -1.0  # a proper rotation
    principal: dict[bytes, str] = {}
    geometry: dict[Shape, str] = {}
    for i, (b, path) in enumerate(zip(builder.bodies, scene.body_paths)):
        name = path.rsplit("/", 1)[1]
        schemas = '"PhysicsRigidBodyAPI"' + ("" if b.static else ', "PhysicsMassAPI"')
        out.append(f'    def Xform "{name}" (\n        prepend apiSchemas = [{schemas}]\n    )\n    {{\n')
        lines = []
        if b.static:
            lines.append("bool physics:kinematicEnabled = 1")
        else:
            key = axes[i].tobytes()
            if key not in principal:
                principal[key] = _quat_text(quat_from_matrix(axes[i]))
            lines += [
                f"float physics:mass = {_f(b.mass)}",
                f"float3 physics:diagonalInertia = {_tup(moments[i])}",
                f"quatf physics:principalAxes = {principal[key]}",
                "point3f physics:centerOfMass = (0, 0, 0)",
                f"vector3f physics:velocity = {_tup(b.linear_velocity)}",
                f"vector3f physics:angularVelocity = {_tup(np.degrees(b.angular_velocity))}",
            ]
        if i in forces:
            fs = forces[i]
            lines += [
                "custom double3[] warpimpulse:forces = [" + ", ".join(_tup(f.force) for f in fs) + "]",
                "custom double3[] warpimpulse:torques = [" + ", ".join(_tup(f.torque) for f in fs) + "]",
                "custom double[] warpimpulse:forceUntil = [" + ", ".join(_f(min(f.until, 1e300)) for f in fs) + "]",
            ]
        lines += [
            f"double3 xformOp:translate = {_tup(local_t[i])}",
            f"quatd xformOp:orient = {_quat_text(local_q[i])}",
            'uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:orient"]',
        ]
        out.append("".join(f"        {line}\n" for line in lines))
        shape = _body_display_shape(b)
        if shape not in geometry:
            geometry[shape] = _geometry_usda("geom", shape, "        ")
        out.append(geometry[shape])
        out.append("    }\n")
    if builder.joints:
        loops = _loop_joints(builder)
        out.append('    def Scope "Joints"\n    {\n')
        bodies = builder.bodies
        for k, (j, jpath) in enumerate(zip(builder.joints, scene.joint_paths)):
            f0, f1, type_name, locked, axis = _joint_frames(j)
            schemas = ", ".join(f'"PhysicsLimitAPI:{d}"' for d in locked)
            meta = f" (\n            prepend apiSchemas = [{schemas}]\n        )" if locked else ""
            out.append(f'        def {type_name} "{jpath.rsplit("/", 1)[1]}"{meta}\n        {{\n')
            lines = []
            for side, bi, fr in ((0, j.parent, f0), (1, j.child, f1)):
                wq = quat_from_matrix(fr)
                if bi == WORLD:
                    lp, lq = j.anchor, wq
                else:
                    body = bodies[bi]
                    lp = _qrot(_qconj(body.orientation), j.anchor - body.position)
                    lq = _qmul(_qconj(body.orientation), wq)
                    lines.append(f"rel physics:body{side} = <{scene.body_paths[bi]}>")
                lines.append(f"point3f physics:localPos{side} = {_tup(lp)}")
                lines.append(f"quatf physics:localRot{side} = {_quat_text(lq)}")
            if axis:
                lines.append(f'uniform token physics:axis = "{axis}"')
            if k in loops:
                lines.append("bool physics:excludeFromArticulation = 1")
            for dof in locked:
                lines += [f"float limit:{dof}:physics:low = 1", f"float limit:{dof}:physics:high = -1"]
            out.append("".join(f"            {line}\n" for line in lines))
            out.append("        }\n")
        out.append("    }\n")
    out.append("}\n")
    return "".join(out)


class AnimationWriter:
    """Streams simulated frames into a USD layer and writes it atomically on `close()`.

    `scene`: a `UsdScene` from `load_stage` (layered output: sublayers the input, `over`s on the body prims;
    `flatten=True` for one self-contained file), or a SceneBuilder / Model / procedural UsdScene (the
    output holds geometry and UsdPhysics schemas and reads back with `load_stage`). `instancer`: True
    writes one PointInstancer (float positions, half orientations; display only), None picks it above
    `INSTANCER_AUTO_BODIES` bodies for procedural scenes. Frames go into the Sdf layer in bounded chunks
    (`_CHUNK_BYTES`); as a context manager, an exception or Ctrl-C still writes the frames done so far to a
    valid file.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        scene: UsdScene | SceneBuilder | Any,
        fps: float,
        settings: dict | None = None,
        flatten: bool = False,
        instancer: bool | None = None,
    ) -> None:
        Gf, Sdf, _, _, _, _, Vt = _pxr()
        self._Sdf, self._Vt = Sdf, Vt
        self.path = os.path.abspath(os.fspath(path))
        self.scene = _as_scene(scene)
        self.fps = float(fps)
        if not (self.fps > 0.0 and math.isfinite(self.fps)):
            raise ValueError(f"fps must be positive, got {fps}")
        self.flatten = bool(flatten)
        layered = self.scene.source_path is not None
        n = self.scene.body_count
        if instancer is None:
            instancer = not layered and n > INSTANCER_AUTO_BODIES
        if instancer and layered:
            raise ValueError("the PointInstancer mode is for procedural scenes; a scene read from USD is "
                             "written as overs on its own body prims")  # fmt: skip
        self.instancer = bool(instancer)
        self.settings = dict(settings or {})
        self.frames_written = 0
        self.first_time: int | None = None
        self.last_time: int | None = None
        self.stopped_early: str | None = None
        self._closed = False
        self._ext = os.path.splitext(self.path)[1].lower() or ".usd"
        if self._ext not in (".usd", ".usda", ".usdc"):
            raise ValueError(f"{self.path}: output must end in .usd, .usda or .usdc")
        self.layer = Sdf.Layer.CreateAnonymous("warpimpulse" + self._ext)
        self._h = _Sdf()
        self._build()
        if not self.instancer:
            m = len(self._moving)
            k = int(np.clip(_CHUNK_BYTES // (56 * max(m, 1)), 1, _CHUNK_FRAMES))  # 56 bytes: 7 doubles a body
            self._buf_t, self._buf_q = np.empty((m, k, 3)), np.empty((m, k, 4))
            self._buf_times: list[float] = []

    # ------------------------------------------------------------------ set-up
    def _build(self) -> None:
        Sdf, Vt, h, T = self._Sdf, self._Vt, self._h, self._h.T
        scene, layer = self.scene, self.layer
        n = scene.body_count
        self._moving = np.array([i for i, bd in enumerate(scene.builder.bodies) if not bd.static], dtype=np.int64)
        self._prev_q: np.ndarray | None = None
        b = scene.builder.bodies
        x0 = np.array([bd.position for bd in b]).reshape(n, 3)
        q0 = np.array([bd.orientation for bd in b]).reshape(n, 4)
        if scene.source_path is None:
            # Procedural: the static content as text, then the time-sampled attributes' paths.
            poses = None if self.instancer else _local_poses(scene, x0, q0)
            layer.ImportFromString(_physics_scene_usda(scene, poses))
            self._write_metadata()
            if self.instancer:
                self._build_instancer(x0, q0)
            else:
                self._tpaths = [Sdf.Path(f"{scene.body_paths[i]}.xformOp:translate") for i in self._moving]
                self._qpaths = [Sdf.Path(f"{scene.body_paths[i]}.xformOp:orient") for i in self._moving]
            return
        self._write_metadata()
        with Sdf.ChangeBlock():
            src = scene.source_path
            layer.subLayerPaths.append(src if self.flatten else os.path.relpath(src, os.path.dirname(self.path)))
            self._tpaths, self._qpaths = [], []
            local_t, local_q = _local_poses(scene, x0, q0)
            tv, qv = Vt.Vec3dArray.FromNumpy(local_t), Vt.QuatdArray.FromNumpy(local_q)
            for i in self._moving.tolist():  # static and kinematic bodies keep the input's transform (and animation)
                spec = h.prim(layer, scene.body_paths[i], specifier=Sdf.SpecifierOver)
                t_op, q_op = scene.xform_ops[i] if scene.xform_ops else ("xformOp:translate", "xformOp:orient")
                ops = [t_op, q_op]
                ratio = scene.body_scales[i].copy()
                if not scene.reset_xform_stack[i]:
                    ratio /= scene.parent_scale[i]
                    if scene.parent_index[i] >= 0:
                        ratio /= scene.body_scales[scene.parent_index[i], 0]
                if np.abs(ratio - 1.0).max() > 1e-12:
                    h.attr(spec, "xformOp:scale", T.Double3, h.Gf.Vec3d(*ratio))
                    ops.append("xformOp:scale")
                if scene.reset_xform_stack[i]:
                    ops.insert(0, "!resetXformStack!")
                h.attr(spec, "xformOpOrder", T.TokenArray, Vt.TokenArray(ops), uniform=True)
                self._tpaths.append(h.attr(spec, t_op, T.Double3, tv[i]).path)
                self._qpaths.append(h.attr(spec, q_op, T.Quatd, qv[i]).path)

    def _build_instancer(self, x0: np.ndarray, q0: np.ndarray) -> None:
        protos: dict[Shape, int] = {}
        indices = [protos.setdefault(_body_display_shape(b), len(protos)) for b in self.scene.builder.bodies]
        targets = ", ".join(f"<{_INSTANCER_PATH}/Prototypes/proto{k}>" for k in range(len(protos)))
        geoms = "".join(_geometry_usda(f"proto{k}", shape, "            ") for shape, k in protos.items())
        text = (
            f'#usda 1.0\nover "World"\n{{\n    def PointInstancer "Instancer"\n    {{\n'
            f"        rel prototypes = [{targets}]\n"
            f"        int[] protoIndices = [{', '.join(map(str, indices))}]\n"
            f'        def Scope "Prototypes"\n        {{\n{geoms}        }}\n    }}\n}}\n'
        )
        sub = self._Sdf.Layer.CreateAnonymous(".usda")
        sub.ImportFromString(text)
        Vt, T, h = self._Vt, self._h.T, self._h
        with self._Sdf.ChangeBlock():
            self._Sdf.CopySpec(sub, _INSTANCER_PATH, self.layer, _INSTANCER_PATH)
            inst = self.layer.GetPrimAtPath(_INSTANCER_PATH)
            pos = h.attr(inst, "positions", T.Point3fArray, Vt.Vec3fArray.FromNumpy(x0.astype(np.float32)))
            ori = h.attr(inst, "orientations", T.QuathArray, Vt.QuathArray.FromNumpy(q0.astype(np.float16)))
        self._ipos, self._iori = pos.path, ori.path

    def _write_metadata(self) -> None:
        scene, layer = self.scene, self.layer
        root = layer.pseudoRoot
        root.SetInfo("upAxis", scene.up_axis)
        root.SetInfo("metersPerUnit", float(scene.meters_per_unit))
        root.SetInfo("kilogramsPerUnit", float(scene.kilograms_per_unit))
        layer.timeCodesPerSecond = self.fps
        layer.framesPerSecond = self.fps
        if scene.default_prim:
            layer.defaultPrim = scene.default_prim
        self._write_layer_data()

    def _write_layer_data(self) -> None:
        from . import __version__

        data: dict[str, Any] = {
            "warpimpulse:version": str(__version__),
            _MODE_KEY: "instancer" if self.instancer else ("layered" if self.scene.source_path else "procedural"),
            "warpimpulse:fps": self.fps,
            "warpimpulse:framesWritten": int(self.frames_written),
            "warpimpulse:complete": self.stopped_early is None,
        }
        if self.stopped_early:
            data["warpimpulse:stoppedEarly"] = self.stopped_early
        if self.scene.source_path:
            data["warpimpulse:source"] = self.scene.source_path
        for k, v in self.settings.items():
            data[f"warpimpulse:{k}" if ":" not in k else k] = _vt_value(v)
        self.layer.customLayerData = data

    # ------------------------------------------------------------------ frames
    def write_frame(self, time_code: int, positions, orientations) -> None:
        """Add the state at `time_code` (= t * fps): centres of mass (N, 3) in metres, orientations (N, 4) xyzw."""
        if self._closed:
            raise RuntimeError("write_frame after close()")
        n = self.scene.body_count
        x = np.asarray(positions, dtype=np.float64)
        q = np.asarray(orientations, dtype=np.float64)
        if x.shape != (n, 3) or q.shape != (n, 4):
            raise ValueError(f"expected positions ({n}, 3) and orientations ({n}, 4), got {x.shape}, {q.shape}")
        tc = float(time_code)
        if self.instancer:
            Vt, layer = self._Vt, self.layer
            with self._Sdf.ChangeBlock():
                layer.SetTimeSample(self._ipos, tc, Vt.Vec3fArray.FromNumpy(x.astype(np.float32)))
                layer.SetTimeSample(self._iori, tc, Vt.QuathArray.FromNumpy(q.astype(np.float16)))
        else:
            local_t, local_q = _local_poses(self.scene, x, q)
            local_q = local_q[self._moving]
            if self._prev_q is not None:  # q and -q are one rotation; keep the sign continuous for slerp
                local_q[np.einsum("ij,ij->i", local_q, self._prev_q) < 0.0] *= -1.0
            if len(self._buf_times) == self._buf_t.shape[1]:
                self._flush()  # before this frame goes in: a frame counted below is in the buffer or the layer
            j = len(self._buf_times)
            self._buf_t[:, j] = local_t[self._moving]
            self._buf_q[:, j] = local_q
            self._buf_times.append(tc)
            self._prev_q = local_q
        self.frames_written += 1
        self.first_time = time_code if self.first_time is None else min(self.first_time, time_code)
        self.last_time = time_code if self.last_time is None else max(self.last_time, time_code)

    def _flush(self) -> None:
        """Author the buffered frames into the layer, attribute by attribute."""
        k, times = len(self._buf_times), self._buf_times
        if k == 0:
            return
        Vt, st = self._Vt, self.layer.SetTimeSample
        tv = Vt.Vec3dArray.FromNumpy(self._buf_t[:, :k].reshape(-1, 3))  # attribute-major: body i's k samples
        qv = Vt.QuatdArray.FromNumpy(self._buf_q[:, :k].reshape(-1, 4))
        with self._Sdf.ChangeBlock():
            for paths, values in ((self._tpaths, tv), (self._qpaths, qv)):
                # One SetTimeSample per sample is the floor of the Sdf API (no call takes a whole sample map);
                # map() makes the calls from C: each path k times, against the k time codes over and over.
                deque(map(st, chain.from_iterable(map(repeat, paths, repeat(k))), cycle(times), values), maxlen=0)
        self._buf_times = []

    # ------------------------------------------------------------------ output
    def close(self, stopped_early: str | None = None) -> str:
        """Write the file (temporary file in the same folder, then rename). Returns the path. Idempotent."""
        if self._closed:
            return self.path
        self._closed = True
        if stopped_early:
            self.stopped_early = stopped_early
        if not self.instancer:
            self._flush()
        layer = self.layer
        layer.startTimeCode = float(self.first_time if self.first_time is not None else 0)
        layer.endTimeCode = float(self.last_time if self.last_time is not None else 0)
        self._write_layer_data()
        folder = os.path.dirname(self.path)
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(self.path)}.", suffix=self._ext, dir=folder)
        os.close(fd)
        try:
            out = layer
            if self.flatten and self.scene.source_path is not None:
                _, _, _, Usd, *_ = _pxr()
                out = Usd.Stage.Open(layer).Flatten()
                for key in ("startTimeCode", "endTimeCode", "timeCodesPerSecond", "framesPerSecond"):
                    out.pseudoRoot.SetInfo(key, layer.pseudoRoot.GetInfo(key))
                out.customLayerData = layer.customLayerData
            if not out.Export(tmp):
                raise OSError(f"could not write {tmp}")
            os.chmod(tmp, _file_mode(self.path))  # mkstemp makes it 0600
            os.replace(tmp, self.path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        return self.path

    def __enter__(self) -> AnimationWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.close()
        else:
            # The caller reports the stop; the file records it in customLayerData (warpimpulse:stoppedEarly).
            reason = "interrupted" if issubclass(exc_type, KeyboardInterrupt) else f"{exc_type.__name__}: {exc}"
            self.close(stopped_early=reason)
        return False


def _file_mode(path: str) -> int:
    """The mode a new file would get (0666 less the umask), or the mode of the file being replaced."""
    try:
        return os.stat(path).st_mode & 0o777
    except FileNotFoundError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def _vt_value(v: Any) -> Any:
    """customLayerData values must be USD types: keep numbers, strings, bools; stringify the rest."""
    if isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, dict):
        return {str(k): _vt_value(x) for k, x in v.items()}
    return str(v)


def save_scene(
    scene: UsdScene | SceneBuilder | Any, path: str | os.PathLike, fps: float = 60.0, dt: float | None = None
) -> str:
    """Write a builder as a UsdPhysics scene file (bodies at their initial pose, no time samples). `dt`: the
    step size to record for `warpimpulse simulate`, for scenes that need a smaller one than 1/fps."""
    sc = _as_scene(scene)
    if sc.source_path is not None:
        sc = scene_from_builder(sc.builder)
    return AnimationWriter(path, sc, fps, {} if dt is None else {"dt": float(dt)}, instancer=False).close()


# ---------------------------------------------------------------------------------------------- driving
def frame_steps(dt: float, fps: float) -> int:
    """Steps of `dt` per frame. Raises ValueError unless 1/fps is a whole multiple of dt (to 1e-9)."""
    ratio = 1.0 / (fps * dt)
    steps = round(ratio)
    if steps < 1 or abs(ratio - steps) > 1e-9 * max(ratio, 1.0):
        raise ValueError(
            f"1/fps = {1.0 / fps:.9g} s is not a whole multiple of dt = {dt:.9g} s ({ratio:.6g} steps a frame); "
            f"choose dt = 1/(fps*k), e.g. dt = {1.0 / (fps * max(1, math.ceil(ratio))):.9g}"
        )
    return steps


def record(
    sim: Any,
    writer: AnimationWriter,
    duration: float,
    dt: float | None = None,
    progress: bool | None = None,
    on_frame: Callable[[int], None] | None = None,
) -> int:
    """Step `sim` and write frames 0 .. round(duration * fps) inclusive (frame f holds t = f / fps).

    `sim` needs `step()`, `positions()` and `orientations()` (and `dt` unless given). A progress bar is
    drawn on stderr when it is a terminal (or `progress=True`). Returns the number of frames written;
    call it inside `with writer:` so that an error or Ctrl-C still leaves a valid file.
    """
    dt = float(dt if dt is not None else sim.dt)
    steps = frame_steps(dt, writer.fps)
    frames = int(round(duration * writer.fps))
    show = sys.stderr.isatty() if progress is None else progress
    start = time.perf_counter()
    for f in range(frames + 1):
        if f > 0:
            for _ in range(steps):
                sim.step()
        x, q = sim.positions(), sim.orientations()
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(q))):
            raise FloatingPointError(f"the simulation diverged (non-finite state) before frame {f}")
        writer.write_frame(f, x, q)
        if on_frame is not None:
            on_frame(f)
        if show:
            done = (f + 1) / (frames + 1)
            bar = "#" * int(30 * done)
            rate = (f + 1) / max(time.perf_counter() - start, 1e-9)
            print(f"\r[{bar:<30}] {f}/{frames} frames  {rate:6.1f} fps", end="", file=sys.stderr, flush=True)
    if show:
        print(file=sys.stderr)
    return frames + 1


# ---------------------------------------------------------------------------------------------- reading
@dataclass
class Animation:
    """Frames read back from an exported file: centres of mass (F, N, 3) in metres, orientations xyzw."""

    time_codes: np.ndarray
    body_paths: list[str]
    positions: np.ndarray
    orientations: np.ndarray
    fps: float


def read_animation(path: str | os.PathLike, scene: UsdScene | None = None) -> Animation:
    """Read the body poses of every time sample of an exported file (per-body prims or instancer)."""
    _, _, _, Usd, UsdGeom, *_ = _pxr()
    path = os.fspath(path)
    stage = _open_stage(path)
    layer = stage.GetRootLayer()
    fps = float(layer.timeCodesPerSecond)
    mode = layer.customLayerData.get(_MODE_KEY, "")
    if mode == "instancer":
        inst = UsdGeom.PointInstancer(stage.GetPrimAtPath(_INSTANCER_PATH))
        times = np.array(inst.GetPositionsAttr().GetTimeSamples(), dtype=np.float64)
        pos = np.array([np.array(inst.GetPositionsAttr().Get(t), dtype=np.float64) for t in times])
        ori = np.array([np.array(inst.GetOrientationsAttr().Get(t), dtype=np.float64) for t in times])
        n = pos.shape[1] if len(times) else 0
        return Animation(times, [f"{_INSTANCER_PATH}[{i}]" for i in range(n)], pos, ori, fps)
    scene = scene or load_stage(path, ignore_unsupported=True)
    prims = [stage.GetPrimAtPath(p) for p in scene.body_paths]
    times = sorted({t for p in prims for t in UsdGeom.Xformable(p).GetTimeSamples()})
    pos = np.zeros((len(times), len(prims), 3))
    ori = np.zeros((len(times), len(prims), 4))
    for k, t in enumerate(times):
        cache = UsdGeom.XformCache(Usd.TimeCode(t))
        for i, prim in enumerate(prims):
            fr = _decompose(cache.GetLocalToWorldTransform(prim), str(prim.GetPath()))
            pos[k, i] = (fr.t + _qrot(fr.q, scene.com_offsets[i])) * scene.meters_per_unit
            ori[k, i] = fr.q
    return Animation(np.array(times, dtype=np.float64), list(scene.body_paths), pos, ori, fps)


def validate(path_or_stage: Any) -> list[str]:
    """UsdValidation errors (not warnings) on a file or stage, as strings; empty when it is clean."""
    from pxr import UsdValidation

    stage = _open_stage(os.fspath(path_or_stage)) if isinstance(path_or_stage, (str, os.PathLike)) else path_or_stage
    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    errors = ctx.Validate(stage)
    return [
        f"{e.GetName()}: {e.GetMessage()}" for e in errors if e.GetType() == UsdValidation.ValidationErrorType.Error
    ]
