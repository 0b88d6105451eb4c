"""MJCF in: a MuJoCo model as a `SceneBuilder` (`load_mjcf`).

MuJoCo's own compiler reads the file (defaults, includes, `inertiafromgeom`, meshes' mass properties), and the
compiled `mujoco.MjModel`, not the XML, is mapped onto the builder, posed by a forward pass (`mj_kinematics`)
at the model's `qpos0` or a given `qpos`. Every element is mapped exactly, refused with one line naming it,
or (where no exact equivalent exists but the motion barely depends on it) mapped with a warning naming it:

- bodies: each body with joints is one of ours, with its mass, its inertia tensor about its centre of mass and
  its pose; bodies welded to it (no joints) are merged into it (mass, centre and inertia composed exactly);
  bodies welded to the world are part of the world (their collision geoms become static bodies).
- joints: free -> a free body; hinge -> revolute, slide -> prismatic, ball -> ball. A body with several joints
  is a chain of the same joints through light bodies (mass `LIGHT` times the body's, at the joints' anchors),
  so that each joint keeps its own coordinate, limit, spring and motor; each light body is named
  "<body>/<joint>". MuJoCo evaluates a body's joints in order, each about the frame the previous ones left,
  which is exactly a chain. Where none of them carries any such element, two hinges through one point are one
  universal joint and three or more whose axes span space one ball joint, named "<joint>+<joint>+..." (exact:
  MuJoCo's hinges of one body have no mass between them; `merge_joints=False` keeps the chain).
  limited range -> joint limit; stiffness/springref and damping -> joint spring; frictionloss -> a stiff
  velocity motor of target 0 whose force is capped at the frictionloss (dry friction, exact); armature -> on a
  hinge whose parent cannot turn (the world, or a body on slides from it), a massless disc of that moment on
  the child (exact); elsewhere one warning naming the joints (MuJoCo adds it to the joint-space mass matrix: no
  rigid body has that inertia).
- actuators on a joint with gain "fixed" and bias "none" or "affine" (motor, position, velocity, and general
  ones of those forms) -> a motor (effort, velocity or position mode) and an `Actuator` that maps the control
  as `ctrl` does: force = gain ctrl + b0 + b1 length + b2 velocity, length = gear q, torque = gear force.
- equality connect -> a ball loop joint, weld -> a fixed loop joint, at the built pose.
- geoms: every one is a `Visual` (its rgba or material colour; a mesh's vertices and faces). Collision:
  planes on the world -> grounds; a sphere, capsule, box or cylinder of a moving body -> the body's shape where
  it is the body's only collision geom and centred on its centre of mass (warpimpulse bodies carry one shape
  at their centre of mass), else a piece welded to the body with a share of its mass (`_pieces`: the whole
  keeps MuJoCo's mass properties); on the world -> a static body each; contype, conaffinity, parent filtering
  and <exclude> -> collision filters. Meshes, ellipsoids, height fields: their
  collision is dropped with a warning naming the geom (their mass properties stay, from MuJoCo).
- option: gravity; the contact, gravity, limit, spring, damper, frictionloss, actuation and equality disable
  flags; gravcomp -> a constant force.
Tendons, flexes, actuators on sites, tendons or bodies, activation dynamics, joint equality, explicit contact
pairs and fluid forces have no equivalent: one line naming the element (`SceneError`), or, with
`ignore_unsupported`, a warning and the element left out.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from .builder import SceneBuilder, SceneError
from .shapes import Shape, collision_pieces, parallel_axis
from .transforms import quat_from_matrix, quat_to_matrix

LIGHT = 1e-6
"""The mass of a light body in a chain of joints, as a fraction of the mass of the body it carries; its
inertia is the same fraction of that body's mean principal moment. The motion differs from MuJoCo's by about
this fraction."""

MERGE_SPREAD = 1e-3
"""The least singular value of a body's unit hinge axes (2 or 3 of them) for the set to be one universal or ball
joint (`_Loader._merged`): nearly parallel axes are a chain, as built."""

INSTALL = "MJCF needs MuJoCo's compiler: pip install 'warpimpulse[mjcf]' (or pip install mujoco)"


def _mujoco():
    try:
        import mujoco
    except ImportError:
        raise SceneError(INSTALL) from None
    return mujoco


def compile_mjcf(source):
    """A `mujoco.MjModel` from a path, an XML string, or an MjModel (returned as is); a compiler error as one
    `SceneError` line naming the file."""
    mujoco = _mujoco()
    if isinstance(source, mujoco.MjModel):
        return source
    text = str(source)
    is_xml = text.lstrip().startswith("<")
    what = "MJCF string" if is_xml else f"MJCF file {text!r}"
    if not is_xml and not Path(text).is_file():
        raise SceneError(f"{what}: no such file")
    try:
        return mujoco.MjModel.from_xml_string(text) if is_xml else mujoco.MjModel.from_xml_path(text)
    except ValueError as exc:
        raise SceneError(f"{what}: {' '.join(str(exc).split())}") from None


def load_mjcf(
    source, ignore_unsupported: bool = False, qpos=None, qvel=None, merge_joints: bool = True
) -> SceneBuilder:
    """The MuJoCo model `source` (a path, an XML string, or a compiled `mujoco.MjModel`) as a SceneBuilder,
    built at `qpos` (default: the model's qpos0) with the joint velocities `qvel` (default 0); see the module
    docstring for what maps to what. An element with no equivalent is a `SceneError` naming it, or with
    `ignore_unsupported` a warning and the element left out. `merge_joints`: a body's hinges through one point
    that carry nothing of their own are one universal or ball joint (exact, and cheaper); False keeps each hinge
    a joint of its own (a chain through light bodies), to read or drive each angle later."""
    model = compile_mjcf(source)
    with warnings.catch_warnings(record=True) as caught:  # said at the caller's line, each once
        warnings.simplefilter("always")
        builder = _Loader(model, ignore_unsupported, qpos, qvel, merge_joints).builder
    for w in caught:
        warnings.warn(w.message, w.category, stacklevel=2)
    return builder


class _Loader:
    """One pass over a compiled model: bodies, joints, actuators, equalities, geoms, in that order."""

    def __init__(self, m, ignore_unsupported: bool, qpos, qvel, merge: bool = True) -> None:
        self.mj = mujoco = _mujoco()
        self.m, self.ignore, self.merge = m, ignore_unsupported, merge
        flags = m.opt.disableflags
        self.off = {k: bool(flags & int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{k.upper()}")))
                    for k in ("contact", "gravity", "limit", "spring", "damper", "frictionloss", "actuation",
                              "equality")}  # fmt: skip
        d = self.d = mujoco.MjData(m)
        for name, values, size in (("qpos", qpos, m.nq), ("qvel", qvel, m.nv)):
            if values is not None:
                arr = np.asarray(values, dtype=np.float64).reshape(-1)
                if arr.shape != (size,) or not np.isfinite(arr).all():
                    raise SceneError(f"load_mjcf: {name} must be {size} finite numbers, got shape {arr.shape}")
                getattr(d, name)[:] = arr
        if qpos is None:
            d.qpos[:] = self._start(m)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        self.builder = SceneBuilder(np.zeros(3) if self.off["gravity"] else np.array(m.opt.gravity, dtype=float))
        self._check_model()
        self.group = self._bodies()  # mj body -> our body (-1: the world)
        self.joint = self._joints()  # mj joint -> our joint (-1: none, a free joint)
        self._actuators()
        self._equalities()
        self._geoms()

    def _start(self, m) -> np.ndarray:
        """qpos0 with each limited hinge or slide outside its range moved to the nearest bound, said (MuJoCo
        starts such a joint outside and its soft limit pushes it in; a limit here holds from the built pose)."""
        qpos = m.qpos0.copy()
        if self.off["limit"]:
            return qpos
        for j in np.flatnonzero(m.jnt_limited):
            if int(m.jnt_type[j]) in (self.mj.mjtJoint.mjJNT_HINGE, self.mj.mjtJoint.mjJNT_SLIDE):
                adr, (low, high) = m.jnt_qposadr[j], m.jnt_range[j]
                if not low <= qpos[adr] <= high:
                    moved = min(max(qpos[adr], low), high)
                    warnings.warn(f"joint {self.name('joint', j)!r}: qpos0 {qpos[adr]:g} is outside its range "
                                  f"[{low:g}, {high:g}]; built at {moved:g}", stacklevel=2)  # fmt: skip
                    qpos[adr] = moved
        return qpos

    # ---------------------------------------------------------------- helpers
    def name(self, kind, i: int) -> str:
        """An element's name, or "<kind><index>" where it has none."""
        obj = getattr(self.mj.mjtObj, f"mjOBJ_{kind.upper()}")
        return self.mj.mj_id2name(self.m, obj, i) or f"{kind}{i}"

    def unsupported(self, message: str) -> None:
        """Refuse the element (one line), or leave it out with a warning."""
        if not self.ignore:
            raise SceneError(f"{message} (load with ignore_unsupported=True / --ignore-unsupported to drop it)")
        warnings.warn(f"{message}: dropped", stacklevel=2)

    def _check_model(self) -> None:
        """The model-wide elements with no equivalent."""
        m = self.m
        for count, what in ((m.ntendon, "tendon"), (m.nflex, "flex"), (m.npair, "pair")):
            for i in range(count):
                self.unsupported(f"{what} {self.name(what, i)!r}: {what}s are not supported")
        for field in ("density", "viscosity"):
            if getattr(m.opt, field) > 0.0:
                self.unsupported(f"option {field}={getattr(m.opt, field)}: fluid forces are not supported")
        if np.any(m.opt.wind != 0.0):
            self.unsupported(f"option wind={m.opt.wind.tolist()}: fluid forces are not supported")
        if m.nsensor:
            warnings.warn(f"{m.nsensor} sensors are not read (outputs only; the motion does not depend on them)",
                          stacklevel=2)  # fmt: skip

    # ---------------------------------------------------------------- bodies
    def _bodies(self) -> np.ndarray:
        """Each mj body's body of ours: one per body with joints, the welded ones merged in."""
        m = self.m
        group = np.full(m.nbody, -1, dtype=np.int64)
        members: dict[int, list[int]] = {}
        for i in range(1, m.nbody):
            if m.body_jntnum[i]:
                members[i] = [i]
                group[i] = i  # the mj body at the group's root, for now
            else:
                group[i] = group[m.body_parentid[i]]
                if group[i] >= 0:
                    members[int(group[i])].append(i)
        self.shapes: dict[int, int] = {}  # colliding geom -> the body of ours that carries it
        ours = {}
        for root, parts in members.items():
            ours[root] = self._body(root, parts)
        return np.array([ours.get(int(g), -1) if g >= 0 else -1 for g in group], dtype=np.int64)

    def _body(self, root: int, parts: list[int]) -> int:
        """Our body for mj body `root` and the bodies welded to it (`parts`): its mass properties composed; its
        colliding geoms as its shape (the one geom, centred on its centre of mass) or as pieces welded to it."""
        m, d, b = self.m, self.d, self.builder
        name = self.name("body", root)
        mass = float(sum(m.body_mass[p] for p in parts))
        if mass <= 0.0:
            raise SceneError(f"body {name!r}: it moves but has no mass")
        com = sum(m.body_mass[p] * d.xipos[p] for p in parts) / mass
        inertia = sum(parallel_axis(m.body_mass[p], d.ximat[p].reshape(3, 3) @ np.diag(m.body_inertia[p]) @
                              d.ximat[p].reshape(3, 3).T, d.xipos[p] - com) for p in parts)  # fmt: skip
        geoms = [g for p in parts for g in range(m.body_geomadr[p], m.body_geomadr[p] + m.body_geomnum[p])
                 if self._collides(g) and _shape_kind(self.mj, m.geom_type[g]) is not None]  # fmt: skip
        shape_geom, pieces = None, []
        if len(geoms) == 1 and np.linalg.norm(d.geom_xpos[geoms[0]] - com) <= 1e-9 * max(1.0, float(m.stat.extent)):
            shape_geom = geoms[0]
        elif geoms:
            mass, com, inertia, pieces = self._pieces(name, geoms, mass, com, inertia)
        # The body frame: the shape's where it has one, else the principal frame (MuJoCo's, for one body).
        frame = d.geom_xmat[shape_geom] if shape_geom is not None else d.ximat[root] if len(parts) == 1 else None
        rot = np.linalg.eigh(inertia)[1] if frame is None or pieces else frame.reshape(3, 3).copy()
        v, w = self._velocity(root, com)
        body = self._add(name, mass, inertia, com, rot, v, w, shape_geom)
        for g, piece_mass, piece_inertia in pieces:
            centre = d.geom_xpos[g]
            v, w = self._velocity(root, centre)
            piece = self._add(f"{name}/{self.name('geom', g)}", piece_mass, piece_inertia, centre,
                              d.geom_xmat[g].reshape(3, 3).copy(), v, w, g)  # fmt: skip
            b.add_joint_fixed(body, piece, centre, name=f"{name}/{self.name('geom', g)}")
        if not self.off["gravity"]:
            lift = sum(float(m.body_gravcomp[p] * m.body_mass[p]) for p in parts)
            if lift:
                b.add_force(body, force=-lift * b.gravity)
        return body

    def _add(self, name: str, mass: float, inertia: np.ndarray, com, rot: np.ndarray, v, w, geom: int | None) -> int:
        """A body of ours with the world inertia tensor `inertia` about `com`, its frame `rot` (world), carrying
        geom `geom`'s shape (or none) with its friction."""
        if np.linalg.det(rot) < 0.0:
            rot[:, 2] = -rot[:, 2]
        local = rot.T @ inertia @ rot
        friction = float(self.m.geom_friction[geom][0]) if geom is not None else 0.5
        if geom is not None:
            self.shapes[geom] = len(self.builder.bodies)
        return self.builder.add_body(mass, 0.5 * (local + local.T), com, quat_from_matrix(rot), v, w, name=name,
                                     shape=self._shape(geom), friction=friction)  # fmt: skip

    def _pieces(self, name: str, geoms: list[int], mass: float, com, inertia):
        """A body's colliding geoms as pieces of its mass welded to what remains of it (`shapes.collision_pieces`).
        Returns the body's (mass, centre, inertia) and the pieces' (geom, mass, world inertia about the geom's
        centre); a body whose remainder is never valid keeps its geoms for display, said."""
        d = self.d
        shapes = [(self._shape(g), d.geom_xpos[g], d.geom_xmat[g].reshape(3, 3)) for g in geoms]
        split = collision_pieces(mass, com, inertia, shapes)
        if split is not None:
            rest, centre, about, pieces = split
            return rest, centre, about, [(g, m, i) for g, (m, i) in zip(geoms, pieces)]
        for g in geoms:
            warnings.warn(f"geom {self.name('geom', g)!r}: its body {name!r} has no mass to spare for it as a "
                          "collision piece; the geom is display only", stacklevel=2)  # fmt: skip
        return mass, com, inertia, []

    def _velocity(self, body: int, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The linear velocity of `point` of mj body `body` and its angular velocity, world frame (cvel is about
        the centre of mass of the body's subtree root)."""
        cvel = self.d.cvel[body]
        origin = self.d.subtree_com[self.m.body_rootid[body]]
        return cvel[3:] + np.cross(cvel[:3], point - origin), cvel[:3].copy()

    # ---------------------------------------------------------------- joints
    def _joints(self) -> np.ndarray:
        """Each mj joint's joint of ours; a body with k joints gets k - 1 light bodies between them."""
        m, d, b, mj = self.m, self.d, self.builder, self.mj
        ours = np.full(m.njnt, -1, dtype=np.int64)
        types = mj.mjtJoint
        still: set[int] = set()  # our bodies that cannot turn: joined to the world by slides only
        self.armature_left: list[str] = []  # the joints whose armature is not modelled (`_armature`)
        for body in range(1, m.nbody):
            count, first = int(m.body_jntnum[body]), int(m.body_jntadr[body])
            if not count or int(m.jnt_type[first]) == types.mjJNT_FREE:
                continue  # a free body (MuJoCo allows a free joint only alone, in a body of the world)
            child, up = int(self.group[body]), int(m.body_parentid[body])
            parent = int(self.group[up])
            merged = self._merged(first, count) if self.merge else None
            if merged is not None:  # one joint of ours is all of them, exactly: no light bodies
                names = "+".join(self.name("joint", j) for j in range(first, first + count))
                anchor, axes = d.xanchor[first], d.xaxis[first : first + count]
                jparent = None if parent < 0 else parent
                if merged == "universal":
                    ours[first : first + count] = b.add_joint_universal(jparent, child, anchor, axes[0], axes[1],
                                                                        name=names)  # fmt: skip
                else:
                    ours[first : first + count] = b.add_joint_ball(jparent, child, anchor, name=names)
                continue
            mass, moments = b.bodies[child].mass, np.linalg.eigvalsh(b.bodies[child].inertia)
            # The velocity of the frame the joints so far leave, at `origin`: the parent's, then each joint's.
            origin = d.xanchor[first]
            v, w = self._velocity(up, origin) if up else (np.zeros(3), np.zeros(3))
            for k, jnt in enumerate(range(first, first + count)):
                name = self.name("joint", jnt)
                anchor, axis, kind = d.xanchor[jnt], d.xaxis[jnt], int(m.jnt_type[jnt])
                v, origin = v + np.cross(w, anchor - origin), anchor
                rate = d.qvel[m.jnt_dofadr[jnt] : m.jnt_dofadr[jnt] + (3 if kind == types.mjJNT_BALL else 1)]
                if kind == types.mjJNT_HINGE:
                    w = w + rate[0] * axis
                elif kind == types.mjJNT_SLIDE:
                    v = v + rate[0] * axis
                else:  # a ball's rates are about the body's axes (MuJoCo's cdof)
                    w = w + d.xmat[body].reshape(3, 3) @ rate
                link = child
                if k < count - 1:  # a light body at the anchor, moving with the frame the joints so far leave
                    link = b.add_body(LIGHT * mass, LIGHT * moments.mean() * np.ones(3), anchor, (0, 0, 0, 1),
                                      v, w, name=f"{b.bodies[child].name}/{name}")  # fmt: skip
                jparent = None if parent < 0 else parent
                if kind == types.mjJNT_HINGE:
                    ours[jnt] = b.add_joint_revolute(jparent, link, anchor, axis, name=name)
                elif kind == types.mjJNT_SLIDE:
                    ours[jnt] = b.add_joint_prismatic(jparent, link, anchor, axis, name=name)
                else:
                    ours[jnt] = b.add_joint_ball(jparent, link, anchor, name=name)
                steady = parent < 0 or parent in still  # the joint's parent side cannot turn
                if kind == types.mjJNT_SLIDE and steady:
                    still.add(link)
                self._joint_elements(jnt, int(ours[jnt]), name)
                self._armature(jnt, link if kind == types.mjJNT_HINGE and steady else None, axis, name)
                parent = link
            if count > 1:
                b.chain_joints(ours[first : first + count])
        if self.armature_left:
            warnings.warn(f"armature not modelled on {len(self.armature_left)} joints: "
                          f"{', '.join(self.armature_left)} (MuJoCo adds it to the joint-space mass matrix, a rotor's "
                          "inertia reflected on the joint's rate alone; no rigid body has it unless the joint's "
                          "parent cannot turn; docs/mjcf.md)", stacklevel=2)  # fmt: skip
        return ours

    def _merged(self, first: int, count: int) -> str | None:
        """The joint of ours that a body's `count` joints from `first` are exactly, where none of them needs a
        coordinate of its own: two hinges through one point are a universal joint (the first axis turns with the
        parent, the second with the body, at the angle they were built at), three or more whose axes span space a
        ball joint (MuJoCo's body between them has no mass: the same motion, away from the gimbal lock where its
        hinges lose a freedom the ball keeps). None (a chain through light bodies) for any other set, or where a
        joint has a limit, spring, damper, dry friction, armature or actuator (each acts on its own coordinate).
        The light bodies cost: on the dm_control humanoid 9 of its 22 bodies and 54 of its 105 joint rows."""
        m, d, mj = self.m, self.d, self.mj
        joints = range(first, first + count)
        if count < 2 or any(int(m.jnt_type[j]) != mj.mjtJoint.mjJNT_HINGE for j in joints):
            return None
        anchors = d.xanchor[first : first + count]
        if np.abs(anchors - anchors[0]).max() > 1e-9 * max(1.0, float(np.abs(anchors[0]).max())):
            return None
        actuated = set(m.actuator_trnid[:, 0][m.actuator_trntype == mj.mjtTrn.mjTRN_JOINT].tolist())
        for j in joints:
            dof = int(m.jnt_dofadr[j])
            if ((m.jnt_limited[j] and not self.off["limit"]) or (m.jnt_stiffness[j] > 0.0 and not self.off["spring"])
                    or (m.dof_damping[dof] > 0.0 and not self.off["damper"]) or m.dof_armature[dof] > 0.0
                    or (m.dof_frictionloss[dof] > 0.0 and not self.off["frictionloss"])
                    or (j in actuated and not self.off["actuation"])):  # fmt: skip
                return None
        spread = np.linalg.svd(d.xaxis[first : first + count], compute_uv=False)  # unit axes
        if count == 2:
            return "universal" if spread[1] > MERGE_SPREAD else None
        return "ball" if spread[2] > MERGE_SPREAD else None

    def _armature(self, jnt: int, link: int | None, axis: np.ndarray, name: str) -> None:
        """MuJoCo's armature a of a joint: kinetic energy a (dq/dt)^2 / 2 on its rate alone. On a hinge whose parent
        cannot turn (`link`: its child) the child turns at dq/dt about the fixed axis n, so a massless disc of
        moment a about n, a/2 (1 + n n^T) welded to the child, adds exactly that (and keeps the inertia a
        rigid body's); elsewhere it would add the parent's turning too, and is said (`armature_left`)."""
        armature = float(self.m.dof_armature[self.m.jnt_dofadr[jnt]])
        if armature <= 0.0:
            return
        if link is None:
            self.armature_left.append(f"{name!r} ({armature:g})")
            return
        body = self.builder.bodies[link]
        rot = quat_to_matrix(np.asarray(body.orientation))
        disc = 0.5 * armature * (np.eye(3) + np.outer(axis, axis))
        body.inertia = body.inertia + rot.T @ disc @ rot

    def _joint_elements(self, jnt: int, joint: int, name: str) -> None:
        """The limit, spring-damper and dry friction of mj joint `jnt` on our `joint`."""
        m, d, b, mj = self.m, self.d, self.builder, self.mj
        what = f"joint {name!r}"
        kind, adr, dof = int(m.jnt_type[jnt]), int(m.jnt_qposadr[jnt]), int(m.jnt_dofadr[jnt])
        ball = kind == mj.mjtJoint.mjJNT_BALL
        built = 0.0 if ball else float(d.qpos[adr])
        limited = bool(m.jnt_limited[jnt]) and not self.off["limit"]
        stiffness = 0.0 if self.off["spring"] else float(m.jnt_stiffness[jnt])
        damping = 0.0 if self.off["damper"] else float(m.dof_damping[dof])
        friction = 0.0 if self.off["frictionloss"] else float(m.dof_frictionloss[dof])
        if ball:
            for on, element in ((limited, "range"), (stiffness > 0.0, "stiffness"), (damping > 0.0, "damping"),
                                (friction > 0.0, "frictionloss")):  # fmt: skip
                if on:
                    self.unsupported(f"{what}: a ball joint's {element} is not supported")
        else:
            if limited:
                lower, upper = m.jnt_range[jnt] - built
                if not lower <= 0.0 <= upper:
                    raise SceneError(f"{what}: the built position {built} is outside its range "
                                     f"{m.jnt_range[jnt].tolist()}")  # fmt: skip
                b.add_joint_limit(joint, lower, upper)
            if stiffness > 0.0 or damping > 0.0:
                b.add_joint_spring(joint, stiffness, damping, float(m.qpos_spring[adr]) - built)
            if friction > 0.0:
                b.add_motor(joint, "velocity", 0.0, max_force=friction, stiff=True)
        if m.jnt_actfrclimited[jnt]:
            self.unsupported(f"{what}: actuatorfrcrange (a limit on the sum of its actuators' forces) is not "
                             "supported")  # fmt: skip

    # ---------------------------------------------------------------- actuators
    def _actuators(self) -> None:
        """Each actuator on a hinge or slide joint as a motor and its control map."""
        m, d, b, mj = self.m, self.d, self.builder, self.mj
        for i in range(m.nu):
            name = self.name("actuator", i)
            what = f"actuator {name!r}"
            jnt = int(m.actuator_trnid[i][0])
            if int(m.actuator_trntype[i]) != mj.mjtTrn.mjTRN_JOINT:
                trn = mj.mjtTrn(m.actuator_trntype[i]).name.removeprefix("mjTRN_").lower()
                self.unsupported(f"{what}: its transmission ({trn}) is not supported, only a joint")
                continue
            if self.off["actuation"]:
                warnings.warn(f"{what}: actuation is disabled in the model's options; left out", stacklevel=2)
                continue
            if int(m.jnt_type[jnt]) not in (mj.mjtJoint.mjJNT_HINGE, mj.mjtJoint.mjJNT_SLIDE):
                self.unsupported(f"{what}: drives joint {self.name('joint', jnt)!r}, not a hinge or a slide")
                continue
            if int(m.actuator_dyntype[i]) != mj.mjtDyn.mjDYN_NONE:
                dyn = mj.mjtDyn(m.actuator_dyntype[i]).name.removeprefix("mjDYN_").lower()
                self.unsupported(f"{what}: activation dynamics ({dyn}) are not supported")
                continue
            bias_type = int(m.actuator_biastype[i])
            if int(m.actuator_gaintype[i]) != mj.mjtGain.mjGAIN_FIXED or bias_type not in (
                mj.mjtBias.mjBIAS_NONE,
                mj.mjtBias.mjBIAS_AFFINE,
            ):
                self.unsupported(f"{what}: only a fixed gain with no or an affine bias is supported")  # fmt: skip
                continue
            gear, gain = float(m.actuator_gear[i][0]), float(m.actuator_gainprm[i][0])
            b0, b1, b2 = (m.actuator_biasprm[i][:3] if bias_type == mj.mjtBias.mjBIAS_AFFINE else np.zeros(3)).tolist()
            max_force = math.inf
            if m.actuator_forcelimited[i]:
                low, high = m.actuator_forcerange[i]
                if low != -high:
                    self.unsupported(f"{what}: an asymmetric forcerange {[low, high]} is not supported")
                    continue
                max_force = abs(gear) * high
            built = float(d.qpos[m.jnt_qposadr[jnt]])
            # torque = gear (gain ctrl + b0 + b1 gear q + b2 gear dq/dt), q = built + x (x: our coordinate)
            kp, kd = -gear * gear * b1, -gear * gear * b2
            if kp < 0.0 or kd < 0.0:
                self.unsupported(f"{what}: a bias that pushes away from its target (b1, b2 > 0) is not supported")
                continue
            if kp > 0.0:  # position: kp (target - x) - kd dx/dt
                mode, scale, offset = "position", gear * gain / kp, gear * b0 / kp - built
            elif kd > 0.0:  # velocity: kd (target - dx/dt)
                mode, scale, offset, kp = "velocity", gear * gain / kd, gear * b0 / kd, kd
            else:  # a force
                mode, scale, offset = "effort", gear * gain, gear * b0
            motor = b.add_motor(int(self.joint[jnt]), mode, 0.0, kp=kp, kd=kd if mode == "position" else 0.0,
                                max_force=max_force)  # fmt: skip
            ctrl = tuple(m.actuator_ctrlrange[i]) if m.actuator_ctrllimited[i] else None
            b.add_actuator(motor, scale, offset, ctrl, name=name)

    # ---------------------------------------------------------------- equalities
    def _equalities(self) -> None:
        """Connect and weld constraints as loop joints at the built pose."""
        m, d, b, mj = self.m, self.d, self.builder, self.mj
        kinds = mj.mjtEq
        for i in range(m.neq):
            name = self.name("equality", i)
            what = f"equality {name!r}"
            kind = int(m.eq_type[i])
            if kind not in (kinds.mjEQ_CONNECT, kinds.mjEQ_WELD):
                label = kinds(kind).name.removeprefix("mjEQ_").lower()
                self.unsupported(f"{what}: {label} equality is not supported, only connect and weld")
                continue
            if self.off["equality"]:
                warnings.warn(f"{what}: equality constraints are disabled in the model's options; left out",
                              stacklevel=2)  # fmt: skip
                continue
            if not m.eq_active0[i]:
                self.unsupported(f"{what}: an equality inactive at the start is not supported")
                continue
            sites = int(m.eq_objtype[i]) == mj.mjtObj.mjOBJ_SITE
            ends = [int(m.eq_obj1id[i]), int(m.eq_obj2id[i])]
            if sites:
                points = [d.site_xpos[s] for s in ends]
                ends = [int(m.site_bodyid[s]) for s in ends]
            else:
                points = [d.xpos[e] + d.xmat[e].reshape(3, 3) @ m.eq_data[i][3 * k : 3 * k + 3]
                          for k, e in enumerate(ends)]  # fmt: skip
            body1, body2 = (int(self.group[e]) for e in ends)
            if body1 == body2:
                self.unsupported(f"{what}: both ends are on one rigid body")
                continue
            gap = float(np.linalg.norm(points[0] - points[1]))
            if kind == kinds.mjEQ_CONNECT and gap > 1e-6:
                warnings.warn(f"{what}: its two points are {gap:.3g} m apart at the built pose; joined at their "
                              "midpoint", stacklevel=2)  # fmt: skip
            anchor = 0.5 * (points[0] + points[1])
            if kind == kinds.mjEQ_WELD and not sites:
                self._check_weld(i, what, ends)
            parent = None if body2 < 0 else body2
            child, parent = (body1, parent) if body1 >= 0 else (body2, None)
            add = b.add_joint_ball if kind == kinds.mjEQ_CONNECT else b.add_joint_fixed
            b.mark_loop_joint(add(parent, child, anchor, name=name))

    def _check_weld(self, i: int, what: str, ends: list[int]) -> None:
        """A weld holds the relative pose it has as built: say so where it differs from the one MuJoCo holds
        (relpose)."""
        m, d = self.m, self.d
        rot1, rot2 = d.xmat[ends[0]].reshape(3, 3), d.xmat[ends[1]].reshape(3, 3)
        relpos = m.eq_data[i][3:6]
        relmat = np.zeros(9)
        self.mj.mju_quat2Mat(relmat, m.eq_data[i][6:10])
        # MuJoCo: body2's pose in body1's frame is relpose (pos, quat).
        pos = rot1.T @ (d.xpos[ends[1]] - d.xpos[ends[0]])
        off = max(float(np.linalg.norm(pos - relpos)), float(np.abs(rot1.T @ rot2 - relmat.reshape(3, 3)).max()))
        if off > 1e-6:
            warnings.warn(f"{what}: the built pose is {off:.3g} off the weld's relpose; held as built", stacklevel=2)

    # ---------------------------------------------------------------- geoms
    def _collides(self, g: int) -> bool:
        return not self.off["contact"] and bool(self.m.geom_contype[g] or self.m.geom_conaffinity[g])

    def _shape(self, g: int | None) -> Shape | None:
        """The Shape of geom g (MuJoCo's sizes are half lengths)."""
        if g is None:
            return None
        kind, size = _shape_kind(self.mj, self.m.geom_type[g]), self.m.geom_size[g]
        if kind == "box":
            return Shape("box", size=tuple(2.0 * size))
        if kind == "sphere":
            return Shape("sphere", radius=float(size[0]))
        return Shape(kind, radius=float(size[0]), length=2.0 * float(size[1]))

    def _geoms(self) -> None:
        """Every geom as a visual; collision as the module docstring says; MuJoCo's filters as ours."""
        m, d, b, mj = self.m, self.d, self.builder, self.mj
        types = mj.mjtGeom
        shapes = dict(self.shapes)  # colliding geom -> our body carrying it
        for g in range(m.ngeom):
            name = self.name("geom", g)
            what = f"geom {name!r}"
            body = int(self.group[m.geom_bodyid[g]])
            kind = int(m.geom_type[g])
            pose = d.geom_xpos[g], quat_from_matrix(d.geom_xmat[g].reshape(3, 3))
            self._visual(g, name, body, kind, pose)
            if not self._collides(g) or g in shapes:
                continue
            friction = float(m.geom_friction[g][0])
            if kind == types.mjGEOM_PLANE:
                if body >= 0:
                    self.unsupported(f"{what}: a plane on a moving body is not supported")
                    continue
                normal = d.geom_xmat[g].reshape(3, 3)[:, 2]
                b.add_ground(float(normal @ d.geom_xpos[g]), normal, friction)
            elif _shape_kind(mj, kind) is None:
                label = types(kind).name.removeprefix("mjGEOM_").lower()
                warnings.warn(f"{what}: {label} collision is not supported; the geom is display only (its mass "
                              "stays)", stacklevel=2)  # fmt: skip
            elif body < 0:
                shapes[g] = b.add_static_body(pose[0], pose[1], name=f"{self.name('body', m.geom_bodyid[g])}/{name}",
                                              shape=self._shape(g), friction=friction)  # fmt: skip
        self._filters(shapes)

    def _visual(self, g: int, name: str, body: int, kind: int, pose) -> None:
        m, b, types = self.m, self.builder, self.mj.mjtGeom
        size = m.geom_size[g]
        rgba = m.mat_rgba[m.geom_matid[g]] if m.geom_matid[g] >= 0 else m.geom_rgba[g]
        body = None if body < 0 else body
        common = dict(position=pose[0], orientation=pose[1], rgba=np.clip(rgba, 0.0, 1.0), name=name)
        if kind == types.mjGEOM_MESH:
            mesh = int(m.geom_dataid[g])
            v0, nv, f0, nf = m.mesh_vertadr[mesh], m.mesh_vertnum[mesh], m.mesh_faceadr[mesh], m.mesh_facenum[mesh]
            b.add_visual(body, "mesh", (1.0, 1.0, 1.0), **common, vertices=m.mesh_vert[v0 : v0 + nv],
                         faces=m.mesh_face[f0 : f0 + nf], mesh_path=self.name("mesh", mesh))  # fmt: skip
        elif kind == types.mjGEOM_PLANE:
            extent = [2.0 * s if s > 0.0 else 20.0 for s in size[:2]]
            b.add_visual(body, "box", (*extent, 0.0), **common)
        elif kind == types.mjGEOM_BOX:
            b.add_visual(body, "box", 2.0 * size, **common)
        elif kind == types.mjGEOM_SPHERE:
            b.add_visual(body, "sphere", (size[0], 0.0, 0.0), **common)
        elif kind in (types.mjGEOM_CAPSULE, types.mjGEOM_CYLINDER):
            b.add_visual(body, _shape_kind(self.mj, kind), (size[0], 2.0 * size[1], 0.0), **common)
        elif kind == types.mjGEOM_ELLIPSOID:
            vertices, faces = _unit_sphere()
            b.add_visual(body, "mesh", size, **common, vertices=vertices, faces=faces)
        else:
            label = types(kind).name.removeprefix("mjGEOM_").lower()
            warnings.warn(f"geom {name!r}: a {label} is not drawn", stacklevel=2)

    def _filters(self, shapes: dict[int, int]) -> None:
        """filter_collision for each pair of our colliding bodies MuJoCo would not let collide: contype and
        conaffinity, a body against its parent (filterparent), one weld group, <exclude>; and a warning for a
        geom that MuJoCo keeps off the ground, which ours is not."""
        m, b = self.m, self.builder
        weld, parent = m.body_weldid, m.body_parentid
        excluded = {(int(s) >> 16, int(s) & 0xFFFF) for s in m.exclude_signature}
        filter_parent = not m.opt.disableflags & int(self.mj.mjtDisableBit.mjDSBL_FILTERPARENT)

        def collide(g1: int, g2: int) -> bool:
            if not (m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1]):
                return False
            b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            w1, w2 = int(weld[b1]), int(weld[b2])
            if w1 == w2 or (min(b1, b2), max(b1, b2)) in excluded:
                return False
            return not (filter_parent and w1 and w2 and (w1 == weld[parent[w2]] or w2 == weld[parent[w1]]))

        items = sorted(shapes.items())
        for i, (g1, o1) in enumerate(items):
            for g2, o2 in items[i + 1 :]:
                dynamic = not (b.bodies[o1].static and b.bodies[o2].static)
                if o1 != o2 and dynamic and not collide(g1, g2):
                    b.filter_collision(int(o1), int(o2))
        planes = [
            g for g in range(m.ngeom) if int(m.geom_type[g]) == self.mj.mjtGeom.mjGEOM_PLANE and self._collides(g)
        ]
        for g1, _ in items:
            if any(not collide(g1, p) for p in planes) and not b.bodies[shapes[g1]].static:
                warnings.warn(f"geom {self.name('geom', g1)!r}: MuJoCo keeps it off a plane (contype/conaffinity); "
                              "here it touches every ground", stacklevel=2)  # fmt: skip


def _shape_kind(mujoco, kind: int) -> str | None:
    """Our collision shape's kind for a MuJoCo geom type, None where there is none."""
    types = mujoco.mjtGeom
    return {types.mjGEOM_SPHERE: "sphere", types.mjGEOM_CAPSULE: "capsule", types.mjGEOM_BOX: "box",
            types.mjGEOM_CYLINDER: "cylinder"}.get(int(kind))  # fmt: skip


def _unit_sphere(rings: int = 8, segments: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """A triangulated unit sphere (vertices (k, 3), faces (f, 3)) for drawing an ellipsoid."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    vertices = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    faces = []
    idx = 1 + np.arange(len(ring)).reshape(rings - 1, segments)
    last = len(vertices) - 1
    for s in range(segments):
        s1 = (s + 1) % segments
        faces.append((0, idx[0, s], idx[0, s1]))
        faces.append((last, idx[-1, s1], idx[-1, s]))
        for r in range(rings - 2):
            faces += [(idx[r, s], idx[r + 1, s], idx[r + 1, s1]), (idx[r, s], idx[r + 1, s1], idx[r, s1])]
    return vertices, np.array(faces, dtype=np.int64)
