"""USD out: simulated motion as time samples (`AnimationWriter`), and a builder as a scene file (`save_scene`).

Frames stream into an Sdf layer through the Sdf API (3.6-3.8x faster than `attr.Set`; docs/architecture.md)
and the file is written atomically (a temporary file in the same folder, then a rename). A scene read from
a file is exported as a small layer that sublayers the input and holds `over`s on the body prims; a
procedural scene is written whole, as usda text with geometry and UsdPhysics schemas, so that the output
reads back with `load_stage`; above `INSTANCER_AUTO_BODIES` bodies it is one PointInstancer instead.

A layered output keeps the input's units and up axis (it composes with the input's geometry). USD stores
quaternions real part first (`Gf.Quatd(w, x, y, z)`); the writer takes them as (x, y, z, w).
"""

from __future__ import annotations

import math
import os
from collections import deque
from collections.abc import Iterable
from itertools import chain, cycle, repeat
from typing import Any

import numpy as np

from .. import __version__
from ..builder import WORLD, SceneBuilder, SceneError, Visual
from ..files import Interrupted, interrupts_deferred, same_file, write_atomically
from ..shapes import Shape
from ..transforms import quat_between, quat_conj, quat_from_matrix, quat_mul, quat_rotate
from ..types import DRIVE_MODES
from .scene import IDENTITY_QUAT, INSTANCER_PATH, MODE_KEY, UsdScene, as_scene, pxr, scene_from_builder

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
CHUNK_BYTES = 32 * 2**20
CHUNK_FRAMES = 512
_PLAIN_OPS = ("xformOp:translate", "xformOp:orient", "xformOp:scale")


def _frame_axes(axis: np.ndarray, second: np.ndarray | None = None) -> np.ndarray:
    """A rotation matrix whose first column is `axis` (second column along `second` if given)."""
    x = axis / np.linalg.norm(axis)
    if second is None:
        second = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = second - np.dot(second, x) * x
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


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
        if not (pt.any() or reset.any() or (ps != 1.0).any() or (pq != IDENTITY_QUAT).any()):
            return origin, q + 0.0  # every parent frame is the world's (procedural scenes); + 0.0: no -0 in files
    else:  # parent frame = ancestor body's simulated pose composed with the static relative transform
        anc = np.where(nested, a, 0)
        anc_t = np.where(nested[:, None], origin[anc], 0.0)
        anc_q = np.where(nested[:, None], q[anc], IDENTITY_QUAT)
        anc_s = np.where(nested, scene.body_scales[anc, 0], 1.0)
        pt = anc_t + anc_s[:, None] * quat_rotate(anc_q, scene.parent_pos)
        pq = quat_mul(anc_q, scene.parent_quat)
        ps = anc_s * scene.parent_scale
    if reset.any():
        pt = np.where(reset[:, None], 0.0, pt)
        pq = np.where(reset[:, None], IDENTITY_QUAT, pq)
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
        Gf, Sdf, _, _, _, _, Vt = pxr()
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


def _solid_lines(shape: Shape) -> tuple[str, list[str]]:
    """A Capsule / Cube / Sphere / Cylinder prim's type and attribute lines (local z axis, centred; a box as a
    unit Cube scaled by its edges, the scale op last)."""
    r, ln = shape.radius, shape.length
    if shape.kind in ("capsule", "cylinder"):
        cap = r if shape.kind == "capsule" else 0.0
        type_name = "Capsule" if shape.kind == "capsule" else "Cylinder"
        lines = [f"double radius = {_f(r)}", f"double height = {_f(ln)}", 'uniform token axis = "Z"']
        lo, hi = (-r, -r, -(0.5 * ln + cap)), (r, r, 0.5 * ln + cap)
    elif shape.kind == "sphere":
        type_name, lines = "Sphere", [f"double radius = {_f(r)}"]
        lo, hi = (-r, -r, -r), (r, r, r)
    else:
        type_name, lines = "Cube", ["double size = 1"]
        lo, hi = (-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)
    lines.append(f"float3[] extent = [{_tup(lo)}, {_tup(hi)}]")
    return type_name, lines


def _prim_usda(type_name: str, name: str, lines: list[str], schemas: list[str], indent: str) -> str:
    meta = ""
    if schemas:
        listed = ", ".join(f'"{x}"' for x in schemas)
        meta = f" (\n{indent}    prepend apiSchemas = [{listed}]\n{indent})"
    inner = "".join(f"{indent}    {line}\n" for line in lines)
    return f'{indent}def {type_name} "{name}"{meta}\n{indent}{{\n{inner}{indent}}}\n'


