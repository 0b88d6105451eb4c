"""USD in: a UsdPhysics scene to a SceneBuilder (`load_stage`).

Rigid bodies, mass and joints come from `UsdPhysics.UsdPhysicsLoadStageFromPrimRange`; transforms come from
`UsdGeom.XformCache` in double precision (the parser's poses are float), at the stage's start time. Generic
(D6) joints map to the combined joint their locked axes describe, or to basic constraints. A joint end that
targets a prim inside a body stands for that body (PhysX's rule); any other prim is the world at that prim's
transform. Limits and drives on a joint with one DOF (revolute, prismatic, or D6 with one free axis) become
motors, joint springs and limits; distance joints distance constraints. What is not simulated (cone limits,
limits or drives on a joint with several free DOFs, break forces, collision groups) is refused (or dropped
with a warning when `ignore_unsupported`), never silently; colliders that do not collide (they still give
mass) get one warning.

Units: the simulator is SI. Inputs are converted with metersPerUnit / kilogramsPerUnit; angles in USD are
degrees. USD stores quaternions real part first (`Gf.Quatd(w, x, y, z)`); here they are (x, y, z, w).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..builder import SceneBuilder, SceneError, checked_material
from ..files import fd2_captured, usd_message, usd_warnings
from ..joints import JOINT_TYPES
from ..shapes import Shape
from ..transforms import quat_conj, quat_from_matrix, quat_mul, quat_rotate, quat_to_matrix
from ..types import DRIVE_MODES
from .scene import IDENTITY_QUAT, UnsupportedFeatureError, UsdScene, UsdSceneError, open_stage, pxr

JOINT_GAP = 1e-5  # m per m of the anchor's distance from the origin (at least 1 m): float32 localPos round-off
VELOCITY = DRIVE_MODES.index("velocity")
_DOFS = ("transX", "transY", "transZ", "rotX", "rotY", "rotZ")
_EYE = np.eye(3)


@dataclass
class Similarity:
    """A decomposed USD matrix: x_world = t + R (s * x_local), s per axis (no shear)."""

    t: np.ndarray
    q: np.ndarray  # (x, y, z, w)
    s: np.ndarray

    @property
    def uniform(self) -> bool:
        return bool(np.ptp(self.s) <= 1e-9 * max(float(np.abs(self.s).max()), 1e-300))


def decompose(m, what: str) -> Similarity:
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
    return Similarity(m[3, :3].copy(), quat_from_matrix(rot), s)


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


def _not_only_sampled(prim, attr) -> None:
    """Schema attributes (and, on a stage without a time range, transforms) are read at the default time: an
    attribute authored only as time samples has no value there (an XformCache takes such an op as the
    identity, a schema attribute its fallback), so the body would start in the wrong place, or at rest.
    Refuse it. (On a stage with a time range, transforms are read at its startTimeCode, `_Xforms`.)"""
    _, _, _, Usd, *_ = pxr()
    if attr.GetNumTimeSamples() and (
        attr.GetResolveInfo(Usd.TimeCode.Default()).GetSource() != Usd.ResolveInfoSourceDefault
    ):
        times = attr.GetTimeSamples()
        raise UsdSceneError(
            f"{prim.GetPath()}: {attr.GetName()} is authored only as time samples ({len(times)}, from time "
            f"{times[0]:g}); the initial state is read from default values: author a default value"
        )


def _check_defaults(prim) -> None:
    """`_not_only_sampled` for every attribute of a body, joint or scene prim but its xformOps, which `_Xforms`
    reads (and checks) at the scene's start time."""
    for attr in prim.GetAttributes():
        if not attr.GetName().startswith("xformOp:"):
            _not_only_sampled(prim, attr)


class _Xforms:
    """World matrices from an XformCache at `time` (the stage's start), after checking the xformOps of the prim
    and its ancestors (each prim once): the cache reads a zero or NaN orient as the identity and drops a
    non-finite matrix op."""

    def __init__(self, time) -> None:
        _, _, _, _, UsdGeom, *_ = pxr()
        self._time = time
        self._cache = UsdGeom.XformCache(time)
        self._xformable = UsdGeom.Xformable
        self._orient = UsdGeom.XformOp.TypeOrient
        self._checked: set[str] = set()

    def _check(self, prim) -> None:
        while prim and not prim.IsPseudoRoot() and str(prim.GetPath()) not in self._checked:
            path = str(prim.GetPath())
            if prim.IsA(self._xformable):
                for op in self._xformable(prim).GetOrderedXformOps():
                    value = op.Get(self._time)
                    if value is None:
                        _not_only_sampled(prim, op.GetAttr())
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


class _Reporter:
    """Unsupported features: an error naming the prim, or a warning when told to ignore them."""

    def __init__(self, ignore: bool, notes: list[str], warned: list[str] | None = None) -> None:
        self.ignore = ignore
        self.notes = notes
        self.warned = [] if warned is None else warned  # the notes that were warnings

    def unsupported(self, prim: str, what: str) -> None:
        if not self.ignore:
            raise UnsupportedFeatureError(
                f"{prim}: {what} is not simulated by warpimpulse (pass ignore_unsupported=True / "
                f"--ignore-unsupported to drop it with a warning)"
            )
        self.note(f"{prim}: {what} is not simulated; ignored", stacklevel=5)

    def note(self, msg: str, stacklevel: int = 4) -> None:
        self.notes.append(msg)
        self.warned.append(msg)
        warnings.warn(msg, stacklevel=stacklevel)


def _collider_shape(prim, xforms: _Xforms, report: _Reporter) -> tuple[Shape, str, int, Similarity]:
    """A collision prim's solid with its world scale applied (stage units): (shape, kind, the axis index of a
    capsule or cylinder, the prim's world similarity). A prim of another type is its extent box (noted)."""
    _, _, _, _, UsdGeom, _, _ = pxr()
    path = str(prim.GetPath())
    sim = decompose(xforms.world(prim), path)
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
        sim.t = sim.t + quat_rotate(sim.q, 0.5 * (lo + hi) * sim.s)
    if shape.zero_size():  # no volume to weigh, nothing to collide: before its mass is computed from it
        sizes = f"size {list(shape.size)}" if kind == "box" else f"radius {shape.radius:g}"
        sizes += f", height {shape.length:g}" if kind in ("capsule", "cylinder") else ""
        raise UsdSceneError(f"{path}: the {prim.GetTypeName()} collider has zero size ({sizes}, its scale applied)")
    return shape, kind, axis, sim


