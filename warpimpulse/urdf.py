"""URDF in: `load_urdf(path)` -> a `SceneBuilder` (our own small parser on xml.etree; no ROS, no MuJoCo).

MuJoCo's compiler reads URDF too, but not the Collada meshes that much of example-robot-data draws with, and it
needs every mesh to compile; this reader needs none of them for the motion (a URDF gives each link's mass
properties) and reads meshes only for display (`meshes.py`).

The mapping (URDF spec: wiki.ros.org/urdf/XML):
- link <inertial>: mass, centre of mass (origin xyz) and the inertia tensor in the origin's rotated frame ->
  a body at its centre of mass, its frame the link's frame (the tensor rotated into it: `add_body` takes a
  full tensor, so no principal axes are needed);
- fixed joints merge the child link into its parent: one body whose mass, centre of mass and inertia are the
  links' composed (parallel axis theorem). That is exact and leaves no weld to hold (a fixed joint would be
  six rows of the system and an error of up to the tolerance); a robot's tool frames, sensors and covers are
  most of its fixed joints (example-robot-data: 846 fixed joints against 1214 moving ones);
- a link without mass (no <inertial>, or mass 0) is merged like any link; a body left with no mass is dropped
  with a warning when nothing moves beyond it (a frame on a joint), and refused naming the link when bodies
  hang beyond it (no exact joint holds a body of no mass between two joints);
- revolute / continuous -> a revolute joint, prismatic -> prismatic, planar -> planar (the axis is the plane's
  normal), floating -> no joint (a free body); the joint sits at the child link's origin, the axis in its
  frame;
- <limit lower upper> -> a joint limit; effort and velocity bound actuators, which a URDF does not declare (its
  <transmission>s are not read): one line says they are not applied;
- <dynamics damping> -> a joint damper (`add_joint_spring` with stiffness 0; where it is stiff for the step,
  the simulator takes it implicitly, `Simulator.implicit_dampers`); friction (dry friction in the joint, not
  modelled) -> a warning naming the joints;
- <mimic> -> refused naming the joint (the coupling is not modelled), or with `ignore_unsupported` the joint
  stays independent, with a warning;
- the root link is fixed to the world by default (merged into it: the world's bodies do not move), free
  with `floating=True` or when the URDF joins it to a massless root ("world") by a floating joint;
- collision box / sphere / cylinder / capsule -> the body's collision shape when it is the body's only one and
  centred on its centre of mass (our shapes are centred there); off-centre or extra primitives -> pieces of the
  link's mass welded to it, each with its shape (the whole's mass properties exact); mesh collisions -> one
  warning naming the links; the robot's links do not collide with each other unless `self_collisions`;
- <visual> box / sphere / cylinder / mesh with the material's colour (a Collada mesh without one: the file's
  own) -> `SceneBuilder.visuals` (display only);
  meshes resolved from package://PKG/... (an ancestor folder named PKG, one holding PKG, `package_dirs`,
  ROS_PACKAGE_PATH), file:// and relative paths, read by `meshes.read_mesh`; one that cannot be read is drawn by
  the link's primitive collision geometry, with a warning naming the file.

The robot is built at `configuration` (URDF joint values; default: each joint at 0, or at the nearest end of its
limits when 0 is outside them): that pose is coordinate 0 of every joint (`Simulator.joint_coordinates`), so a
URDF joint value is configuration[joint] + the simulator's coordinate.
"""

from __future__ import annotations

import math
import os
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from .builder import WORLD, SceneBuilder, SceneError
from .meshes import MeshError, read_mesh
from .shapes import Shape, collision_pieces, parallel_axis
from .transforms import quat_from_matrix

__all__ = ["UrdfError", "example_robots", "load_urdf"]

MOVING = ("revolute", "continuous", "prismatic", "planar")
JOINT_KINDS = (*MOVING, "fixed", "floating")
PRIMITIVES = ("box", "sphere", "cylinder", "capsule")
_CENTRED = 1e-9  # m: a collision primitive this close to the centre of mass is taken as centred on it


class UrdfError(SceneError):
    """A URDF that cannot be loaded as it is; the message names the file and the element at fault."""


@dataclass
class _Geometry:
    """A <visual> or <collision>: kind ("box", ..., "mesh"), size (box edges; radius; radius and length),
    pose in its link's frame (4x4), colour, the mesh file (resolved) and scale."""

    kind: str
    size: tuple[float, float, float]
    pose: np.ndarray
    rgba: tuple[float, float, float, float] | None = None
    mesh: str | None = None
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    name: str = ""