def _geometry_usda(
    name: str, shape: Shape, indent: str, material: str | None = None, look: str | None = None, guide: bool = False
) -> str:
    """One Capsule / Cube / Sphere / Cylinder prim (`_solid_lines`) with a display colour, as usda; with
    `material` (a physics material's path), a collider (CollisionAPI) bound to it; with `look` (a
    UsdPreviewSurface material's path), that material bound for rendering; `guide`: drawn only as a guide (a
    collider under visual geometry)."""
    type_name, lines = _solid_lines(shape)
    if shape.kind == "box":
        lines += [f"double3 xformOp:scale = {_tup(shape.size)}", 'uniform token[] xformOpOrder = ["xformOp:scale"]']
    lines.append(f'color3f[] primvars:displayColor = [{_tup(shape.color)}] (interpolation = "constant")')
    if guide:
        lines.append('uniform token purpose = "guide"')
    schemas = []
    if material is not None:
        lines.append(f"rel material:binding:physics = <{material}>")
        schemas = ["PhysicsCollisionAPI", "MaterialBindingAPI"]
    if look is not None:
        lines.append(f"rel material:binding = <{look}>")
        schemas = schemas or ["MaterialBindingAPI"]
    return _prim_usda(type_name, name, lines, schemas, indent)


LOOKS_PATH = "/World/Looks"


def _rgba(color) -> tuple[float, ...]:
    """An RGB or RGBA colour as RGBA (opaque by default)."""
    return tuple(float(c) for c in color) + ((1.0,) if len(color) == 3 else ())


def _looks_usda(builder: SceneBuilder) -> tuple[str, dict[tuple[float, ...], str]]:
    """One UsdPreviewSurface Material per distinct colour of the bodies' shapes and the visuals, under
    /World/Looks, so that a renderer (Blender, usdview, Omniverse) shows the colours, not a default grey;
    returns the usda and each colour's material path."""
    colors = [_rgba(b.shape.color) for b in builder.bodies if b.shape is not None]
    colors += [_rgba(v.rgba) for v in builder.visuals]
    paths = {rgba: f"{LOOKS_PATH}/color{k}" for k, rgba in enumerate(dict.fromkeys(colors))}
    if not paths:
        return "", paths
    out = ['    def Scope "Looks"\n    {\n']
    for rgba, path in paths.items():
        name = path.rsplit("/", 1)[1]
        out.append(f'        def Material "{name}"\n        {{\n'
                   f"            token outputs:surface.connect = <{path}/PreviewSurface.outputs:surface>\n"
                   f'            def Shader "PreviewSurface"\n            {{\n'
                   f'                uniform token info:id = "UsdPreviewSurface"\n'
                   f"                color3f inputs:diffuseColor = {_tup(rgba[:3])}\n"
                   f"                float inputs:opacity = {_f(rgba[3])}\n"
                   f"                float inputs:roughness = 0.5\n"
                   f"                token outputs:surface\n            }}\n        }}\n")  # fmt: skip
    out.append("    }\n")
    return "".join(out), paths


def _numbers(values: np.ndarray, fmt: str) -> str:
    """Rows of numbers as usda tuples "(a, b, c), ..." (`fmt` per number)."""
    row = "(" + ", ".join([fmt] * values.shape[1]) + ")"
    return ", ".join(row % tuple(v) for v in values.tolist())


def _visual_usda(visual: Visual, name: str, indent: str, look: str) -> str:
    """A `Visual` as a display-only prim (no physics schema) placed in its body's frame, bound to `look`."""
    if visual.kind == "mesh":
        v, f = np.asarray(visual.vertices, dtype=np.float64), np.asarray(visual.faces, dtype=np.int64)
        type_name, scale = "Mesh", visual.size
        lines = [
            f"point3f[] points = [{_numbers(v, '%.9g')}]",
            f"int[] faceVertexCounts = [{', '.join(['3'] * len(f))}]",
            f"int[] faceVertexIndices = [{', '.join(map(str, f.reshape(-1).tolist()))}]",
            f"float3[] extent = [{_tup(v.min(axis=0))}, {_tup(v.max(axis=0))}]",
            'uniform token subdivisionScheme = "none"',
        ]
    else:
        r, length = visual.size[0], visual.size[1]
        solid = Shape("box", size=visual.size) if visual.kind == "box" else Shape(visual.kind, r, length)
        type_name, lines = _solid_lines(solid)
        scale = visual.size if visual.kind == "box" else (1.0, 1.0, 1.0)
    lines += [
        f'color3f[] primvars:displayColor = [{_tup(visual.rgba[:3])}] (interpolation = "constant")',
        f"rel material:binding = <{look}>",
        f"double3 xformOp:translate = {_tup(visual.position)}",
        f"quatd xformOp:orient = {_quat_text(visual.orientation)}",
        f"double3 xformOp:scale = {_tup(scale)}",
        'uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:orient", "xformOp:scale"]',
    ]
    return _prim_usda(type_name, name, lines, ["MaterialBindingAPI"], indent)