def _shape_mass_info(prim, body_frame: Similarity, xforms: _Xforms, report: _Reporter):
    """MassInformation (unit density) of one collision prim, in the body's rigid frame."""
    Gf, _, _, _, _, UsdPhysics, _ = pxr()
    shape, kind, axis, sim = _collider_shape(prim, xforms, report)
    volume = shape.volume()
    inertia = shape.inertia(volume)  # density 1
    if kind in ("capsule", "cylinder") and axis != 2:
        perm = {0: [2, 1, 0], 1: [0, 2, 1]}[axis]  # move the symmetry axis (z moments) onto `axis`
        inertia = inertia[np.ix_(perm, perm)]
    info = UsdPhysics.RigidBodyAPI.MassInformation()
    info.volume = float(volume)
    info.inertia = Gf.Matrix3f(*[float(v) for v in inertia.reshape(-1)])
    info.centerOfMass = Gf.Vec3f(0.0, 0.0, 0.0)
    local_pos = quat_rotate(quat_conj(body_frame.q), sim.t - body_frame.t)
    local_rot = quat_mul(quat_conj(body_frame.q), sim.q)
    info.localPos = Gf.Vec3f(*[float(v) for v in local_pos])
    info.localRot = Gf.Quatf(float(local_rot[3]), *[float(v) for v in local_rot[:3]])
    return info


def _body_mass(prim, desc, frame: Similarity, xforms: _Xforms, report: _Reporter):
    """(mass, diagonal inertia, centre of mass in the rigid frame, principal axes xyzw), stage units."""
    _, _, _, _, _, UsdPhysics, _ = pxr()
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
        return mass, diag, com if com is not None else np.zeros(3), axes if axes is not None else IDENTITY_QUAT
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
    rot = IDENTITY_QUAT.copy() if rot is None else _unit_quat(jpath, f"physics:localRot{side}", rot)
    rel = joint_prim.GetRelationship(f"physics:body{side}")
    targets = rel.GetTargets() if rel else []
    if not targets:
        return pos * mpu, rot
    target = stage.GetPrimAtPath(targets[0])
    frame = decompose(xforms.world(target), str(targets[0]))
    anchor = frame.t + quat_rotate(frame.q, frame.s * pos)
    return anchor * mpu, quat_mul(frame.q, rot)


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


def _d6_axes(desc, path: str, report: _Reporter) -> tuple[set[int], set[int], dict[int, tuple], dict[int, Any]]:
    """A D6 joint's locked translations and rotations (axis indices), and its other limits (lower, upper) and
    drives by DOF index (0-5 as `_DOFS`). Limits and drives of DOFs the schema's generic joint does not
    index (the distance limit) are reported here."""
    _, _, _, _, _, UsdPhysics, _ = pxr()
    dof_index = {
        UsdPhysics.JointDOF.TransX: 0, UsdPhysics.JointDOF.TransY: 1, UsdPhysics.JointDOF.TransZ: 2,
        UsdPhysics.JointDOF.RotX: 3, UsdPhysics.JointDOF.RotY: 4, UsdPhysics.JointDOF.RotZ: 5,
    }  # fmt: skip
    locked_t, locked_r, ranges, drives = set(), set(), {}, {}
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
            ranges[i] = (limit.lower, limit.upper)
    for pair in desc.jointDrives:
        if pair.second.enabled:
            if pair.first not in dof_index:
                report.unsupported(path, f"a {pair.first.name} drive")
            else:
                drives[dof_index[pair.first]] = pair.second
    return locked_t, locked_r, ranges, drives


def _usd_coordinate(angular: bool, k: int, a0: np.ndarray, q0: np.ndarray, a1: np.ndarray, q1: np.ndarray) -> float:
    """The coordinate USD gives a joint with one DOF, about or along axis k of its frames: the angle (rad, in
    (-pi, pi]) of joint frame 1 against frame 0 about it, or the offset (m) of frame 1's origin along it."""
    if not angular:
        return float(np.dot(a1 - a0, quat_rotate(q0, np.eye(3)[k])))
    d = quat_mul(quat_conj(q0), q1)
    sine, cosine = (d[k], d[3]) if d[3] >= 0.0 else (-d[k], -d[3])
    return 2.0 * math.atan2(sine, cosine)


