"""What the USD reader and writer share: the `UsdScene` (a SceneBuilder plus the prim paths and frames that
put simulated bodies back on their prims), the errors, the prim paths of procedural output and the lazy pxr
import."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..builder import SceneBuilder, SceneError
from ..files import fd2_captured, usd_message, usd_warnings
from ..joints import JOINT_TYPES
from ..model import Model
from ..shapes import SHAPE_CODES, Shape
from ..transforms import quat_rotate
from ..types import DRIVE_MODES, WORLD, ConstraintKind

WORLD_PATH = "/World"
INSTANCER_PATH = "/World/Instancer"
MODE_KEY = "warpimpulse:mode"  # customLayerData: "procedural", "layered" or "instancer"
IDENTITY_QUAT = np.array([0.0, 0.0, 0.0, 1.0])  # (x, y, z, w)
# The prims a procedural output puts under /World besides the bodies (a body of that name is renamed)
RESERVED_NAMES = ("Joints", "PhysicsScene", "Instancer", "Looks", "Visuals", "PhysicsMaterials", "Actuators")


class UsdSceneError(SceneError):
    """A USD file that cannot be simulated as it is; the message names the file or prim at fault."""


class UnsupportedFeatureError(UsdSceneError):
    """A drive, limit or other authored feature the simulator does not model (see `ignore_unsupported`)."""


def pxr():
    """Import pxr lazily: `import warpimpulse` must not pay for USD."""
    from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt

    return Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt


@dataclass
class UsdScene:
    """A SceneBuilder plus what export needs to put simulated bodies back on their prims.

    Per body (builder order): prim path, centre-of-mass offset in the prim's rigid frame (stage units),
    the prim's own scale, and its parent frame: relative to the world (`parent_index` -1) or to an
    ancestor rigid body, as translation / rotation (x, y, z, w) / uniform scale. Read from a file, the rigid
    bodies come first, then the static colliders' bodies (collision prims without a rigid body: no offset,
    their world scale, the world as parent; the output leaves their prims as authored).
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
    xform_ops: list[tuple[str, str, str]] | None = None  # (translate, orient, scale) op names per body; None: plain
    loop_joints: list[str] = field(default_factory=list)
    distance_paths: list[str] = field(default_factory=list)  # prims of the builder's distance constraints
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # the notes that were warned about (the output records them)
    colliders_ignored: int = 0  # CollisionAPI prims that take no part in the motion
    dt: float | None = None  # the step size the file asks for (customLayerData warpimpulse:dt), if any
    # The stage's time: time codes per second, and its [start, end] range (None when it authors none).
    # An output over the input keeps its rate, so that time code c means the same instant in both.
    time_codes_per_second: float | None = None
    time_range: tuple[float, float] | None = None

    @property
    def body_count(self) -> int:
        return len(self.body_paths)


def scene_from_builder(builder: SceneBuilder) -> UsdScene:
    """The UsdScene of a procedural builder: bodies at /World/<name>, centre of mass at the prim origin."""
    _, _, Tf, *_ = pxr()
    n = len(builder.bodies)
    paths, used = [], set()
    for b in builder.bodies:
        base = Tf.MakeValidIdentifier(b.name.strip("/").replace("/", "_") or "body")
        name, k = base, 1
        while name in used or name in RESERVED_NAMES:
            name, k = f"{base}_{k}", k + 1
        used.add(name)
        paths.append(f"{WORLD_PATH}/{name}")
    joint_paths, used = [], set()
    for j in [*builder.joints, *builder.distances]:
        base = Tf.MakeValidIdentifier(j.name.strip("/").replace("/", "_") or "joint")
        name, k = base, 1
        while name in used:
            name, k = f"{base}_{k}", k + 1
        used.add(name)
        joint_paths.append(f"{WORLD_PATH}/Joints/{name}")
    joint_paths, distance_paths = joint_paths[: len(builder.joints)], joint_paths[len(builder.joints) :]
    ident = np.tile(IDENTITY_QUAT, (n, 1))
    return UsdScene(
        builder=builder, source_path=None, body_paths=paths, joint_paths=joint_paths, distance_paths=distance_paths,
        com_offsets=np.zeros((n, 3)), body_scales=np.ones((n, 3)), parent_index=np.full(n, -1),
        parent_pos=np.zeros((n, 3)), parent_quat=ident, parent_scale=np.ones(n),
        reset_xform_stack=np.zeros(n, dtype=bool), default_prim="World",
    )  # fmt: skip