def _materials_usda(builder: SceneBuilder) -> tuple[str, dict[tuple[float, float], str]]:
    """One PhysicsMaterialAPI Material per (friction, restitution) of the colliding bodies and the grounds (the
    same static and dynamic friction), under /World/PhysicsMaterials; returns the usda and the paths."""
    pairs = [(b.friction, b.restitution) for b in builder.bodies if b.shape is not None and b.shape.collide]
    pairs += [(g.friction, g.restitution) for g in builder.grounds]
    paths = {pair: f"/World/PhysicsMaterials/material{k}" for k, pair in enumerate(dict.fromkeys(pairs))}
    if not paths:
        return "", paths
    out = ['    def Scope "PhysicsMaterials"\n    {\n']
    for (friction, restitution), path in paths.items():
        out.append(f'        def Material "{path.rsplit("/", 1)[1]}" (\n            prepend apiSchemas = '
                   f'["PhysicsMaterialAPI"]\n        )\n        {{\n'
                   f"            float physics:staticFriction = {_f(friction)}\n"
                   f"            float physics:dynamicFriction = {_f(friction)}\n"
                   f"            float physics:restitution = {_f(restitution)}\n        }}\n")  # fmt: skip
    out.append("    }\n")
    return "".join(out), paths


_ORDER = 'uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:orient"]'


def _grounds_usda(builder: SceneBuilder, materials: dict[tuple[float, float], str]) -> str:
    """Each ground as a static collider Plane prim (axis Z turned onto the normal, through normal * height)."""
    out = []
    for k, g in enumerate(builder.grounds):
        q = quat_between([0.0, 0.0, 1.0], g.normal)
        out.append(f'    def Plane "Ground{k}" (\n        prepend apiSchemas = ["PhysicsCollisionAPI", '
                   f'"MaterialBindingAPI"]\n    )\n    {{\n'
                   f'        uniform token axis = "Z"\n        double width = 20\n        double length = 20\n'
                   f"        rel material:binding:physics = <{materials[(g.friction, g.restitution)]}>\n"
                   f"        double3 xformOp:translate = {_tup(g.normal * g.height)}\n"
                   f"        quatd xformOp:orient = {_quat_text(q)}\n"
                   f"        {_ORDER}\n    }}\n")  # fmt: skip
    return "".join(out)


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
    order = sorted(range(len(builder.joints)), key=lambda k: builder.joints[k].loop)  # marked loop joints last
    for k in order:
        j = builder.joints[k]
        a = find(world if j.parent == WORLD else node[j.parent])
        c = find(node[j.child])
        if a == c:
            loops.add(k)
        else:
            parent[a] = c
    return loops


def _extra_drive(drive, n: int) -> list[str]:
    """A drive USD's DriveAPI cannot hold (a second drive on the joint's one axis, such as a joint damper beside a
    motor, or an effort motor: a torque or force by itself) as warpimpulse:drive<n>:* attributes of the joint,
    in the builder's terms: SI units, the coordinate 0 as built (`reader._extra_drives` reads them back)."""
    kp, ki, kd = drive.kp, drive.ki, drive.kd
    lines = [f'custom string warpimpulse:drive{n}:mode = "{DRIVE_MODES[drive.mode]}"',
             f"custom double warpimpulse:drive{n}:target = {_f(drive.target)}",
             f"custom double3 warpimpulse:drive{n}:gains = ({_f(kp)}, {_f(ki)}, {_f(kd)})",
             f"custom bool warpimpulse:drive{n}:motor = {int(drive.motor)}",
             f"custom bool warpimpulse:drive{n}:stiff = {int(drive.stiff)}"]  # fmt: skip
    if math.isfinite(drive.max_force):
        lines.append(f"custom double warpimpulse:drive{n}:maxForce = {_f(drive.max_force)}")
    return lines