def _limit_and_drive(
    builder: SceneBuilder, joint: int, prim, limit, drive, angular: bool, x0: float, sign: float, mpu: float,
    kpu: float, report: _Reporter,
) -> tuple[float, float]:  # fmt: skip
    """A USD limit (lower, upper) and DriveAPI on a joint's one DOF (a revolute or prismatic joint, or a D6 joint
    with one free axis) as warpimpulse limits, motors and joint springs, on the coordinate sign (x - x0): x the
    DOF as USD measures it (`_usd_coordinate`), x0 its value as built, sign -1 where the reader turned the joint
    round (the world on body1's side).

    Angular values are in degrees in USD (stiffness and damping per degree), linear ones in stage units. A drive
    is stiffness (targetPosition - x) + damping (targetVelocity - dx/dt): with a stiffness, a position motor
    (kp = stiffness, kd = damping); without, a velocity motor (kp = damping), which is stiff (it holds its
    target velocity within maxForce, `SceneBuilder.add_motor(stiff=True)`) unless the file says otherwise: the
    large damping of a velocity drive is beyond an explicit PID (kp h / I < 2) and PhysX's drives are implicit.
    warpimpulse's extras on the joint prim: warpimpulse:drive:ki (per the unit of the coordinate and second),
    warpimpulse:drive:stiff and warpimpulse:drive:jointSpring (a joint spring, not a motor).

    Returns (scale, offset): the drive's target in the builder is scale * (its USD target) + offset (an actuator
    maps its control through it, `_read_actuators`)."""
    jpath = str(prim.GetPath())
    unit = math.radians(1.0) if angular else mpu  # USD's unit of the coordinate, in rad or m
    scale = sign * unit
    if limit is not None:
        lower, upper = sorted(sign * (v * unit - x0) for v in limit)
        if lower > 1e-6 or upper < -1e-6:  # the engine's limits hold a built pose inside them
            start = f"{math.degrees(x0):.6g} degrees" if angular else f"{x0 / mpu:.6g}"
            raise UsdSceneError(f"{jpath}: the joint starts at {start}, outside its limits [{limit[0]}, {limit[1]}]")
        if math.isfinite(lower) or math.isfinite(upper):
            builder.add_joint_limit(joint, min(lower, 0.0), max(upper, 0.0))  # round-off at a bound is on it
    if drive is None:
        return scale, 0.0
    force_unit = kpu * mpu * (mpu if angular else 1.0)  # USD's unit of force (torque) in N (N m)
    per = force_unit / unit  # a gain per USD unit, as one per rad or m
    attrs = {name: prim.GetAttribute(f"warpimpulse:drive:{name}") for name in ("ki", "stiff", "jointSpring")}
    extra = {name: (a.Get() if a and a.HasAuthoredValue() else None) for name, a in attrs.items()}
    ki = float(extra["ki"] or 0.0) * per
    max_force = drive.forceLimit * force_unit if math.isfinite(drive.forceLimit) else math.inf
    target = sign * (drive.targetPosition * unit - x0)
    if drive.acceleration:
        report.unsupported(jpath, "a drive of physics:type acceleration")
    elif extra["jointSpring"]:
        builder.add_joint_spring(joint, drive.stiffness * per, drive.damping * per, target)
    elif drive.stiffness > 0.0:
        if drive.targetVelocity != 0.0:
            report.unsupported(jpath, "a drive with a stiffness and a targetVelocity (tracking both)")
            return scale, 0.0
        builder.add_motor(joint, "position", target, drive.stiffness * per, ki, drive.damping * per, max_force,
                          stiff=bool(extra["stiff"]))  # fmt: skip
    else:
        stiff = drive.damping > 0.0 if extra["stiff"] is None else bool(extra["stiff"])
        if not (stiff or drive.damping > 0.0 or ki > 0.0):
            report.note(f"{jpath}: a drive with neither stiffness nor damping exerts nothing; ignored")
            return scale, 0.0
        builder.add_motor(joint, "velocity", scale * drive.targetVelocity, drive.damping * per, ki, 0.0,
                          max_force, stiff=stiff)  # fmt: skip
        return scale, 0.0
    return scale, -sign * x0


def _extra_drives(builder: SceneBuilder, joint: int, prim, sign: float) -> None:
    """The drives a joint's DriveAPI could not hold, from its warpimpulse:drive<n>:* attributes (the writer's
    `_extra_drive`: SI units, the coordinate 0 as built), n = 1, 2, ...; the target turned with the joint."""
    n = 1
    while (mode := _authored(prim, f"warpimpulse:drive{n}:mode")) is not None:
        values = {name: _authored(prim, f"warpimpulse:drive{n}:{name}") for name in
                  ("target", "gains", "maxForce", "motor", "stiff")}  # fmt: skip
        target = sign * float(values["target"] or 0.0)
        kp, ki, kd = (float(g) for g in (values["gains"] or (0.0, 0.0, 0.0)))
        max_force = math.inf if values["maxForce"] is None else float(values["maxForce"])
        if values["motor"] is None or values["motor"]:
            builder.add_motor(joint, str(mode), target, kp, ki, kd, max_force, stiff=bool(values["stiff"]))
        else:
            builder.add_joint_spring(joint, kp, kd, target)
        n += 1


def _read_chains(stage, builder: SceneBuilder, joint_index: dict[str, int]) -> None:
    """Joints in series through light bodies (`SceneBuilder.chain_joints`, MJCF's several joints in one body):
    the writer's custom rel warpimpulse:chain on a chain's first joint, targeting its joints in order."""
    for jpath in joint_index:
        rel = stage.GetPrimAtPath(jpath).GetRelationship("warpimpulse:chain")
        if not rel:
            continue
        targets = [str(t) for t in rel.GetTargets()]
        missing = [t for t in targets if t not in joint_index]
        if missing:
            raise UsdSceneError(f"{jpath}: warpimpulse:chain targets {missing[0]}, which is no joint read")
        try:
            builder.chain_joints([joint_index[t] for t in targets])
        except SceneError as exc:
            raise UsdSceneError(f"{jpath}: warpimpulse:chain: {exc}") from None


_API_TARGET = re.compile(r"drive:[A-Za-z]+:physics:target(Position|Velocity)")
_EXTRA_TARGET = re.compile(r"warpimpulse:drive([1-9][0-9]*):target")


def _read_actuators(stage, builder: SceneBuilder, slots: dict[tuple[str, str], tuple[int, float, float]]) -> None:
    """The writer's actuators (`writer._actuators_usda`), in file order: prims with warpimpulse:target, the joint
    attribute their control sets, on the joint warpimpulse:joint targets. `slots`: per (joint prim, "api" for
    its DriveAPI or n for warpimpulse:drive<n>), the builder's drive and the map (scale, offset) of that drive's
    USD target to the builder's."""
    for prim in stage.Traverse():
        target = _authored(prim, "warpimpulse:target")
        if target is None:
            continue
        path = str(prim.GetPath())
        joints = prim.GetRelationship("warpimpulse:joint").GetTargets() if prim.HasRelationship(
            "warpimpulse:joint") else []  # fmt: skip
        api, extra = _API_TARGET.fullmatch(str(target)), _EXTRA_TARGET.fullmatch(str(target))
        key = (str(joints[0]) if len(joints) == 1 else "", "api" if api else extra.group(1) if extra else "")
        if key not in slots:
            raise UsdSceneError(f"{path}: an actuator needs warpimpulse:joint targeting one joint and "
                                f"warpimpulse:target naming a drive target of it; got {[str(j) for j in joints]}, "
                                f"{target!r}")  # fmt: skip
        drive, scale, offset = slots[key]
        mode = builder.drives[drive].mode
        if not builder.drives[drive].motor or (api and (api.group(1) == "Velocity") != (mode == VELOCITY)):
            raise UsdSceneError(f"{path}: warpimpulse:target {target!r} is no motor's target")
        gain = _real(path, "warpimpulse:gain", _authored(prim, "warpimpulse:gain") or 1.0)
        bias = _real(path, "warpimpulse:bias", _authored(prim, "warpimpulse:bias") or 0.0)
        low, high = (math.copysign(math.inf, x) if abs(x) >= 1e300 else float(x) for x in
                     _real(path, "warpimpulse:ctrlRange", _authored(prim, "warpimpulse:ctrlRange") or
                           (-math.inf, math.inf), infinite_ok=True))  # fmt: skip
        motor = sum(d.motor for d in builder.drives[:drive])
        name = _authored(prim, "warpimpulse:name") or prim.GetName()
        try:
            builder.add_actuator(motor, scale * float(gain), scale * float(bias) + offset, (low, high), str(name))
        except SceneError as exc:
            raise UsdSceneError(f"{path}: {exc}") from None