@dataclass
class _Link:
    name: str
    mass: float = 0.0
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))  # link frame (m)
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # about the COM, link frame (kg m^2)
    visuals: list[_Geometry] = field(default_factory=list)
    collisions: list[_Geometry] = field(default_factory=list)


@dataclass
class _Joint:
    name: str
    kind: str
    parent: str
    child: str
    origin: np.ndarray  # child link frame in the parent link's frame at joint value 0 (4x4)
    axis: np.ndarray  # unit, in the child link's (joint) frame
    lower: float = -math.inf
    upper: float = math.inf
    limited: bool = False
    effort: float | None = None
    velocity: float | None = None
    damping: float = 0.0
    friction: float = 0.0
    mimic: str | None = None


class _Report:
    """Unsupported elements (an error, or a warning under ignore_unsupported) and notes (warnings), each one
    line naming the file and the element."""

    def __init__(self, path: str, ignore: bool) -> None:
        self.path, self.ignore = path, ignore

    def error(self, what: str) -> UrdfError:
        return UrdfError(f"{self.path}: {what}")

    def unsupported(self, what: str) -> None:
        if not self.ignore:
            raise UrdfError(f"{self.path}: {what} (ignore_unsupported=True / --ignore-unsupported drops it)")
        self.note(f"{what}; ignored")

    def note(self, what: str) -> None:
        warnings.warn(f"{self.path}: {what}", stacklevel=4)


def _names(items: list[str], limit: int = 6) -> str:
    """'a', 'b', 'c' (and 4 more)."""
    shown = ", ".join(repr(n) for n in items[:limit])
    return shown + (f" (and {len(items) - limit} more)" if len(items) > limit else "")


def _floats(text: str | None, count: int, what: str, report: _Report, default=None) -> np.ndarray:
    if text is None:
        if default is None:
            raise report.error(f"{what} is missing")
        return np.array(default, dtype=np.float64)
    try:
        values = np.array([float(x) for x in text.split()], dtype=np.float64)
    except ValueError:
        raise report.error(f"{what} = {text!r} is not {count} numbers") from None
    if len(values) != count or not np.isfinite(values).all():
        raise report.error(f"{what} = {text!r} is not {count} finite numbers")
    return values


def _number(element: ET.Element | None, attr: str, what: str, report: _Report, default: float | None = None) -> float:
    text = None if element is None else element.get(attr)
    return float(_floats(text, 1, f"{what} {attr}", report, None if default is None else [default])[0])


def _rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF's fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])  # fmt: skip


def _origin(element: ET.Element, what: str, report: _Report) -> np.ndarray:
    """The 4x4 pose of an element's <origin xyz rpy> (identity when absent)."""
    o = element.find("origin")
    pose = np.eye(4)
    if o is not None:
        pose[:3, 3] = _floats(o.get("xyz"), 3, f"{what} origin xyz", report, [0.0, 0.0, 0.0])
        pose[:3, :3] = _rpy_matrix(_floats(o.get("rpy"), 3, f"{what} origin rpy", report, [0.0, 0.0, 0.0]))
    return pose


def _axis_motion(joint: _Joint, q: float) -> np.ndarray:
    """The child frame's motion in the joint frame at joint value q (rad about, or m along, the axis)."""
    m = np.eye(4)
    if joint.kind in ("revolute", "continuous"):
        x, y, z = joint.axis
        c, s = math.cos(q), math.sin(q)
        k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        m[:3, :3] = np.eye(3) + s * k + (1.0 - c) * (k @ k)
    elif joint.kind == "prismatic":
        m[:3, 3] = q * joint.axis
    return m