def _joint_mechanisms(builder: SceneBuilder) -> tuple[dict[int, tuple[list[str], list[str]]], dict[int, tuple]]:
    """Per joint: the DriveAPI schema and the attribute lines of its limit and drive (revolute: degrees, gains
    per degree; prismatic: metres), the inverse of the reader's `_limit_and_drive`. USD has one drive per
    joint axis: a joint's further drives, and effort motors, are `_extra_drive` attributes. USD has no
    point-to-point spring: a scene with springs is refused. Also per drive: the joint prim's attribute that
    holds its target and that attribute's unit in the builder's (degrees per rad, or 1), for `_actuators_usda`."""
    if builder.springs:
        raise SceneError(f"spring {builder.springs[0].name!r}: USD has no spring between two points; not written")
    out: dict[int, tuple[list[str], list[str]]] = {}
    targets: dict[int, tuple[str, float]] = {}
    for limit in builder.limits:
        j = builder.joints[limit.joint]
        unit = math.degrees(1.0) if j.kind == "revolute" else 1.0
        lines = []
        for name, value in (("lowerLimit", limit.lower), ("upperLimit", limit.upper)):
            if math.isfinite(value):
                lines.append(f"float physics:{name} = {_f(value * unit)}")
        out[limit.joint] = ([], lines)
    extra: dict[int, int] = {}  # per joint, the drives written as warpimpulse:drive<n>:* (`_extra_drive`)
    for d, drive in enumerate(builder.drives):
        j = builder.joints[drive.joint]
        if (drive.joint in out and out[drive.joint][0]) or drive.mode == DRIVE_MODES.index("effort"):
            extra[drive.joint] = extra.get(drive.joint, 0) + 1
            schema, lines = out.get(drive.joint, ([], []))
            out[drive.joint] = (schema, lines + _extra_drive(drive, extra[drive.joint]))
            targets[d] = (f"warpimpulse:drive{extra[drive.joint]}:target", 1.0)
            continue
        angular = j.kind == "revolute"
        unit = math.degrees(1.0) if angular else 1.0  # a coordinate in USD's unit
        per = 1.0 / unit  # a gain per USD unit
        kind = "angular" if angular else "linear"
        velocity = drive.mode == DRIVE_MODES.index("velocity")
        targets[d] = (f"drive:{kind}:physics:target{'Velocity' if velocity else 'Position'}", unit)
        stiffness, damping = (0.0, drive.kp) if velocity else (drive.kp, drive.kd)
        attrs = {
            "type": '"force"',
            "stiffness": _f(stiffness * per),
            "damping": _f(damping * per),
            "targetPosition": _f(0.0 if velocity else drive.target * unit),
            "targetVelocity": _f(drive.target * unit if velocity else 0.0),
        }
        lines = [
            f"{'uniform token' if name == 'type' else 'float'} drive:{kind}:physics:{name} = {value}"
            for name, value in attrs.items()
        ]
        if math.isfinite(drive.max_force):
            lines.append(f"float drive:{kind}:physics:maxForce = {_f(drive.max_force)}")
        if drive.ki:
            lines.append(f"custom double warpimpulse:drive:ki = {_f(drive.ki * per)}")
        if drive.stiff or (drive.motor and velocity):  # the reader takes a velocity drive without it as stiff
            lines.append(f"custom bool warpimpulse:drive:stiff = {int(drive.stiff)}")
        if not drive.motor:
            lines.append("custom bool warpimpulse:drive:jointSpring = 1")
        limit_lines = out.get(drive.joint, ([], []))[1]
        out[drive.joint] = ([f'"PhysicsDriveAPI:{kind}"'], limit_lines + lines)
    return out, targets