def _authored(prim, name: str):
    """The authored value of attribute `name`, or None."""
    attr = prim.GetAttribute(name)
    return attr.Get() if attr and attr.HasAuthoredValue() else None


def load_stage(path: str | os.PathLike, ignore_unsupported: bool = False) -> UsdScene:
    """Read a UsdPhysics scene into a SceneBuilder (SI units) plus what export needs.

    Body and joint names in the builder are their prim paths. Raises `UsdSceneError` (a `SceneError`)
    naming the prim for input that cannot be simulated. Limits and drives on a joint with one DOF become
    limits, motors and joint springs (`_limit_and_drive`); physics:excludeFromArticulation marks the joints that
    close loops. Features not simulated (cone limits, break forces, ...) raise `UnsupportedFeatureError` unless
    `ignore_unsupported`, which warns and drops them.
    """
    _, Sdf, _, _, UsdGeom, UsdPhysics, _ = pxr()
    path = os.fspath(path)
    stage = open_stage(path)
    notes: list[str] = []
    warned: list[str] = []
    report = _Reporter(ignore_unsupported, notes, warned)
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    kpu = float(UsdPhysics.GetStageKilogramsPerUnit(stage))
    for key, value in (("metersPerUnit", mpu), ("kilogramsPerUnit", kpu)):
        if not (value > 0.0 and math.isfinite(value)):
            raise UsdSceneError(f"{path}: the stage's {key} must be positive and finite, got {value}")
    up = str(UsdGeom.GetStageUpAxis(stage))
    try:
        with fd2_captured() as caught:  # its warnings (e.g. a CollisionAPI on a non-geometry prim): one line each
            parsed = UsdPhysics.UsdPhysicsLoadStageFromPrimRange(stage, [Sdf.Path("/")])
    except Exception as exc:  # noqa: BLE001 - the parser raises Tf errors of several kinds
        raise UsdSceneError(f"{path}: the UsdPhysics parser failed: {usd_message(exc)}") from None
    for text in usd_warnings(caught):
        warnings.warn(f"{path}: {text}", stacklevel=2)
    T = UsdPhysics.ObjectType
    get = lambda t: list(zip(*parsed[t])) if t in parsed else []  # noqa: E731

    # Gravity.
    scenes = get(T.Scene)
    if up not in ("Y", "Z"):  # UsdGeom allows only these two
        raise UsdSceneError(f"{path}: the stage's upAxis must be Y or Z, got {up!r}")
    up_vec = {"Y": [0, 1.0, 0], "Z": [0, 0, 1.0]}[up]
    if scenes:
        _check_defaults(stage.GetPrimAtPath(scenes[0][0]))
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

    xforms = _Xforms(_start_time(stage))
    order = {str(p.GetPath()): k for k, p in enumerate(stage.Traverse())}  # bodies and joints in file order
    bodies = sorted(get(T.RigidBody), key=lambda pd: order.get(str(pd[0]), len(order)))
    index: dict[str, int] = {}
    n = len(bodies)
    com_offsets, scales = np.zeros((n, 3)), np.ones((n, 3))
    parent_index = np.full(n, -1)
    parent_pos, parent_quat, parent_scale = np.zeros((n, 3)), np.tile(IDENTITY_QUAT, (n, 1)), np.ones(n)
    reset = np.zeros(n, dtype=bool)
    xform_ops: list[tuple[str, str, str]] = []
    frames: list[Similarity] = []
    for i, (p, desc) in enumerate(bodies):
        bpath = str(p)
        prim = stage.GetPrimAtPath(p)
        _check_defaults(prim)
        frame = decompose(xforms.world(prim), bpath)
        frames.append(frame)
        scales[i] = frame.s
        xform_ops.append(_op_names(prim))
        static = bool(desc.kinematicBody) or not bool(desc.rigidBodyEnabled)
        if desc.kinematicBody:
            notes.append(f"{bpath}: kinematic body; held at its initial pose")
        if static:
            mass, diag, com, axes = 0.0, np.ones(3), np.zeros(3), IDENTITY_QUAT
        else:
            mass, diag, com, axes = _body_mass(prim, desc, frame, xforms, report)
        com_offsets[i] = com
        position = (frame.t + quat_rotate(frame.q, com)) * mpu
        rpa = quat_to_matrix(axes)
        inertia = rpa @ np.diag(diag) @ rpa.T * (kpu * mpu * mpu)
        # Velocities are authored in the space of the prim's xform, i.e. its parent's frame.
        pq = decompose(xforms.parent(prim), bpath).q
        v = quat_rotate(pq, _real(bpath, "physics:velocity", desc.linearVelocity)) * mpu
        w = quat_rotate(pq, np.radians(_real(bpath, "physics:angularVelocity", desc.angularVelocity)))
        try:
            if static:
                index[bpath] = builder.add_static_body(position, frame.q, name=bpath)
            else:
                index[bpath] = builder.add_body(mass * kpu, inertia, position, frame.q, v, w, name=bpath)
        except SceneError as exc:
            raise UsdSceneError(str(exc) if bpath in str(exc) else f"{bpath}: {exc}") from None
        _read_forces(builder, prim, index[bpath], mpu, kpu)
    colliding, not_colliding, statics = _read_colliders(stage, get, builder, index, frames, com_offsets, xforms, mpu,
                                                        report)  # fmt: skip
    for group, _ in get(T.CollisionGroup):  # bodies a group filters out of each other would still collide
        report.unsupported(str(group), "collision-group filtering (a PhysicsCollisionGroup)")
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
            rel = decompose(parent_m @ np.linalg.inv(anc_m), f"{p} (relative to {anc.GetPath()})")
            parent_index[i] = a
        else:
            rel = decompose(parent_m, f"{p} (parent transform)")
        if not rel.uniform:
            raise UsdSceneError(f"{p}: rigid body under a non-uniformly scaled parent (scale "
                                f"{np.round(rel.s, 9).tolist()}); {_NON_UNIFORM}")  # fmt: skip
        parent_pos[i], parent_quat[i], parent_scale[i] = rel.t, rel.q, rel.s[0]

    joint_paths: list[str] = []
    slots: dict[tuple[str, str], tuple[int, float, float]] = {}  # a joint's drives, for `_read_actuators`
    distance_paths: list[str] = []
    loop_joints: list[str] = []
    supported = {T.RevoluteJoint, T.PrismaticJoint, T.SphericalJoint, T.FixedJoint, T.D6Joint, T.DistanceJoint}
    all_joints = []
    for t, (paths, descs) in parsed.items():
        if "Joint" in t.name:
            all_joints += [(str(p), t, d) for p, d in zip(paths, descs)]
    for jpath, t, desc in sorted(all_joints, key=lambda x: order.get(x[0], len(order))):
        jprim = stage.GetPrimAtPath(jpath)
        _check_defaults(jprim)
        if not desc.jointEnabled:
            notes.append(f"{jpath}: joint disabled (physics:jointEnabled = false); skipped")
            continue
        if t not in supported:
            report.unsupported(jpath, _joint_type_text(jprim.GetTypeName() or t.name))
            continue
        ends, held = [], []  # held: the static colliders at a joint end that is no rigid body
        for side, rel in ((0, desc.rel0), (1, desc.rel1)):
            if rel.isEmpty:
                ends.append(None)
                continue
            target = stage.GetPrimAtPath(rel)
            if not target:
                raise UsdSceneError(f"{jpath}: physics:body{side} targets {rel}, which does not exist")
            # Not the parser's body0/body1: it leaves out bodies with physics:rigidBodyEnabled = false (static here).
            # A prim inside a body stands for that body; any other prim (a static collider, the default prim)
            # is the world, at that prim's transform (`_joint_frame`), as in PhysX.
            body = _rigid_ancestor(target, index)
            ends.append(None if body is None else index[str(body.GetPath())])
            if body is None:
                held.extend(_statics_at(str(target.GetPath()), statics))
        if not desc.collisionEnabled:  # the schema's default: the bodies a joint holds do not collide
            for static in held:
                for end in {e for e in ends if e is not None}:
                    builder.filter_collision(static, end)
        if ends[0] is None and ends[1] is None:
            if desc.rel0.isEmpty and desc.rel1.isEmpty:
                raise UsdSceneError(f"{jpath}: both physics:body0 and physics:body1 are empty")
            report.note(f"{jpath}: neither physics:body0 nor physics:body1 is a rigid body or inside one; the "
                        f"joint holds only the world to itself; skipped")  # fmt: skip
            continue
        for attr in jprim.GetAuthoredAttributes():  # the parser reads a NaN limit as no limit
            if attr.GetName().endswith(_JOINT_BOUNDS) and attr.Get() is not None:
                _real(jpath, attr.GetName(), attr.Get(), infinite_ok=True)
        if math.isfinite(desc.breakForce) or math.isfinite(desc.breakTorque):
            report.unsupported(jpath, "a break force or torque")
        a0, q0 = _joint_frame(stage, jprim, 0, xforms, mpu)
        a1, q1 = _joint_frame(stage, jprim, 1, xforms, mpu)
        r0, r1 = quat_to_matrix(q0), quat_to_matrix(q1)
        parent, child = ends
        if t == T.DistanceJoint:
            lower = desc.limit.lower * mpu if desc.minEnabled else 0.0
            upper = desc.limit.upper * mpu if desc.maxEnabled else math.inf
            if not (desc.minEnabled or desc.maxEnabled):
                report.note(f"{jpath}: a distance joint with neither physics:minDistance nor maxDistance; skipped")
                continue
            try:
                builder.add_distance(parent, child, a0, a1, lower, upper, jpath)
                distance_paths.append(jpath)
            except SceneError as exc:
                raise UsdSceneError(str(exc) if jpath in str(exc) else f"{jpath}: {exc}") from None
            apart = float(np.linalg.norm(a1 - a0))
            if not lower <= apart <= upper:  # the first step's impulse pulls them in, adding energy
                report.note(f"{jpath}: its anchors start {apart / mpu:.6g} apart, outside [{lower / mpu:.6g}, "
                            f"{upper / mpu:.6g}]: the first step brings them within, at that gap per step, which adds "
                            "energy")  # fmt: skip
            continue
        dof, limit, drive = None, None, None  # the one DOF of a revolute or prismatic joint, its limit, its drive
        if t in (T.RevoluteJoint, T.PrismaticJoint):
            token = jprim.GetAttribute("physics:axis").Get()
            if token not in ("X", "Y", "Z"):  # the parser reads any other token as X
                raise UsdSceneError(f"{jpath}: physics:axis must be X, Y or Z, got {token!r}")
            ax = r0[:, "XYZ".index(token)]
            plans = [_JointPlan("revolute" if t == T.RevoluteJoint else "prismatic", ax)]
            free_t = [ax] if t == T.PrismaticJoint else []
            dof = "XYZ".index(token) + 3 * (t == T.RevoluteJoint)
            limit = (desc.limit.lower, desc.limit.upper) if desc.limit.enabled else None
            drive = desc.drive if desc.drive.enabled else None
        elif t == T.SphericalJoint:
            if desc.limit.enabled:
                report.unsupported(jpath, "a cone limit")
            plans, free_t = [_JointPlan("ball")], []
        elif t == T.FixedJoint:
            plans, free_t = [_JointPlan("fixed")], []
        else:
            locked_t, locked_r, ranges, drives = _d6_axes(desc, jpath, report)
            plans = _d6_plans(locked_t, locked_r, r0, r1)
            if not plans:
                notes.append(f"{jpath}: generic joint with no locked axis constrains nothing; skipped")
                continue
            free_t = [r0[:, k] for k in range(3) if k not in locked_t]
            free = [i for i in range(6) if i % 3 not in (locked_t if i < 3 else locked_r)]
            if len(free) == 1:  # a revolute or prismatic joint: its limit and drive act on its coordinate
                dof, limit, drive = free[0], ranges.pop(free[0], None), drives.pop(free[0], None)
            for i, (lo, hi) in sorted(ranges.items()):
                report.unsupported(jpath, f"a {_DOFS[i]} limit [{lo}, {hi}] on a joint with {len(free)} free DOFs")
            for i in sorted(drives):
                report.unsupported(jpath, f"a {_DOFS[i]} drive on a joint with {len(free)} free DOFs")
        # Apart along a free translation (a prismatic joint's axis) is where the joint starts; across, it is not.
        offset = a1 - a0 - sum((np.dot(a1 - a0, d) * d for d in free_t), np.zeros(3))
        gap, tolerance = float(np.linalg.norm(offset)), JOINT_GAP * max(1.0, float(np.abs(a0).max()))
        if gap > tolerance and ends[0] != ends[1]:  # it would take body0's frame and pull body1 across the gap
            raise UsdSceneError(
                f"{jpath}: its frames on body0 and body1 (physics:localPos0, physics:localPos1) are {gap:.3g} m "
                f"apart at the start; they must coincide (to {tolerance:.2g} m)"
            )
        sign = 1.0
        if child is None:  # body1 empty: the world is on the child side; swap so the child is a body
            parent, child, sign = None, parent, -1.0
            plans = [_JointPlan(p.kind, p.axis_child if p.axis_child is not None else p.axis,
                                p.axis if p.axis_child is not None else None) for p in plans]  # fmt: skip
        if desc.excludeFromArticulation:
            loop_joints.append(jpath)
        first_joint = len(builder.joints)
        try:
            for plan in plans:
                if plan.kind in JOINT_TYPES:
                    builder.add_joint(plan.kind, parent, child, a0, plan.axis, plan.axis_child, jpath)
                else:
                    builder.add_constraint(plan.kind, parent, child, a0, plan.axis, plan.axis_child, jpath)
                joint_paths.append(jpath)
            if desc.excludeFromArticulation:
                for k in range(first_joint, len(builder.joints)):
                    builder.mark_loop_joint(k)
            before = len(builder.drives)
            if limit is not None or drive is not None:
                x0 = _usd_coordinate(dof >= 3, dof % 3, a0, q0, a1, q1)
                scale, offset = _limit_and_drive(builder, first_joint, jprim, limit, drive, dof >= 3, x0, sign, mpu,
                                                 kpu, report)  # fmt: skip
                if len(builder.drives) > before:
                    slots[(jpath, "api")] = (before, scale, offset)
            before = len(builder.drives)
            _extra_drives(builder, first_joint, jprim, sign)
            for n in range(1, len(builder.drives) - before + 1):
                slots[(jpath, str(n))] = (before + n - 1, sign, 0.0)
        except UnsupportedFeatureError:
            raise
        except SceneError as exc:
            raise UsdSceneError(str(exc) if jpath in str(exc) else f"{jpath}: {exc}") from None
    joint_index: dict[str, int] = {}
    for k, jpath in enumerate(joint_paths):
        joint_index.setdefault(jpath, k)
    _read_chains(stage, builder, joint_index)
    _read_actuators(stage, builder, slots)
    parsed_joints = {j[0] for j in all_joints}
    for prim in stage.Traverse():  # typed joints the parser did not report (e.g. custom joint schemas)
        if prim.IsA(UsdPhysics.Joint) and str(prim.GetPath()) not in parsed_joints:
            report.unsupported(str(prim.GetPath()), _joint_type_text(prim.GetTypeName()))
    if not bodies:
        raise UsdSceneError(f"{path}: no rigid bodies (UsdPhysics RigidBodyAPI) in the stage")
    for prim_path, type_name in _unknown_physics_prims(stage):
        report.note(_unknown_type_text(prim_path, type_name))
    colliders = _ignored_colliders(stage, index, colliding, not_colliding)
    if colliders:
        report.note(_colliders_text(colliders))
    body_paths = [*(str(p) for p, _ in bodies), *(c.path for c in statics)]
    com_offsets, scales, parent_index, parent_pos, parent_quat, parent_scale, reset = _with_statics(
        statics, com_offsets, scales, parent_index, parent_pos, parent_quat, parent_scale, reset
    )
    xform_ops += [_op_names(stage.GetPrimAtPath(c.path)) for c in statics]
    default_prim = stage.GetDefaultPrim()
    default_prim_name = default_prim.GetName() if default_prim else ""
    if not default_prim_name:  # give the output a default prim even if the input lacks one
        roots = [p for p in stage.GetPseudoRoot().GetChildren() if p.IsDefined()]
        default_prim_name = roots[0].GetName() if roots else ""
    return UsdScene(
        builder=builder, source_path=os.path.abspath(path), body_paths=body_paths,
        joint_paths=joint_paths, com_offsets=com_offsets, body_scales=scales, parent_index=parent_index,
        parent_pos=parent_pos, parent_quat=parent_quat, parent_scale=parent_scale, reset_xform_stack=reset,
        meters_per_unit=mpu, kilograms_per_unit=kpu, up_axis=up, default_prim=default_prim_name,
        xform_ops=xform_ops, loop_joints=loop_joints, distance_paths=distance_paths, notes=notes, warnings=warned,
        colliders_ignored=len(colliders), dt=_recorded_dt(stage, path), time_codes_per_second=_rate(stage, path),
        time_range=_time_range(stage, path),
    )  # fmt: skip