def builder_from_model(model: Model) -> SceneBuilder:
    """A SceneBuilder that finalizes to `model` again: the bodies at their initial state, each joint from its
    first constraint's build-time anchor and axes (the builder gives all of a joint's constraints the same
    ones), the forces, the distance constraints, the collision shapes, materials, grounds and filters. Bodies
    without a collision shape have none: the writer draws each as a sphere of the same mean inertia (write the
    SceneBuilder itself to keep display shapes and colours)."""
    h = model.host
    builder = SceneBuilder(gravity=h.gravity)
    for i, name in enumerate(model.body_name):
        if h.body_static[i]:
            builder.add_static_body(h.body_x[i], h.body_q[i], name=name)
        else:
            builder.add_body(h.body_mass[i], h.body_inertia[i], h.body_x[i], h.body_q[i], h.body_v[i], h.body_w[i],
                             name=name)  # fmt: skip
    for k, (name, kind) in enumerate(zip(model.joint_name, model.joint_type)):
        first, end = h.joint_constraint_start[k], h.joint_constraint_start[k + 1]
        kinds = [ConstraintKind(int(c)) for c in h.constraint_kind[first:end]]
        parent, child = int(h.joint_parent[k]), int(h.joint_child[k])
        x0, q0 = (np.zeros(3), IDENTITY_QUAT) if parent == WORLD else (h.body_x[parent], h.body_q[parent])
        anchor = x0 + quat_rotate(q0, h.constraint_anchor0[first])
        axis = quat_rotate(q0, h.constraint_axis0[first]) if any(c.needs_axis for c in kinds) else None
        axis_child = quat_rotate(h.body_q[child], h.constraint_axis1[first]) if ConstraintKind.ANGLE in kinds else None
        add = builder.add_joint if kind in JOINT_TYPES else builder.add_constraint
        add(kind, None if parent == WORLD else parent, child, anchor, axis, axis_child, name)
    for body, force, torque, until in zip(h.force_body, h.force_force, h.force_torque, h.force_until):
        builder.add_force(int(body), force, torque, float(until))
    _mechanisms_from_model(builder, model)
    _restore_colliders(builder, model)
    return builder


def _mechanisms_from_model(builder: SceneBuilder, model: Model) -> None:
    """The model's springs, drives and actuators, limits, distance constraints and loop marks back on `builder`
    (whose bodies and joints are the model's, in order). Chains of joints (`chain_joints`) are not restored: a drive on
    a chained joint comes back acting on its own joint's bodies."""
    h = model.host
    for k in np.flatnonzero(h.joint_loop).tolist():
        builder.mark_loop_joint(k)
    for i, name in enumerate(model.spring_name):
        b0, b1 = int(h.spring_body0[i]), int(h.spring_body1[i])
        ends = []
        for b, anchor in ((b0, h.spring_anchor0[i]), (b1, h.spring_anchor1[i])):
            ends.append(anchor if b == WORLD else h.body_x[b] + quat_rotate(h.body_q[b], anchor))
        k, c, rest = h.spring_params[i]
        builder.add_spring(None if b0 == WORLD else b0, None if b1 == WORLD else b1, *ends, k, c, rest, name)
    for i in range(model.drive_count):
        joint, (kp, ki, kd) = int(h.drive_joint[i]), h.drive_gains[i]
        if not h.drive_motor[i]:
            builder.add_joint_spring(joint, kp, kd, h.drive_target[i])
        else:
            builder.add_motor(joint, DRIVE_MODES[h.drive_mode[i]], h.drive_target[i], kp, ki, kd,
                              h.drive_max_force[i], stiff=bool(h.drive_stiff[i]))  # fmt: skip
    motors = np.cumsum(h.drive_motor) - 1  # each drive's index among the motors (`add_actuator`'s)
    for name, drive, (gain, bias, low, high) in zip(model.actuator_name, h.actuator_drive, h.actuator_map):
        builder.add_actuator(int(motors[drive]), gain, bias, (low, high), name)
    for joint, (lower, upper), drive in zip(h.limit_joint, h.limit_bounds, h.limit_drive):
        if drive < 0 and joint >= 0:  # the stiff motors' rows come back with their motors, distances below
            builder.add_joint_limit(int(joint), lower, upper)
    for name, bodies, (local0, local1, _), (lower, upper) in zip(
        model.distance_name, h.distance_body, h.distance_anchor, h.distance_bounds
    ):
        ends = [None if b == WORLD else int(b) for b in bodies]
        anchors = [
            a if b is None else h.body_x[b] + quat_rotate(h.body_q[b], a) for b, a in zip(ends, (local0, local1))
        ]
        builder.add_distance(ends[0], ends[1], anchors[0], anchors[1], float(lower), float(upper), name)