def _actuators_usda(scene: UsdScene, targets: dict[int, tuple[str, float]]) -> str:
    """Each actuator (`SceneBuilder.actuators`, in order: a control's index) as a Scope under /World/Actuators
    holding warpimpulse:* attributes, UsdPhysics having no actuator: the joint prim (warpimpulse:joint), the
    attribute of it whose value the control sets (warpimpulse:target: a DriveAPI's targetPosition or
    targetVelocity, or a warpimpulse:drive<n>:target), and the map, in that attribute's units,
    target = gain * clip(control, ctrlRange) + bias (the reader's `_read_actuators`)."""
    _, _, Tf, *_ = pxr()
    builder = scene.builder
    out, used = ['    def Scope "Actuators"\n    {\n'], set()
    for a in builder.actuators:
        base = Tf.MakeValidIdentifier(a.name) or "actuator"
        name, k = base, 1
        while name in used:
            name, k = f"{base}_{k}", k + 1
        used.add(name)
        target, unit = targets[a.drive]
        low, high = (max(x, -1e300) if x < 0 else min(x, 1e300) for x in a.ctrl_range)  # usda has no inf
        text = a.name.replace("\\", "\\\\").replace('"', '\\"')
        lines = [f'custom string warpimpulse:name = "{text}"',
                 f"custom rel warpimpulse:joint = <{scene.joint_paths[builder.drives[a.drive].joint]}>",
                 f'custom string warpimpulse:target = "{target}"',
                 f"custom double warpimpulse:gain = {_f(a.gain * unit)}",
                 f"custom double warpimpulse:bias = {_f(a.bias * unit)}",
                 f"custom double2 warpimpulse:ctrlRange = ({_f(low)}, {_f(high)})"]  # fmt: skip
        out.append(_prim_usda("Scope", name, lines, [], "        "))
    out.append("    }\n")
    return "".join(out)


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
    materials_usda, materials = _materials_usda(builder)
    out.append(materials_usda)
    looks_usda, looks = _looks_usda(builder)
    out.append(looks_usda)
    visuals: dict[int, list[Visual]] = {}
    for v in builder.visuals:
        visuals.setdefault(v.body, []).append(v)
    out.append(_grounds_usda(builder, materials))
    filters: dict[int, list[int]] = {}
    for a, b in sorted(builder.collision_filters):
        filters.setdefault(a, []).append(b)
    forces: dict[int, list] = {}
    for f in builder.forces:
        forces.setdefault(f.body, []).append(f)
    local_t, local_q = poses[0].tolist(), poses[1].tolist()
    # Principal moments and axes of every body in one batched eigh; bodies often share axes, and a shape.
    moments, axes = np.linalg.eigh(np.array([b.inertia for b in builder.bodies], dtype=np.float64).reshape(-1, 3, 3))
    axes[np.linalg.det(axes) < 0.0, :, 0] *= -1.0  # a proper rotation
    principal: dict[bytes, str] = {}
    geometry: dict[tuple[Shape, str | None], str] = {}
    for i, (b, path) in enumerate(zip(builder.bodies, scene.body_paths)):
        name = path.rsplit("/", 1)[1]
        schemas = '"PhysicsRigidBodyAPI"' + ("" if b.static else ', "PhysicsMassAPI"')
        schemas += ', "PhysicsFilteredPairsAPI"' if i in filters else ""
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
        if i in filters:
            targets = ", ".join(f"<{scene.body_paths[j]}>" for j in filters[i])
            lines.append(f"rel physics:filteredPairs = [{targets}]")
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
        own = visuals.get(i, [])
        for k, v in enumerate(own):
            out.append(_visual_usda(v, f"visual{k}", "        ", looks[_rgba(v.rgba)]))
        if not own or b.shape is not None:  # visuals replace the inertia sphere; a shape of its own stays
            shape = _body_display_shape(b)
            material = materials[(b.friction, b.restitution)] if b.shape is not None and b.shape.collide else None
            key = (shape, material, bool(own))
            if key not in geometry:
                look = looks.get(_rgba(shape.color)) if b.shape is not None else None
                geometry[key] = _geometry_usda("geom", shape, "        ", material, look, guide=bool(own))
            out.append(geometry[key])
        out.append("    }\n")
    if visuals.get(WORLD):
        out.append('    def Xform "Visuals"\n    {\n')
        for k, v in enumerate(visuals[WORLD]):
            out.append(_visual_usda(v, f"visual{k}", "        ", looks[_rgba(v.rgba)]))
        out.append("    }\n")
    if builder.joints or builder.distances:
        loops = _loop_joints(builder)
        out.append('    def Scope "Joints"\n    {\n')
        bodies = builder.bodies
        mechanisms, targets = _joint_mechanisms(builder)
        chains = {c[0]: c for c in builder.chains}
        for dist, dpath in zip(builder.distances, scene.distance_paths):
            lines = [f"rel physics:body{side} = <{scene.body_paths[bi]}>"
                     for side, bi in ((0, dist.body0), (1, dist.body1)) if bi != WORLD]  # fmt: skip
            lines += [
                f"point3f physics:localPos{side} = {_tup(a)}" for side, a in enumerate((dist.anchor0, dist.anchor1))
            ]
            lines.append(f"float physics:minDistance = {_f(dist.lower)}")
            if math.isfinite(dist.upper):
                lines.append(f"float physics:maxDistance = {_f(dist.upper)}")
            out.append(f'        def PhysicsDistanceJoint "{dpath.rsplit("/", 1)[1]}"\n        {{\n')
            out.append("".join(f"            {line}\n" for line in lines) + "        }\n")
        for k, (j, jpath) in enumerate(zip(builder.joints, scene.joint_paths)):
            f0, f1, type_name, locked, axis = _joint_frames(j)
            drive_schema, drive_lines = mechanisms.get(k, ([], []))
            schemas = ", ".join([*(f'"PhysicsLimitAPI:{d}"' for d in locked), *drive_schema])
            meta = f" (\n            prepend apiSchemas = [{schemas}]\n        )" if schemas else ""
            out.append(f'        def {type_name} "{jpath.rsplit("/", 1)[1]}"{meta}\n        {{\n')
            lines = []
            for side, bi, fr in ((0, j.parent, f0), (1, j.child, f1)):
                wq = quat_from_matrix(fr)
                if bi == WORLD:
                    lp, lq = j.anchor, wq
                else:
                    body = bodies[bi]
                    lp = quat_rotate(quat_conj(body.orientation), j.anchor - body.position)
                    lq = quat_mul(quat_conj(body.orientation), wq)
                    lines.append(f"rel physics:body{side} = <{scene.body_paths[bi]}>")
                lines.append(f"point3f physics:localPos{side} = {_tup(lp)}")
                lines.append(f"quatf physics:localRot{side} = {_quat_text(lq)}")
            if axis:
                lines.append(f'uniform token physics:axis = "{axis}"')
            if k in loops:
                lines.append("bool physics:excludeFromArticulation = 1")
            if k in chains:  # joints in series through light bodies (`SceneBuilder.chain_joints`); USD has none
                listed = ", ".join(f"<{scene.joint_paths[c]}>" for c in chains[k])
                lines.append(f"custom rel warpimpulse:chain = [{listed}]")
            for dof in locked:
                lines += [f"float limit:{dof}:physics:low = 1", f"float limit:{dof}:physics:high = -1"]
            lines += drive_lines
            out.append("".join(f"            {line}\n" for line in lines))
            out.append("        }\n")
        out.append("    }\n")
        if builder.actuators:
            out.append(_actuators_usda(scene, targets))
    out.append("}\n")
    return "".join(out)