def _ignored_colliders(
    stage, index: dict[str, int], colliding: set[str], not_colliding: dict[str, str]
) -> list[tuple[str, str]]:
    """(path, why) of the enabled collision prims (CollisionAPI) that do not collide, static ones first: those
    `_read_colliders` could not simulate, and those the parser did not take for colliders (not geometry)."""
    _, _, _, _, _, UsdPhysics, _ = pxr()
    static, moving = [], []
    for prim in stage.Traverse():
        if prim.HasAPI(UsdPhysics.CollisionAPI) and UsdPhysics.CollisionAPI(prim).GetCollisionEnabledAttr().Get():
            path = str(prim.GetPath())
            if path in colliding:
                continue
            why = not_colliding.get(path, "not a collision geometry")
            (static if _rigid_ancestor(prim, index) is None else moving).append((path, why))
    return static + moving


def _unknown_physics_prims(stage) -> list[tuple[str, str]]:
    """(path, type name) of prims whose type no schema defines but which author physics:* properties: USD
    (and so every simulator) ignores them, which the author rarely means (OpenUSD's own distance joint
    example is a `DistancePhysicsJoint`)."""
    _, _, Tf, *_ = pxr()
    unknown = Tf.Type.Unknown
    return [
        (str(prim.GetPath()), str(prim.GetTypeName()))
        for prim in stage.Traverse()
        if prim.GetTypeName()
        and prim.GetPrimTypeInfo().GetSchemaType() == unknown
        and any(name.startswith("physics:") for name in prim.GetAuthoredPropertyNames())
    ]