def _restore_colliders(builder: SceneBuilder, model: Model) -> None:
    """The model's collision shapes (from their sizes), materials, grounds and filters, back on the builder."""
    c = model.colliders
    if c is None:
        return
    kinds = {code: kind for kind, code in SHAPE_CODES.items()}
    for body, code, size, friction, restitution in zip(builder.bodies, c.shape_kind, c.shape_size, c.friction,
                                                        c.restitution):  # fmt: skip
        body.friction, body.restitution = float(friction), float(restitution)
        if code >= 0:
            kind = kinds[int(code)]
            if kind == "box":
                body.shape = Shape(kind, size=tuple(2.0 * float(v) for v in size))
            else:
                body.shape = Shape(kind, radius=float(size[0]), length=2.0 * float(size[1]))
    for normal, offset, friction, restitution in zip(c.plane_normal, c.plane_offset, c.plane_friction,
                                                      c.plane_restitution):  # fmt: skip
        builder.add_ground(float(offset), normal, float(friction), float(restitution))
    jointed = {(min(j.parent, j.child), max(j.parent, j.child)) for j in builder.joints}
    for a, b in c.filter_pairs.tolist():
        if (a, b) not in jointed:
            builder.filter_collision(a, b)


def as_scene(scene: UsdScene | SceneBuilder | Model) -> UsdScene:
    """A UsdScene as it is; a SceneBuilder, or a Model (through `builder_from_model`), as a procedural scene."""
    if isinstance(scene, UsdScene):
        return scene
    if isinstance(scene, SceneBuilder):
        return scene_from_builder(scene)
    if isinstance(scene, Model):
        return scene_from_builder(builder_from_model(scene))
    raise TypeError(f"expected a UsdScene, SceneBuilder or Model, got {type(scene).__name__}")


def open_stage(path: str):
    """The stage of a file, or a UsdSceneError naming the file: missing, not USD, or part of it missing (a
    sublayer, reference or payload that cannot be opened: the scene would be simulated without it). USD's own
    warnings while composing go into the error instead of onto stderr."""
    _, _, Tf, Usd, *_ = pxr()
    if not os.path.isfile(path):
        raise UsdSceneError(f"{path}: no such file")
    try:
        with fd2_captured() as caught:
            stage = Usd.Stage.Open(path)
    except Tf.ErrorException as exc:
        raise UsdSceneError(f"{path}: not a USD file that can be opened ({usd_message(exc)})") from None
    if stage is None:
        raise UsdSceneError(f"{path}: not a USD file that can be opened")
    errors = [" ".join(str(e).split()) for e in stage.GetCompositionErrors()]
    if errors:
        more = f"; and {len(errors) - 3} more" if len(errors) > 3 else ""
        raise UsdSceneError(f"{path}: part of the scene cannot be opened: {'; '.join(errors[:3])}{more}")
    for text in usd_warnings(caught):
        warnings.warn(f"{path}: {text}", stacklevel=2)
    return stage