class AnimationWriter:
    """Streams simulated frames into a USD layer and writes it atomically on `close()`.

    `scene`: a `UsdScene` from `load_stage` (layered output: sublayers the input, `over`s on the body prims;
    `flatten=True` for one self-contained file), or a SceneBuilder / Model / procedural UsdScene (the
    output holds geometry and UsdPhysics schemas and reads back with `load_stage`). `instancer`: True
    writes one PointInstancer (float positions, half orientations; display only), None picks it above
    `INSTANCER_AUTO_BODIES` bodies for procedural scenes. Frames go into the Sdf layer in bounded chunks
    (`CHUNK_BYTES`); as a context manager, an exception or Ctrl-C still writes the frames done so far to a
    valid file.

    Time: frame f (t = f / fps s) is time code start + f * rate / fps. A layered output keeps the input's
    rate (timeCodesPerSecond) and starts at its startTimeCode, so that a time code means the same instant
    in the output and in the input's layer stack; a procedural one has rate = fps and starts at 0.
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
        Gf, Sdf, _, _, _, _, Vt = pxr()
        self._Sdf, self._Vt = Sdf, Vt
        self.path = os.path.abspath(os.fspath(path))
        self.scene = as_scene(scene)
        self.fps = float(fps)
        if not (self.fps > 0.0 and math.isfinite(self.fps)):
            raise ValueError(f"fps must be positive, got {fps}")
        self.flatten = bool(flatten)
        layered = self.scene.source_path is not None
        if layered and same_file(self.path, self.scene.source_path):
            raise ValueError(
                f"{self.path}: is the input scene {self.scene.source_path}; the output would replace it (choose "
                "another output file)"
            )
        n = self.scene.body_count
        if instancer is None:
            instancer = not layered and n > INSTANCER_AUTO_BODIES
        if instancer and layered:
            raise ValueError("the PointInstancer mode is for procedural scenes; a scene read from USD is "
                             "written as overs on its own body prims")  # fmt: skip
        self.instancer = bool(instancer)
        self.settings = dict(settings or {})
        self.time_codes_per_second = self.fps
        self.start_time_code = 0.0
        if layered:
            self.time_codes_per_second = self.scene.time_codes_per_second or self.fps
            self.start_time_code = self.scene.time_range[0] if self.scene.time_range else 0.0
        self.frames_written = 0
        self.first_time: float | None = None
        self.last_time: float | None = None
        self.stopped_early: str | None = None
        self._closed = False
        self.saved = False  # True once close() has written the file
        self._ext = os.path.splitext(self.path)[1].lower() or ".usd"
        if self._ext not in (".usd", ".usda", ".usdc"):
            raise ValueError(f"{self.path}: output must end in .usd, .usda or .usdc")
        self.layer = Sdf.Layer.CreateAnonymous("warpimpulse" + self._ext)
        self._h = _Sdf()
        self._build()
        if not self.instancer:
            m = len(self._moving)
            # frames buffered before they are authored; 56 bytes: 7 doubles a body
            self.chunk_frames = int(np.clip(CHUNK_BYTES // (56 * max(m, 1)), 1, CHUNK_FRAMES))
            self._buf_t, self._buf_q = np.empty((m, self.chunk_frames, 3)), np.empty((m, self.chunk_frames, 4))
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
                t_op, q_op, s_op = scene.xform_ops[i] if scene.xform_ops else _PLAIN_OPS
                ops = [t_op, q_op]
                ratio = scene.body_scales[i].copy()
                if not scene.reset_xform_stack[i]:
                    ratio /= scene.parent_scale[i]
                    if scene.parent_index[i] >= 0:
                        ratio /= scene.body_scales[scene.parent_index[i], 0]
                if np.abs(ratio - 1.0).max() > 1e-12:
                    h.attr(spec, s_op, T.Double3, h.Gf.Vec3d(*ratio))
                    ops.append(s_op)
                if scene.reset_xform_stack[i]:
                    ops.insert(0, "!resetXformStack!")
                h.attr(spec, "xformOpOrder", T.TokenArray, Vt.TokenArray(ops), uniform=True)
                self._tpaths.append(h.attr(spec, t_op, T.Double3, tv[i]).path)
                self._qpaths.append(h.attr(spec, q_op, T.Quatd, qv[i]).path)

    def _build_instancer(self, x0: np.ndarray, q0: np.ndarray) -> None:
        protos: dict[Shape, int] = {}
        indices = [protos.setdefault(_body_display_shape(b), len(protos)) for b in self.scene.builder.bodies]
        targets = ", ".join(f"<{INSTANCER_PATH}/Prototypes/proto{k}>" for k in range(len(protos)))
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
            self._Sdf.CopySpec(sub, INSTANCER_PATH, self.layer, INSTANCER_PATH)
            inst = self.layer.GetPrimAtPath(INSTANCER_PATH)
            pos = h.attr(inst, "positions", T.Point3fArray, Vt.Vec3fArray.FromNumpy(x0.astype(np.float32)))
            ori = h.attr(inst, "orientations", T.QuathArray, Vt.QuathArray.FromNumpy(q0.astype(np.float16)))
        self._ipos, self._iori = pos.path, ori.path

    def _write_metadata(self) -> None:
        scene, layer = self.scene, self.layer
        root = layer.pseudoRoot
        root.SetInfo("upAxis", scene.up_axis)
        root.SetInfo("metersPerUnit", float(scene.meters_per_unit))
        root.SetInfo("kilogramsPerUnit", float(scene.kilograms_per_unit))
        layer.timeCodesPerSecond = self.time_codes_per_second
        layer.framesPerSecond = self.fps
        if scene.default_prim:
            layer.defaultPrim = scene.default_prim
        self._write_layer_data()

    def _write_layer_data(self) -> None:
        data: dict[str, Any] = {
            "warpimpulse:version": str(__version__),
            MODE_KEY: "instancer" if self.instancer else ("layered" if self.scene.source_path else "procedural"),
            "warpimpulse:fps": self.fps,
            "warpimpulse:framesWritten": int(self.frames_written),
            "warpimpulse:complete": self.stopped_early is None,
        }
        if self.scene.warnings:  # what the reader warned about: colliders ignored, features dropped
            data["warpimpulse:warnings"] = self._Vt.StringArray(self.scene.warnings)
        if self.scene.colliders_ignored:
            data["warpimpulse:collidersIgnored"] = int(self.scene.colliders_ignored)
        if self.stopped_early:
            data["warpimpulse:stoppedEarly"] = self.stopped_early
        if self.scene.source_path:
            data["warpimpulse:source"] = self.scene.source_path
        for k, v in self.settings.items():  # a list holds strings (the fallbacks, `run.record_frames`)
            value = self._Vt.StringArray(v) if isinstance(v, list) else _vt_value(v)
            data[f"warpimpulse:{k}" if ":" not in k else k] = value
        self.layer.customLayerData = data

    # ------------------------------------------------------------------ frames
    def time_code(self, frame: int) -> float:
        """The time code of frame `frame` (t = frame / fps s)."""
        if self.time_codes_per_second == self.fps:
            return self.start_time_code + frame  # exact
        return self.start_time_code + frame * self.time_codes_per_second / self.fps

    def write_frame(self, frame: int, positions, orientations) -> None:
        """Add frame `frame`, the state at t = frame / fps s (time code `time_code(frame)`): centres of mass
        (N, 3) in metres, orientations (N, 4) xyzw."""
        if self._closed:
            raise RuntimeError("write_frame after close()")
        n = self.scene.body_count
        x = np.asarray(positions, dtype=np.float64)
        q = np.asarray(orientations, dtype=np.float64)
        if x.shape != (n, 3) or q.shape != (n, 4):
            raise ValueError(f"expected positions ({n}, 3) and orientations ({n}, 4), got {x.shape}, {q.shape}")
        tc = float(self.time_code(frame))
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
        self.first_time = tc if self.first_time is None else min(self.first_time, tc)
        self.last_time = tc if self.last_time is None else max(self.last_time, tc)

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
    def discard(self) -> None:
        """Drop the frames and write nothing (an output path that was only being tried)."""
        self._closed = True

    def close(self, stopped_early: str | None = None) -> str:
        """Write the file (`files.write_atomically`: a temporary file renamed over the target, through a
        symbolic link, straight into a device) and set `saved`. Returns the path. Idempotent. Raises
        WriteError (the previous file unchanged) when the file system refuses it: disk full, a size limit."""
        if self._closed:
            return self.path
        self._closed = True
        if stopped_early:
            self.stopped_early = stopped_early
        # From here to the rename, a Ctrl-C (or SIGTERM) would lose every frame: it waits for the file.
        with interrupts_deferred(f"saving {self.path}"):
            self._save()
        return self.path

    def _save(self) -> None:
        if not self.instancer:
            self._flush()
        layer = self.layer
        layer.startTimeCode = float(self.first_time if self.first_time is not None else self.start_time_code)
        layer.endTimeCode = float(self.last_time if self.last_time is not None else self.start_time_code)
        self._write_layer_data()

        def export(tmp: str) -> bool:
            out = layer
            if self.flatten and self.scene.source_path is not None:
                _, _, _, Usd, *_ = pxr()
                out = Usd.Stage.Open(layer).Flatten()
                for key in ("startTimeCode", "endTimeCode", "timeCodesPerSecond", "framesPerSecond"):
                    out.pseudoRoot.SetInfo(key, layer.pseudoRoot.GetInfo(key))
                out.customLayerData = layer.customLayerData
            return out.Export(tmp)

        os.makedirs(os.path.dirname(os.path.realpath(self.path)), exist_ok=True)
        write_atomically(self.path, export, self._ext, _file_mode(self.path))
        self.saved = True

    def __enter__(self) -> AnimationWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.close()
        else:
            # The caller reports the stop; the file records it in customLayerData (warpimpulse:stoppedEarly).
            if issubclass(exc_type, KeyboardInterrupt):  # Ctrl-C, or SIGTERM / SIGHUP under files.signals_interrupt
                reason = f"interrupted ({exc.name if isinstance(exc, Interrupted) else 'SIGINT'})"
            else:
                reason = f"{exc_type.__name__}: {exc}"
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
    sc = as_scene(scene)
    if sc.source_path is not None:
        sc = scene_from_builder(sc.builder)
    return AnimationWriter(path, sc, fps, {} if dt is None else {"dt": float(dt)}, instancer=False).close()