def _unknown_type_text(path: str, type_name: str) -> str:
    _, _, _, Usd, *_ = pxr()
    guess = "Physics" + type_name.replace("Physics", "")
    hint = f" (did you mean {guess}?)" if Usd.SchemaRegistry().FindConcretePrimDefinition(guess) else ""
    return f"{path}: no schema defines the prim type {type_name}{hint}; its physics:* properties are ignored"


def _colliders_text(colliders: list[tuple[str, str]]) -> str:
    """The one warning for colliders that do not collide, naming how many and the first (a static one when
    there is one) with why."""
    n = len(colliders)
    path, why = colliders[0]
    return (
        f"{n} collider{'s do' if n > 1 else ' does'} not collide ({'e.g. ' if n > 1 else ''}{path}: {why}): bodies "
        f"pass through {'them' if n > 1 else 'it'}; colliders still give their bodies mass"
    )


def _rate(stage, path: str) -> float:
    """The stage's timeCodesPerSecond (24 where it authors none)."""
    rate = float(stage.GetTimeCodesPerSecond())
    if not (rate > 0.0 and math.isfinite(rate)):
        raise UsdSceneError(f"{path}: the stage's timeCodesPerSecond must be positive and finite, got {rate}")
    return rate


def _time_range(stage, path: str) -> tuple[float, float] | None:
    """[startTimeCode, endTimeCode] when the stage authors both, else None."""
    if not stage.HasAuthoredTimeCodeRange():
        return None
    start, end = float(stage.GetStartTimeCode()), float(stage.GetEndTimeCode())
    if not (math.isfinite(start) and math.isfinite(end) and end >= start):
        raise UsdSceneError(f"{path}: the stage's time range [{start}, {end}] is not a finite interval")
    return start, end