class _Parser:
    """One URDF file: its materials, links and joints, mesh paths resolved."""

    def __init__(self, path: str, report: _Report, package_dirs: list[str]) -> None:
        self.path, self.report, self.package_dirs = path, report, package_dirs
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError as exc:
            raise report.error(f"not well-formed XML ({exc})") from None
        except OSError as exc:
            raise UrdfError(f"{path}: cannot be read ({exc.strerror or exc})") from None
        if root.tag != "robot":
            raise report.error(f"the root element is <{root.tag}>, not <robot>")
        self.name = root.get("name", os.path.splitext(os.path.basename(path))[0])
        self.materials = {m.get("name"): self._color(m) for m in root.findall("material")}
        self.textures: list[str] = []
        self.links: dict[str, _Link] = {}
        self.joints: list[_Joint] = []
        ignored: dict[str, int] = {}
        for element in root:
            if not isinstance(element.tag, str):
                continue  # a comment or processing instruction
            if element.tag == "link":
                link = self._link(element)
                if link.name in self.links:
                    raise report.error(f"link {link.name!r} is defined twice")
                self.links[link.name] = link
            elif element.tag == "joint":
                self.joints.append(self._joint(element))
            elif element.tag != "material":
                ignored[element.tag] = ignored.get(element.tag, 0) + 1
        if ignored:  # simulator plugins (<gazebo>), actuator transmissions, ros2_control blocks, sensors
            listed = ", ".join(f"<{tag}> ({n})" for tag, n in ignored.items())
            report.note(f"{listed} not read: warpimpulse takes the links and joints (and materials) of a URDF")
        if self.textures:
            report.note(f"textures {_names(self.textures)} not drawn: visuals take their material's colour only")

    def _color(self, material: ET.Element | None) -> tuple[float, float, float, float] | None:
        if material is None:
            return None
        texture = material.find("texture")
        if texture is not None and texture.get("filename"):
            self.textures.append(texture.get("filename"))
        color = material.find("color")
        if color is None:
            return None
        rgba = _floats(color.get("rgba"), 4, f"material {material.get('name')!r} color rgba", self.report)
        return tuple(float(x) for x in np.clip(rgba, 0.0, 1.0))

    def _link(self, element: ET.Element) -> _Link:
        name = element.get("name")
        if not name:
            raise self.report.error("a <link> has no name")
        what = f"link {name!r}"
        link = _Link(name)
        inertial = element.find("inertial")
        if inertial is not None:
            link.mass = _number(inertial.find("mass"), "value", f"{what} inertial mass", self.report, 0.0)
            if link.mass < 0.0:
                raise self.report.error(f"{what}: mass {link.mass} is negative")
            pose = _origin(inertial, f"{what} inertial", self.report)
            link.com = pose[:3, 3]
            t = inertial.find("inertia")
            keys = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
            c = {k: _number(t, k, f"{what} inertia", self.report, 0.0) for k in keys}
            tensor = np.array([[c["ixx"], c["ixy"], c["ixz"]], [c["ixy"], c["iyy"], c["iyz"]],
                               [c["ixz"], c["iyz"], c["izz"]]])  # fmt: skip
            link.inertia = pose[:3, :3] @ tensor @ pose[:3, :3].T
        for kind in ("visual", "collision"):
            for k, g in enumerate(element.findall(kind)):
                geometry = self._geometry(g, f"{what} {kind} {k}")
                if geometry is not None:
                    (link.visuals if kind == "visual" else link.collisions).append(geometry)
        return link

    def _geometry(self, element: ET.Element, what: str) -> _Geometry | None:
        g = element.find("geometry")
        shapes = [] if g is None else [s for s in g if isinstance(s.tag, str)]
        if not shapes:
            raise self.report.error(f"{what}: no <geometry>")
        s = shapes[0]
        pose = _origin(element, what, self.report)
        material = element.find("material")
        rgba = self._color(material)
        if rgba is None and material is not None:
            rgba = self.materials.get(material.get("name"))
        name = element.get("name") or ""
        if s.tag == "box":
            size = tuple(_floats(s.get("size"), 3, f"{what} box size", self.report).tolist())
        elif s.tag == "sphere":
            size = (_number(s, "radius", f"{what} sphere", self.report), 0.0, 0.0)
        elif s.tag in ("cylinder", "capsule"):
            size = (_number(s, "radius", f"{what} {s.tag}", self.report),
                    _number(s, "length", f"{what} {s.tag}", self.report), 0.0)  # fmt: skip
        elif s.tag == "mesh":
            filename = s.get("filename")
            if not filename:
                raise self.report.error(f"{what}: <mesh> has no filename")
            scale = tuple(_floats(s.get("scale"), 3, f"{what} mesh scale", self.report, [1.0, 1.0, 1.0]).tolist())
            return _Geometry("mesh", scale, pose, rgba, self._resolve(filename), scale, name)
        else:
            self.report.unsupported(f"{what}: geometry <{s.tag}>")
            return None
        if min(size[: {"box": 3, "sphere": 1}.get(s.tag, 2)]) < 0.0:
            raise self.report.error(f"{what}: {s.tag} has a negative size {size}")
        return _Geometry(s.tag, size, pose, rgba, name=name)

    def _resolve(self, filename: str) -> str:
        """A mesh's path on disk (not checked to exist: a missing file is said when it is read)."""
        if filename.startswith("file://"):
            return filename[len("file://") :]
        if not filename.startswith("package://"):
            return os.path.normpath(os.path.join(os.path.dirname(self.path), filename))
        rest = filename[len("package://") :].lstrip("/")
        package, _, inner = rest.partition("/")
        roots = list(self.package_dirs) + [p for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
        folder = os.path.dirname(os.path.abspath(self.path))
        while True:
            roots.append(folder)
            up = os.path.dirname(folder)
            if up == folder:
                break
            folder = up
        for root in roots:
            for candidate in (os.path.join(root, inner) if os.path.basename(root) == package else None,
                              os.path.join(root, package, inner)):  # fmt: skip
                if candidate and os.path.exists(candidate):
                    return candidate
        return filename  # unresolved: said when it is read

    def _joint(self, element: ET.Element) -> _Joint:
        name = element.get("name")
        if not name:
            raise self.report.error("a <joint> has no name")
        what = f"joint {name!r}"
        kind = element.get("type")
        if kind not in JOINT_KINDS:
            raise self.report.error(f"{what}: type {kind!r} is not a URDF joint type {JOINT_KINDS}")
        ends = []
        for side in ("parent", "child"):
            e = element.find(side)
            if e is None or not e.get("link"):
                raise self.report.error(f"{what}: no <{side} link=...>")
            ends.append(e.get("link"))
        axis = _floats((element.find("axis") if element.find("axis") is not None else element).get("xyz")
                       if element.find("axis") is not None else None, 3, f"{what} axis xyz", self.report,
                       [1.0, 0.0, 0.0])  # fmt: skip
        norm = float(np.linalg.norm(axis))
        if kind in MOVING and norm < 1e-12:
            raise self.report.error(f"{what}: axis is a zero vector")
        joint = _Joint(name, kind, ends[0], ends[1], _origin(element, what, self.report), axis / max(norm, 1e-300))
        limit = element.find("limit")
        if limit is not None:
            if kind in ("revolute", "prismatic"):
                joint.lower = _number(limit, "lower", f"{what} limit", self.report, 0.0)
                joint.upper = _number(limit, "upper", f"{what} limit", self.report, 0.0)
                joint.limited = True
                if joint.lower > joint.upper:
                    raise self.report.error(f"{what}: limit lower {joint.lower} > upper {joint.upper}")
            joint.effort = _number(limit, "effort", f"{what} limit", self.report, 0.0) if limit.get("effort") else None
            joint.velocity = (_number(limit, "velocity", f"{what} limit", self.report, 0.0)
                              if limit.get("velocity") else None)  # fmt: skip
        elif kind in ("revolute", "prismatic"):
            raise self.report.error(f"{what}: a {kind} joint needs a <limit> (URDF spec)")
        dynamics = element.find("dynamics")
        if dynamics is not None:
            joint.damping = _number(dynamics, "damping", f"{what} dynamics", self.report, 0.0)
            joint.friction = _number(dynamics, "friction", f"{what} dynamics", self.report, 0.0)
            if joint.damping < 0.0 or joint.friction < 0.0:
                raise self.report.error(f"{what}: dynamics damping and friction must be >= 0")
        mimic = element.find("mimic")
        if mimic is not None:
            joint.mimic = mimic.get("joint") or "?"
        return joint


def load_urdf(
    path: str | os.PathLike,
    ignore_unsupported: bool = False,
    floating: bool | None = None,
    configuration: dict[str, float] | None = None,
    collisions: bool = True,
    self_collisions: bool = False,
    visuals: bool = True,
    package_dirs: list[str] | None = None,
    gravity=(0.0, 0.0, -9.81),
) -> SceneBuilder:
    """A URDF robot as a `SceneBuilder` (bodies named after their links, joints after the URDF's joints).

    Args:
        path: the .urdf file.
        ignore_unsupported: drop what is not simulated (<mimic> couplings, unknown geometry) with a warning
            naming it, instead of a `UrdfError` naming it.
        floating: True: the root link is a free body (a floating base); False: fixed to the world (a floating
            joint from a massless root link is then taken as fixed); None: fixed unless the URDF joins its root
            to a massless root link ("world") by a floating joint.
        configuration: URDF joint values (rad, m) to build the robot at, by joint name; each other joint at 0,
            or at the nearest end of its limits when 0 lies outside them. The built pose is coordinate 0 of
            every joint of the builder (limits and dampers are shifted to it).
        collisions: give bodies their collision primitives (False: no collision shapes, no contacts). A body
            carries one shape at its centre of mass, so a primitive off it (a foot at the end of a shank) or a
            link's second one is a piece of the link's mass welded to it (`shapes.collision_pieces`: the link's
            mass, centre and inertia unchanged).
        self_collisions: the robot's links collide with each other (but for jointed ones, as MuJoCo's
            filterparent); off by default, as in Gazebo and PyBullet: a URDF's collision geometry of neighbouring
            links often overlaps, which pushes the links apart at the first step.
        visuals: keep the visual geometry on `builder.visuals`, reading the meshes (False: none, no mesh read).
        package_dirs: folders to look for package://NAME/... in (NAME itself, or a folder holding NAME), before
            ROS_PACKAGE_PATH and the URDF's own ancestors.
        gravity: the builder's gravity (m/s^2, world frame; the URDF's base frame is the world's).
    """
    path = os.fspath(path)
    report = _Report(path, ignore_unsupported)
    urdf = _Parser(path, report, list(package_dirs or []))
    try:
        return _build(urdf, report, floating, dict(configuration or {}), collisions, self_collisions, visuals, gravity)
    except UrdfError:
        raise
    except SceneError as err:  # the builder's check of a link's values (an inertia that no body has)
        raise UrdfError(f"{path}: {err}") from None


def _build(
    urdf: _Parser, report: _Report, floating, configuration, collisions, self_collisions, visuals, gravity
) -> SceneBuilder:
    """The builder of a parsed URDF (`load_urdf`'s arguments)."""
    links, joints = urdf.links, urdf.joints
    if not links:
        raise report.error("the robot has no <link>")
    parent_joint: dict[str, _Joint] = {}
    names = set()
    for j in joints:
        if j.name in names:
            raise report.error(f"joint {j.name!r} is defined twice")
        names.add(j.name)
        for end in (j.parent, j.child):
            if end not in links:
                raise report.error(f"joint {j.name!r}: link {end!r} is not defined")
        if j.child in parent_joint:
            raise report.error(f"link {j.child!r} is the child of two joints, {parent_joint[j.child].name!r} and "
                               f"{j.name!r} (a URDF is a tree)")  # fmt: skip
        parent_joint[j.child] = j
    roots = [n for n in links if n not in parent_joint]
    if len(roots) != 1:
        raise report.error(f"a URDF has one root link; found {len(roots)}: {_names(roots)}"
                           + (" (the joints make a loop)" if not roots else ""))  # fmt: skip
    root = roots[0]
    children: dict[str, list[_Joint]] = {n: [] for n in links}
    for j in joints:
        children[j.parent].append(j)
    order = [root]  # links, parents first
    for name in order:
        order.extend(j.child for j in children[name])
    if len(order) != len(links):
        raise report.error(f"links {_names([n for n in links if n not in set(order)])} are not connected to the root")

    mimics = [j for j in joints if j.mimic is not None]
    if mimics:
        report.unsupported(f"<mimic> of joints {_names([j.name for j in mimics])} (a coupling to another joint is not "
                           "modelled; each moves on its own)")  # fmt: skip
    unknown = sorted(set(configuration) - {j.name for j in joints if j.kind in MOVING})
    if unknown:
        raise report.error(f"configuration names {_names(unknown)}, which are not revolute, continuous or prismatic "
                           "joints of the robot")  # fmt: skip
    q0 = {}
    for j in joints:
        if j.kind in ("revolute", "continuous", "prismatic"):
            q = float(configuration.get(j.name, min(max(0.0, j.lower), j.upper)))
            if j.limited and not j.lower <= q <= j.upper:
                raise report.error(f"configuration: joint {j.name!r} = {q} is outside its limits "
                                   f"[{j.lower}, {j.upper}]")  # fmt: skip
            q0[j.name] = q

    # World poses of the links at the built configuration.
    pose = {root: np.eye(4)}
    for name in order[1:]:
        j = parent_joint[name]
        pose[name] = pose[j.parent] @ j.origin @ _axis_motion(j, q0.get(j.name, 0.0))

    # Groups: fixed joints merge a child into its parent's group; the root's group is the world unless floating.
    in_world = floating is not True
    group = {root: root}
    for name in order[1:]:
        j = parent_joint[name]
        as_fixed = j.kind == "floating" and j.parent == root and floating is False
        if as_fixed:
            report.note(f"joint {j.name!r}: floating joint taken as fixed (floating=False)")
        group[name] = group[j.parent] if j.kind == "fixed" or as_fixed else name
    members: dict[str, list[str]] = {}
    for name in order:
        members.setdefault(group[name], []).append(name)
    group_mass = {g: sum(links[n].mass for n in ms) for g, ms in members.items()}

    # Massless groups: dropped when nothing with mass moves beyond them (or, for a free robot's root, when only
    # free bodies hang from it), refused otherwise.
    child_groups: dict[str, list[str]] = {g: [] for g in members}
    for g in members:
        if g != root:
            child_groups[group[parent_joint[g].parent]].append(g)
    kept: dict[str, bool] = {}
    bridged: set[str] = set()  # massless links between hinges through one point: their hinges compose
    for g in reversed(list(members)):
        beyond = any(kept[c] or c in bridged for c in child_groups[g])
        if (g == root and in_world) or group_mass[g] > 0.0:
            kept[g] = True
        elif not beyond or (g == root and all(parent_joint[c].kind == "floating" for c in child_groups[g])):
            kept[g] = False
        elif g != root and _hinge_bridge(g, parent_joint[g], child_groups[g], parent_joint, pose):
            kept[g] = False
            bridged.add(g)
        else:
            what = f"link {g!r}" + (f" (with {_names(members[g][1:])} fixed to it)" if len(members[g]) > 1 else "")
            via = f"on joint {parent_joint[g].name!r}" if g != root else "as the free root"
            raise report.error(f"{what} has no mass {via}, and bodies move beyond it: give it an <inertial> (a body "
                               "of no mass between two joints has no exact motion)")  # fmt: skip
    dropped = [g for g, k in kept.items() if not k and g not in bridged]
    if dropped:
        report.note(f"links {_names(dropped)} have no mass and nothing with mass fixed to them: not simulated "
                    "(frames)")  # fmt: skip

    builder = SceneBuilder(gravity)
    body_of: dict[str, int] = {}
    shape_notes: dict[str, list[str]] = {"mesh": [], "spare": []}
    welds = []  # (body, collision piece, anchor, name)
    for g in [n for n in order if group[n] == n]:
        if not kept[g]:
            continue
        if g == root and in_world:
            body_of[g] = WORLD
            continue
        frame = pose[g]
        rot = frame[:3, :3]
        mass = group_mass[g]
        com = sum(links[n].mass * (pose[n][:3, :3] @ links[n].com + pose[n][:3, 3]) for n in members[g]) / mass
        inertia = np.zeros((3, 3))
        for n in members[g]:
            r = pose[n][:3, :3]
            c = r @ links[n].com + pose[n][:3, 3]
            inertia += parallel_axis(links[n].mass, r @ links[n].inertia @ r.T, c - com)
        name = next(n for n in members[g] if links[n].mass > 0.0)  # not a massless "world" frame above it
        found = _collision_primitives(members[g], links, pose, shape_notes) if collisions else []
        shape, orientation, pieces = None, rot, []
        if len(found) == 1 and np.linalg.norm(found[0][2][:3, 3] - com) <= _CENTRED * max(1.0, np.linalg.norm(com)):
            shape, orientation = found[0][1], found[0][2][:3, :3]  # the body's frame is its shape's
        elif found:  # off the centre of mass (a foot at the end of a shank), or several: pieces welded to the link
            split = collision_pieces(mass, com, inertia, [(sh, w[:3, 3], w[:3, :3]) for _, sh, w in found])
            if split is None:
                shape_notes["spare"].append(name)
            else:
                mass, com, inertia, pieces = split
        body_of[g] = builder.add_body(mass, orientation.T @ inertia @ orientation, com, quat_from_matrix(orientation),
                                      name=name, shape=shape)  # fmt: skip
        for k, ((_, piece_shape, world), (piece_mass, piece_inertia)) in enumerate(zip(found, pieces)):
            r, centre = world[:3, :3], world[:3, 3]
            piece = builder.add_body(piece_mass, r.T @ piece_inertia @ r, centre, quat_from_matrix(r),
                                     name=f"{name}/collision{k}", shape=piece_shape)  # fmt: skip
            welds.append((body_of[g], piece, centre, f"{name}/collision{k}"))  # after the URDF's joints
    if collisions and any(shape_notes.values()):
        parts = []
        if shape_notes["mesh"]:
            parts.append(f"mesh collisions of links {_names(shape_notes['mesh'])} do not collide (warpimpulse "
                         "collides boxes, spheres, capsules and cylinders)")  # fmt: skip
        if shape_notes["spare"]:
            parts.append(f"links {_names(shape_notes['spare'])} have no mass to spare for their collision "
                         "primitives as pieces welded to them: those do not collide")  # fmt: skip
        report.note("; ".join(parts))
    if not len(builder.bodies):
        raise report.error(f"nothing moves: every link is fixed to root link {root!r}, which is fixed to the world "
                           "(floating=True / --floating makes the robot a free body)")  # fmt: skip
    body_of = {name: body_of[group[name]] if kept[group[name]] else None for name in order}  # None: dropped

    # Joints between the kept bodies.
    frictions, actuator_limits, damped_other = [], [], []
    composed = []
    for j in joints:
        if j.kind in ("fixed", "floating") or group[j.child] != j.child or not kept[j.child]:
            continue  # merged, a free child, or a dropped or bridged massless link
        chain = [j]  # the hinges from the last kept body down to this one, through bridged links
        while group[chain[0].parent] in bridged:
            chain.insert(0, parent_joint[group[chain[0].parent]])
        top = chain[0].parent
        parent = None if body_of[top] == WORLD else body_of[top]
        child = body_of[j.child]
        anchor, axis = pose[j.child][:3, 3], pose[j.child][:3, :3] @ j.axis
        if len(chain) > 1:
            axes = [pose[c.child][:3, :3] @ c.axis for c in chain]
            if len(chain) == 2:
                builder.add_joint_universal(parent, child, anchor, axes[0], axes[1], name=j.name)
            else:
                builder.add_joint_ball(parent, child, anchor, name=j.name)
            kind = "universal" if len(chain) == 2 else "ball"
            lost = [c.name for c in chain if c.limited or c.damping > 0.0]
            composed.append(f"{kind} {j.name!r} from {_names([c.name for c in chain])}"
                            + (f" (limits and dampers of {_names(lost)} not applied)" if lost else ""))  # fmt: skip
            frictions += [c.name for c in chain if c.friction > 0.0]
            actuator_limits += [c.name for c in chain if c.effort is not None or c.velocity is not None]
            continue
        if j.kind in ("revolute", "continuous"):
            k = builder.add_joint_revolute(parent, child, anchor, axis, name=j.name)
        elif j.kind == "prismatic":
            k = builder.add_joint_prismatic(parent, child, anchor, axis, name=j.name)
        else:
            k = builder.add_joint_planar(parent, child, anchor, axis, name=j.name)
        if j.limited:
            q = q0[j.name]
            builder.add_joint_limit(k, j.lower - q, j.upper - q)
        if j.damping > 0.0:
            if j.kind == "planar":
                damped_other.append(j.name)
            else:
                builder.add_joint_spring(k, 0.0, j.damping)
        if j.friction > 0.0:
            frictions.append(j.name)
        if j.effort is not None or j.velocity is not None:
            actuator_limits.append(j.name)
    _weld_pieces(builder, welds, self_collisions)
    if frictions:
        report.note(f"joints {_names(frictions)}: <dynamics friction> (dry friction in the joint) is not modelled")
    if composed:
        report.note(f"hinges through one point with massless links between them composed: {'; '.join(composed)}")
    if damped_other:
        report.note(f"joints {_names(damped_other)}: <dynamics damping> of a planar joint is not modelled")
    if actuator_limits:
        report.note(f"joints {_names(actuator_limits)}: <limit effort/velocity> bound actuators, which a URDF does not "
                    "declare (no <transmission> is read): not applied")  # fmt: skip
    if visuals:
        _add_visuals(builder, urdf, order, body_of, pose, report)
    return builder


def _hinge_bridge(g: str, above: _Joint, below: list[str], parent_joint: dict, pose: dict) -> bool:
    """Whether massless link `g` only relays a rotation: it turns on a hinge (`above`), and one hinge turns its
    one child group about the same point (within `_CENTRED`): the serial hinges are then one joint of the
    bodies either side (2: universal, its axes' angle kept; 3 or more: ball), exact with nothing between."""
    hinges = ("revolute", "continuous")
    if above.kind not in hinges or len(below) != 1 or parent_joint[below[0]].kind not in hinges:
        return False
    gap = np.linalg.norm(pose[g][:3, 3] - pose[below[0]][:3, 3])
    return bool(gap <= _CENTRED * max(1.0, float(np.linalg.norm(pose[g][:3, 3]))))


def _weld_pieces(builder: SceneBuilder, welds: list, self_collisions: bool) -> None:
    """Weld each collision piece to its link (`welds`: (link body, piece, anchor, name)) and filter the robot's
    collisions: without `self_collisions` no two of its bodies collide (Gazebo's and PyBullet's default for a
    URDF, whose neighbouring links' collision geometry often overlaps); with it, a piece collides with what its
    link collides with, as one MuJoCo body of several geoms does: not with its link's other pieces, nor with the
    links jointed to its link (MuJoCo's filterparent) or their pieces."""
    for body, piece, anchor, name in welds:
        builder.add_joint_fixed(body, piece, anchor, name=name)
    link = {piece: body for body, piece, _, _ in welds}
    jointed = {(link.get(j.parent, j.parent), link.get(j.child, j.child)) for j in builder.joints}
    shaped = [i for i, x in enumerate(builder.bodies) if x.shape is not None and x.shape.collide]
    for k, a in enumerate(shaped):
        for b in shaped[k + 1 :]:
            la, lb = link.get(a, a), link.get(b, b)
            if not self_collisions or la == lb or (la, lb) in jointed or (lb, la) in jointed:
                builder.filter_collision(a, b)


def _collision_primitives(names, links, pose, notes) -> list[tuple[str, Shape, np.ndarray]]:
    """The collision primitives of a group of links: (link, its shape, its world pose 4x4); mesh collisions are
    added to `notes`."""
    found = []
    for n in names:
        for geo in links[n].collisions:
            if geo.kind == "mesh":
                notes["mesh"].append(n)
                continue
            r, length = geo.size[0], geo.size[1]
            if geo.kind == "box":
                shape = Shape("box", size=geo.size)
            elif geo.kind == "sphere":
                shape = Shape("sphere", radius=r)
            else:
                shape = Shape(geo.kind, radius=r, length=length)
            found.append((n, shape, pose[n] @ geo.pose))
    return found


def _add_visuals(builder: SceneBuilder, urdf: _Parser, order, body_of, pose, report: _Report) -> None:
    """Every <visual> of a simulated link onto `builder.visuals`; a mesh that cannot be read is replaced by the
    link's primitive collision geometry (one warning naming the files)."""
    unread: list[str] = []
    for name in order:
        if body_of[name] is None:
            continue  # a dropped massless link (said above)
        body = None if body_of[name] == WORLD else body_of[name]
        link = urdf.links[name]
        for k, geo in enumerate(link.visuals):
            world = pose[name] @ geo.pose
            what = geo.name or f"{name}/visual{k}"
            rgba = geo.rgba or (0.7, 0.7, 0.7, 1.0)
            q = quat_from_matrix(world[:3, :3])
            if geo.kind == "mesh":
                try:
                    mesh = read_mesh(geo.mesh)
                except MeshError as exc:
                    unread.append(str(exc))
                    for c, proxy in enumerate(g for g in link.collisions if g.kind != "mesh"):
                        w = pose[name] @ proxy.pose
                        builder.add_visual(body, proxy.kind, proxy.size, w[:3, 3], quat_from_matrix(w[:3, :3]), rgba,
                                           name=f"{what}/proxy{c}")  # fmt: skip
                    continue
                rgba = geo.rgba or mesh.rgba or rgba  # the URDF's colour, else the file's own
                builder.add_visual(body, "mesh", geo.scale, world[:3, 3], q, rgba, name=what, mesh_path=geo.mesh,
                                   vertices=mesh.vertices, faces=mesh.faces)  # fmt: skip
            else:
                size = geo.size if geo.kind != "sphere" else (geo.size[0], 0.0, 0.0)
                builder.add_visual(body, geo.kind, size, world[:3, 3], q, rgba, name=what)
    if unread:
        report.note(f"{len(unread)} visual meshes not read, drawn by their link's collision primitives (if any): "
                    + "; ".join(unread[:3]) + (f"; and {len(unread) - 3} more" if len(unread) > 3 else ""))  # fmt: skip


def example_robots() -> str | None:
    """The robots folder of example-robot-data (the `[robots]` extra: a cmeel wheel, no Python module; its
    URDFs are at ROBOT_description/{urdf,robots}/NAME.urdf), or None when it is not installed."""
    from importlib import metadata

    try:
        folder = metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data/robots")
    except metadata.PackageNotFoundError:
        return None
    return str(folder) if os.path.isdir(str(folder)) else None