def _start_time(stage):
    """The time code at which the scene starts: the stage's startTimeCode when it authors one (a prim animated
    in its layer stack is where it is then), else the default time."""
    _, _, _, Usd, *_ = pxr()
    return Usd.TimeCode(stage.GetStartTimeCode()) if stage.HasAuthoredTimeCodeRange() else Usd.TimeCode.Default()


def _material(stage, paths, where: str) -> tuple[float, float]:
    """(friction, restitution) of a collider's first bound PhysicsMaterialAPI material; (0.5, 0) without one.
    The dynamic friction is the Coulomb coefficient (warpimpulse has one for sliding and sticking)."""
    _, _, _, _, _, UsdPhysics, _ = pxr()
    for mpath in paths:
        prim = stage.GetPrimAtPath(mpath)
        if prim and prim.HasAPI(UsdPhysics.MaterialAPI):
            api = UsdPhysics.MaterialAPI(prim)
            friction = float(_real(str(mpath), "physics:dynamicFriction", api.GetDynamicFrictionAttr().Get() or 0.0))
            restitution = float(_real(str(mpath), "physics:restitution", api.GetRestitutionAttr().Get() or 0.0))
            if friction < 0.0:
                raise UsdSceneError(f"{mpath}: physics:dynamicFriction must be >= 0, got {friction} (bound to {where})")
            if not 0.0 <= restitution <= 1.0:
                raise UsdSceneError(f"{mpath}: physics:restitution must be in [0, 1], got {restitution} "
                                    f"(bound to {where})")  # fmt: skip
            return friction, restitution
    return 0.5, 0.0


@dataclass
class _StaticCollider:
    """A collision prim outside every rigid body, simulated as a static body: its prim path, its world
    similarity (stage units) and its index in the builder."""

    path: str
    frame: Similarity
    body: int


_AXIS_TURN = {0: np.array([0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5)]),  # +90 degrees about y: z onto x
              1: np.array([-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)]),  # -90 degrees about x: z onto y
              2: IDENTITY_QUAT}  # fmt: skip


def _uneven(kind: str, axis: int, sim: Similarity) -> str | None:
    """Why a collider's solid is not what the narrow phase collides (an ellipsoid, an elliptic capsule or
    cylinder: a sphere scaled unevenly, or a capsule or cylinder across its radius), or None."""
    radial = sim.s if kind == "sphere" else np.delete(sim.s, axis)
    if kind in ("sphere", "capsule", "cylinder") and np.ptp(radial) > 1e-9 * float(radial.max()):
        return f"a {kind} collider scaled unevenly across its radius (scale {np.round(sim.s, 9).tolist()})"
    return None


def _refuse(report: _Reporter, path: str, what: str) -> str:
    """An unsupported collider: an error naming it, or (told to ignore such) `what`, for the one warning about
    the colliders that do not collide."""
    if not report.ignore:
        report.unsupported(path, what)
    return what


def _read_colliders(
    stage, get, builder: SceneBuilder, index, frames, com_offsets, xforms, mpu, report
) -> tuple[set[str], dict[str, str], list[_StaticCollider]]:
    """CollisionAPI prims: a Plane without a rigid body is a ground; a Sphere, Capsule, Cube or Cylinder
    without one is a static body of that shape at the prim's world transform (scale applied: a floor, a wall, a
    ramp); one of a rigid body, centred on its centre of mass with its axis (a cube's edges) along the body
    frame's z (edges), is the body's collision shape (one per body). Each takes its material's friction and
    restitution; a body's FilteredPairsAPI targets never collide with it. A Mesh, Cone or other collider is
    unsupported (refused, or dropped with a warning when told to ignore such). Returns the colliders
    simulated, the others, which do not collide, with why (the reader warns once for them all,
    `_colliders_text`), and the static colliders in builder order."""
    _, _, _, _, UsdGeom, UsdPhysics, _ = pxr()
    T = UsdPhysics.ObjectType
    solids = (T.SphereShape, T.CapsuleShape, T.CubeShape, T.CylinderShape)
    shaped: set[int] = set()
    simulated: set[str] = set()
    ignored: dict[str, str] = {}
    statics: list[_StaticCollider] = []
    kinds = (T.SphereShape, T.CapsuleShape, T.Capsule1Shape, T.CubeShape, T.CylinderShape, T.Cylinder1Shape,
             T.PlaneShape, T.ConeShape, T.MeshShape, T.CustomShape, T.SpherePointsShape)  # fmt: skip
    found = [(p, t, desc) for t in kinds for p, desc in get(t) if desc.collisionEnabled]
    order = {str(p.GetPath()): k for k, p in enumerate(stage.Traverse())}
    for p, t, desc in sorted(found, key=lambda f: order.get(str(f[0]), len(order))):  # statics in file order
        path = str(p)
        prim = stage.GetPrimAtPath(p)
        body_prim = _rigid_ancestor(prim, index)
        friction, restitution = _material(stage, desc.materials, path)
        if t == T.PlaneShape and body_prim is None:
            sim = decompose(xforms.world(prim), path)
            axis = str(prim.GetAttribute("axis").Get() or "Z")
            normal = quat_rotate(sim.q, np.eye(3)["XYZ".index(axis)])
            builder.add_ground(float(np.dot(normal, sim.t)) * mpu, normal, friction, restitution)
            simulated.add(path)
            continue
        if t not in solids and t != T.PlaneShape:
            what = f"a {prim.GetTypeName() or t.name} collider (warpimpulse collides spheres, capsules, boxes, "
            ignored[path] = _refuse(report, path, what + "cylinders and planes)")
            continue
        if t not in solids:
            ignored[path] = f"a {t.name} on a rigid body"
            continue
        b = None if body_prim is None else index[str(body_prim.GetPath())]
        if b in shaped:
            ignored[path] = "a second collider on its body"
            continue
        shape, kind, axis, sim = _collider_shape(prim, xforms, report)
        uneven = _uneven(kind, axis, sim)
        if uneven:
            ignored[path] = _refuse(report, path, uneven)
            continue
        if b is not None:
            frame = frames[b]
            centre = frame.t + quat_rotate(frame.q, com_offsets[b])
            offset = quat_rotate(quat_conj(frame.q), sim.t - centre)
            turn = quat_to_matrix(quat_mul(quat_conj(frame.q), sim.q))
            along = np.abs(turn[:, axis]) if kind in ("capsule", "cylinder") else None
            aligned = (kind == "sphere" or (kind == "box" and np.allclose(np.abs(turn), np.eye(3), atol=1e-6))
                       or (along is not None and along[2] > 1.0 - 1e-6))  # fmt: skip
            scale = max(shape.bounding_radius(), 1e-12)
            if float(np.linalg.norm(offset)) > 1e-6 * scale or not aligned:
                ignored[path] = "off its body's centre of mass or turned from its body frame"
                continue
        size = dict(
            radius=shape.radius * mpu, length=shape.length * mpu, size=tuple(float(v) * mpu for v in shape.size)
        )
        try:
            si = Shape(kind, **size)
            if si.zero_size():
                raise SceneError(f"collision shape {kind} has zero size")
            friction, restitution = checked_material(friction, restitution, path)
            if b is None:  # a static collider: its own static body, its shape's axis along the body's z
                q = quat_mul(sim.q, _AXIS_TURN[axis if kind in ("capsule", "cylinder") else 2])
                k = builder.add_static_body(sim.t * mpu, q, name=path, shape=si, friction=friction,
                                            restitution=restitution)  # fmt: skip
                statics.append(_StaticCollider(path, sim, k))
            else:
                body = builder.bodies[b]
                body.shape, body.friction, body.restitution = si, friction, restitution
                shaped.add(b)
        except (SceneError, ValueError) as exc:
            raise UsdSceneError(str(exc) if path in str(exc) else f"{path}: {exc}") from None
        simulated.add(path)
    for p, desc in get(T.RigidBody):
        a = index.get(str(p))
        for target in desc.filteredCollisions:
            other = _rigid_ancestor(stage.GetPrimAtPath(target), index)
            if a is not None and other is not None and index[str(other.GetPath())] != a:
                builder.filter_collision(a, index[str(other.GetPath())])
    return simulated, ignored, statics


def _with_statics(statics: list[_StaticCollider], com_offsets, scales, parent_index, parent_pos, parent_quat,
                  parent_scale, reset) -> tuple[np.ndarray, ...]:  # fmt: skip
    """The rigid bodies' per-body arrays (`UsdScene`) with the static colliders' bodies after them: no centre of
    mass offset, the prim's world scale, the world as parent frame (the output never moves them; it keeps their
    prims as authored)."""
    k = len(statics)
    return (
        np.vstack([com_offsets, np.zeros((k, 3))]),
        np.vstack([scales, *(c.frame.s for c in statics)]),
        np.concatenate([parent_index, np.full(k, -1)]),
        np.vstack([parent_pos, np.zeros((k, 3))]),
        np.vstack([parent_quat, np.tile(IDENTITY_QUAT, (k, 1))]),
        np.concatenate([parent_scale, np.ones(k)]),
        np.concatenate([reset, np.zeros(k, dtype=bool)]),
    )


def _statics_at(target: str, statics: list[_StaticCollider]) -> list[int]:
    """The static colliders' bodies at or under prim path `target` (a joint end that is no rigid body)."""
    return [s.body for s in statics if s.path == target or s.path.startswith(target.rstrip("/") + "/")]


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
    return f"the joint type {type_name} (supported: revolute, prismatic, spherical, fixed, distance and D6 joints)"


def _op_names(prim) -> tuple[str, str, str]:
    """xformOp names for the exported pose and scale: the plain ones unless the input gave them other value
    types (an `over` of another type is a validation error; OpenUSD's examples scale with float3), then ones
    with a `:warpimpulse` suffix."""
    ops = []
    for op, type_name in (("xformOp:translate", "double3"), ("xformOp:orient", "quatd"), ("xformOp:scale", "double3")):
        attr = prim.GetAttribute(op)
        clash = attr and attr.HasAuthoredValue() and str(attr.GetTypeName()) != type_name
        ops.append(f"{op}:warpimpulse" if clash else op)
    return ops[0], ops[1], ops[2]


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
