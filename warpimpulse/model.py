"""Model (what a scene is: static arrays on the device), State (where its bodies are) and Control (forces).

Field names are the kernels' parameter names (`launch.record` binds them by name), in the MuJoCo Warp habit:
`body_*` per body, `constraint_*` per basic constraint, `joint_*` per joint. Frames: positions and
velocities are world frame; anchors and axes of a constraint are in the frame of the body on that side (world
frame on a WORLD side); quaternions are (x, y, z, w).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import warp as wp

from . import checks
from .kernels import rigid as rigid_kernels
from .shapes import Colliders
from .topology import Graph, Topology, analyze
from .transforms import quat_from_matrix
from .types import COORDINATES, DISTANCE_COORDINATE, ConstraintKind


def _array(values, dtype, device) -> wp.array:
    return wp.array(np.ascontiguousarray(values), dtype=dtype, device=device)


def _static(values: np.ndarray, dtype, device) -> wp.array:
    """A read-only model array: on the CPU it shares the host array's memory (the kernels only read it, and a
    million constraints' geometry is 136 MB), on a GPU it is a copy."""
    if device.is_cpu and values.flags.c_contiguous and values.dtype == np.float64:
        return wp.array(values, dtype=dtype, device=device, copy=False)
    return _array(values, dtype, device)


def principal_axes(inertia: np.ndarray, dynamic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(principal moments j (n, 3) kg m^2, principal frames r (n, 4) quaternions x y z w) of the dynamic bodies
    whose inertia J (n, 3, 3, body frame) is not diagonal: J = R(r) diag(j) R(r)^T, R(r) a rotation (its columns
    the principal axes in the body frame). Zero moments and the identity elsewhere (or where a moment is not
    positive): `rigid.principal_terms` then leaves the body DIAGONAL or GENERAL."""
    n = len(inertia)
    moments, axes = np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    off = inertia[:, [0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]]
    turned = np.flatnonzero(dynamic & np.any(off != 0.0, axis=1))
    j, r = np.linalg.eigh(inertia[turned]) if len(turned) else (np.zeros((0, 3)), np.zeros((0, 3, 3)))
    r[:, :, 2] *= np.sign(np.linalg.det(r))[:, None]  # a rotation, not a reflection
    for k in np.flatnonzero(np.all(j > 0.0, axis=1)):
        moments[turned[k]], axes[turned[k]] = j[k], quat_from_matrix(r[k])
    return moments, axes


@dataclass
class State:
    """The bodies' state at one time, world frame."""

    body_x: wp.array  # centre of mass (m)
    body_q: wp.array  # orientation (x, y, z, w), body to world
    body_v: wp.array  # linear velocity of the centre of mass (m/s)
    body_w: wp.array  # angular velocity (rad/s), world frame

    def copy_from(self, other: State) -> None:
        for name in ("body_x", "body_q", "body_v", "body_w"):
            wp.copy(getattr(self, name), getattr(other, name))


@dataclass
class Control:
    """External loads, constant over a step."""

    body_force: wp.array  # world force at the centre of mass (N)
    body_torque: wp.array  # world torque (N m)


class Model:
    """Everything about a scene that does not change while it runs: device arrays for the kernels, and the
    same inputs on the host (`host`) with the names that messages and accessors use.

    Built by `SceneBuilder.finalize()`, from names and arrays only (the model keeps no builder).
    """

    def __init__(
        self,
        device,
        *,
        gravity: np.ndarray,
        body_name: list[str],
        body_mass: np.ndarray,
        body_inertia: np.ndarray,
        body_static: np.ndarray,
        body_x: np.ndarray,
        body_q: np.ndarray,
        body_v: np.ndarray,
        body_w: np.ndarray,
        constraint_kind: np.ndarray,
        constraint_body0: np.ndarray,
        constraint_body1: np.ndarray,
        constraint_anchor0: np.ndarray,
        constraint_anchor1: np.ndarray,
        constraint_axis0: np.ndarray,
        constraint_axis1: np.ndarray,
        constraint_rest_rotation: np.ndarray,
        constraint_rest_angle: np.ndarray,
        constraint_joint: np.ndarray,
        joint_name: list[str],
        joint_type: list[str],
        joint_parent: np.ndarray,
        joint_child: np.ndarray,
        joint_constraint_start: np.ndarray,
        force_body: np.ndarray,
        force_force: np.ndarray,
        force_torque: np.ndarray,
        force_until: np.ndarray,
        world_count: int = 1,
        spring_name: list[str] = (),
        spring_body0: np.ndarray = (),
        spring_body1: np.ndarray = (),
        spring_anchor0: np.ndarray = (),
        spring_anchor1: np.ndarray = (),
        spring_params: np.ndarray = (),
        drive_name: list[str] = (),
        drive_joint: np.ndarray = (),
        drive_mode: np.ndarray = (),
        drive_target: np.ndarray = (),
        drive_gains: np.ndarray = (),
        drive_max_force: np.ndarray = (),
        drive_motor: np.ndarray = (),
        drive_stiff: np.ndarray = (),
        drive_chain: np.ndarray = (),
        drive_ends: np.ndarray = (),
        joint_loop: np.ndarray = (),
        limit_joint: np.ndarray = (),
        limit_bounds: np.ndarray = (),
        distance_name: list[str] = (),
        distance_body: np.ndarray = (),
        distance_anchor: np.ndarray = (),
        distance_bounds: np.ndarray = (),
        actuator_name: list[str] = (),
        actuator_drive: np.ndarray = (),
        actuator_map: np.ndarray = (),
        colliders: Colliders | None = None,
    ) -> None:
        """Args (SI units; n bodies, m basic constraints, k joints, f forces):
        gravity: (3,) m/s^2, world.
        body_name, body_mass (kg, 0 for static), body_inertia ((n, 3, 3) kg m^2, body frame about the centre
            of mass), body_static (bool), body_x / body_q / body_v / body_w: the initial state.
        constraint_*: each basic constraint's kind, bodies (WORLD = -1), anchors and axes in its bodies'
            frames, rest rotation q0^-1 q1 and rest angle at build time, and its joint.
        joint_*: name, catalogue type, parent and child body, and the first of its constraints (a joint's
            constraints are consecutive; (k + 1,) with the end last).
        force_*: constant world forces (N) and torques (N m) on bodies, active while t < until (s).
        world_count: independent copies of one scene laid out world-major (`SceneBuilder.replicate`): world w
            owns bodies [w n_w, (w + 1) n_w), and its constraints, joints and forces likewise, with indices into
            the whole model. Every launch covers all worlds; the simulator decides convergence per world.
        colliders: the collision shapes, planes and filters; None where nothing collides.
        spring_*: spring-dampers between a point of body0 and one of body1 (anchors in their frames), params
            (stiffness N/m, damping N s/m, rest length m).
        drive_*: joint springs and PID motors on a revolute or prismatic joint: mode (`types.DRIVE_MODES`
            index), initial target, gains (kp, ki, kd), max_force (N m or N), motor (False: a joint spring),
            stiff (a velocity constraint in the correction loop, not a force); chain: (two joints whose axes
            the drive's direction is reciprocal to, the joint whose anchor a force acts at; -1 for none) and ends
            (the two bodies its wrench acts on) of a drive on a chain of joints (`SceneBuilder.chain_joints`);
            by default none, and the joint's parent and child.
        actuator_*: named control inputs (`builder.Actuator`): the drive each sets, and (gain, bias, lowest,
            highest control): target = gain * clip(control, lowest, highest) + bias.
        limit_*: the joint and its (lower, upper) bounds (rad or m) of revolute or prismatic joints.
        joint_loop: (k,) bool, the joints to close loops with where there is a choice (USD's
            excludeFromArticulation); empty: the spanning tree chooses.
        distance_*: distance constraints: name, (body0, body1), anchors A, B and the direction used while they
            meet ((d, 3, 3), body frames), and (lower, upper) bounds on |B - A| (m).
        """
        self.device = checks.device(device)  # the first call initialises Warp quietly
        self.colliders = colliders
        d = self.device
        dynamic = ~np.asarray(body_static, dtype=bool)
        self.host = SimpleNamespace(
            gravity=np.asarray(gravity, dtype=np.float64),
            body_mass=np.array(body_mass, dtype=np.float64),
            body_inertia=np.array(body_inertia, dtype=np.float64).reshape(-1, 3, 3),
            body_static=~dynamic,
            body_x=np.asarray(body_x, np.float64).reshape(-1, 3),
            body_q=np.asarray(body_q, np.float64).reshape(-1, 4),
            body_v=np.asarray(body_v, np.float64).reshape(-1, 3),
            body_w=np.asarray(body_w, np.float64).reshape(-1, 3),
            constraint_kind=np.asarray(constraint_kind, np.int32),
            constraint_body0=np.asarray(constraint_body0, np.int64),
            constraint_body1=np.asarray(constraint_body1, np.int64),
            constraint_anchor0=np.asarray(constraint_anchor0, np.float64).reshape(-1, 3),
            constraint_anchor1=np.asarray(constraint_anchor1, np.float64).reshape(-1, 3),
            constraint_axis0=np.asarray(constraint_axis0, np.float64).reshape(-1, 3),
            constraint_axis1=np.asarray(constraint_axis1, np.float64).reshape(-1, 3),
            constraint_rest_rotation=np.asarray(constraint_rest_rotation, np.float64).reshape(-1, 4),
            constraint_rest_angle=np.asarray(constraint_rest_angle, np.float64),
            joint_parent=np.asarray(joint_parent, np.int64),
            joint_child=np.asarray(joint_child, np.int64),
            joint_constraint_start=np.asarray(joint_constraint_start, np.int64),
            force_body=np.asarray(force_body, np.int64),
            force_force=np.asarray(force_force, np.float64).reshape(-1, 3),
            force_torque=np.asarray(force_torque, np.float64).reshape(-1, 3),
            force_until=np.asarray(force_until, np.float64),
        )
        h = self.host
        self.actuator_name = list(actuator_name)
        h.actuator_drive = np.asarray(actuator_drive, np.int64).reshape(-1)
        h.actuator_map = np.asarray(actuator_map, np.float64).reshape(-1, 4)
        self.body_name = list(body_name)
        self.joint_name = list(joint_name)
        self.joint_type = list(joint_type)
        self.constraint_joint = np.asarray(constraint_joint, np.int64)
        self.body_count = len(self.body_name)
        self.joint_count = len(self.joint_name)
        self.constraint_count = len(h.constraint_kind)
        self.world_count = int(world_count)
        counts = {"bodies": self.body_count, "constraints": self.constraint_count, "joints": self.joint_count,
                  "forces": len(h.force_body)}  # fmt: skip
        for what, count in counts.items():
            if self.world_count < 1 or count % self.world_count:
                raise ValueError(f"{count} {what} do not split into {self.world_count} equal worlds")
        self.world_body_count = self.body_count // self.world_count
        self.world_constraint_count = self.constraint_count // self.world_count
        self.world_joint_count = self.joint_count // self.world_count
        self.constraint_world = _array(np.arange(self.constraint_count) // max(self.world_constraint_count, 1),
                                       wp.int32, d)  # fmt: skip

        self.graph = Graph(
            body_static=h.body_static,
            constraint_body0=h.constraint_body0,
            constraint_body1=h.constraint_body1,
            constraint_joint=self.constraint_joint,
            joint_parent=h.joint_parent,
            joint_child=h.joint_child,
            world_count=self.world_count,
            joint_loop=np.asarray(joint_loop, bool).reshape(-1) if len(joint_loop) else None,
        )
        self.topology: Topology = analyze(self.graph, level_order=d.is_cuda)
        self.kinds = [ConstraintKind(int(k)) for k in np.unique(h.constraint_kind)]

        self.gravity = wp.vec3d(*h.gravity)
        self.body_inv_mass = wp.zeros(self.body_count, dtype=wp.float64, device=d)
        self.body_inertia = wp.zeros(self.body_count, dtype=wp.mat33d, device=d)
        self.body_inv_inertia = wp.zeros(self.body_count, dtype=wp.mat33d, device=d)
        self.body_principal = wp.zeros(self.body_count, dtype=wp.int32, device=d)  # `rigid.DIAGONAL`, `TURNED`, ...
        self.body_euler = wp.zeros(self.body_count, dtype=wp.vec3d, device=d)  # its Euler coefficients (dimensionless)
        self.body_inv_principal = wp.zeros(self.body_count, dtype=wp.vec3d, device=d)  # its inverse's diagonal
        self.body_axes = wp.zeros(self.body_count, dtype=wp.quatd, device=d)  # a TURNED body's principal frame
        self.set_masses(h.body_mass, h.body_inertia)
        self.body_rows_start = _array(self.topology.body_rows_start, wp.int32, d)
        self.body_rows = _array(self.topology.body_rows, wp.int32, d)
        self.constraint_kind = _array(h.constraint_kind, wp.int32, d)
        self.constraint_body0 = _array(h.constraint_body0, wp.int32, d)
        self.constraint_body1 = _array(h.constraint_body1, wp.int32, d)
        self.constraint_anchor0 = _static(h.constraint_anchor0, wp.vec3d, d)
        self.constraint_anchor1 = _static(h.constraint_anchor1, wp.vec3d, d)
        self.constraint_axis0 = _static(h.constraint_axis0, wp.vec3d, d)
        self.constraint_axis1 = _static(h.constraint_axis1, wp.vec3d, d)
        self.constraint_rest_rotation = _static(h.constraint_rest_rotation, wp.quatd, d)
        self.constraint_rest_angle = _static(h.constraint_rest_angle, wp.float64, d)
        self._mechanisms(
            spring_name, spring_body0, spring_body1, spring_anchor0, spring_anchor1, spring_params,
            drive_name, drive_joint, drive_mode, drive_target, drive_gains, drive_max_force, drive_motor,
            drive_stiff, limit_joint, limit_bounds, joint_loop,
            (distance_name, distance_body, distance_anchor, distance_bounds), (drive_chain, drive_ends),
        )  # fmt: skip

    def _mechanisms(
        self, spring_name, spring_body0, spring_body1, spring_anchor0, spring_anchor1, spring_params, drive_name,
        drive_joint, drive_mode, drive_target, drive_gains, drive_max_force, drive_motor, drive_stiff, limit_joint,
        limit_bounds, joint_loop, distances, chains,
    ) -> None:  # fmt: skip
        """Springs and drives (force elements, evaluated in every RK4 stage of the prediction: `kernels/forces.py`)
        and the rows of the correction loop on a coordinate, limits then stiff motors (`kernels/limits.py`), on
        the table of coordinates: every revolute angle and prismatic offset (0 as built), then the distance of
        every distance constraint; a distance constraint is a limit row on its coordinate."""
        d, h = self.device, self.host
        h.spring_body0 = np.asarray(spring_body0, np.int64)
        h.spring_body1 = np.asarray(spring_body1, np.int64)
        h.spring_params = np.asarray(spring_params, np.float64).reshape(-1, 3)
        h.spring_anchor0 = np.asarray(spring_anchor0, np.float64).reshape(-1, 3)
        h.spring_anchor1 = np.asarray(spring_anchor1, np.float64).reshape(-1, 3)
        h.drive_mode = np.asarray(drive_mode, np.int32)
        h.drive_gains = np.asarray(drive_gains, np.float64).reshape(-1, 3)
        h.drive_max_force = np.asarray(drive_max_force, np.float64)
        h.joint_loop = np.asarray(joint_loop, bool).reshape(-1)
        h.drive_joint = np.asarray(drive_joint, np.int64)
        h.drive_target = np.asarray(drive_target, np.float64)
        h.drive_motor = np.asarray(drive_motor, bool)
        h.drive_stiff = np.asarray(drive_stiff, bool).reshape(-1)
        stiff = np.flatnonzero(h.drive_stiff)
        forced = np.flatnonzero(~h.drive_stiff)  # the drives that are force elements
        self.spring_name, self.drive_name = list(spring_name), list(drive_name)
        self.spring_count, self.drive_count = len(self.spring_name), len(self.drive_name)
        self.force_drive_count = len(forced)
        self.spring_body0 = _array(h.spring_body0, wp.int32, d)
        self.spring_body1 = _array(h.spring_body1, wp.int32, d)
        self.spring_anchor0 = _array(h.spring_anchor0, wp.vec3d, d)
        self.spring_anchor1 = _array(h.spring_anchor1, wp.vec3d, d)
        self.spring_params = _array(h.spring_params, wp.vec3d, d)

        # The coordinate of a revolute joint (constraints POINT, AXIS) or prismatic one (LINE, ROTATION): anchors
        # of its first constraint, the axis of the AXIS or LINE constraint in body0's frame, the rest rotation.
        # A distance constraint's coordinate: its bodies, anchors, and the direction for when they meet.
        distance_name, distance_body, distance_anchor, distance_bounds = distances
        self.distance_name = list(distance_name)
        self.distance_count = nd = len(self.distance_name)
        h.distance_body = distance_body = np.asarray(distance_body, np.int64).reshape(-1, 2)
        h.distance_anchor = distance_anchor = np.asarray(distance_anchor, np.float64).reshape(-1, 3, 3)
        h.distance_bounds = np.asarray(distance_bounds, np.float64).reshape(-1, 2)
        # Each joint's coordinate kind (-1: none), a comparison per distinct type (a million joints share a few).
        types = np.array(self.joint_type, dtype=object)
        coordinate = np.full(self.joint_count, -1, dtype=np.int32)
        for name in set(self.joint_type) & COORDINATES.keys():
            coordinate[types == name] = COORDINATES[name]
        coordinate_joint = np.flatnonzero(coordinate >= 0)
        self.coordinate_joint = coordinate_joint.tolist()
        row_of = np.full(self.joint_count, -1, dtype=np.int64)  # a joint's coordinate row
        row_of[coordinate_joint] = np.arange(len(coordinate_joint))
        first = h.joint_constraint_start[coordinate_joint]
        kind = coordinate[coordinate_joint]
        axis_constraint = first + (kind == COORDINATES["revolute"])
        self.coordinate_count = len(self.coordinate_joint) + nd
        kinds = np.concatenate([kind, np.full(nd, DISTANCE_COORDINATE)])  # every coordinate row's
        self.coordinate_kind = _array(kinds, wp.int32, d)
        body0 = np.concatenate([h.joint_parent[self.coordinate_joint], distance_body[:, 0]])
        body1 = np.concatenate([h.joint_child[self.coordinate_joint], distance_body[:, 1]])
        self.coordinate_body0 = _array(body0, wp.int32, d)
        self.coordinate_body1 = _array(body1, wp.int32, d)
        self.coordinate_anchor0 = _array(np.concatenate([h.constraint_anchor0[first], distance_anchor[:, 0]]),
                                         wp.vec3d, d)  # fmt: skip
        self.coordinate_anchor1 = _array(np.concatenate([h.constraint_anchor1[first], distance_anchor[:, 1]]),
                                         wp.vec3d, d)  # fmt: skip
        self.coordinate_axis0 = _array(np.concatenate([h.constraint_axis0[axis_constraint], distance_anchor[:, 2]]),
                                       wp.vec3d, d)  # fmt: skip
        rest = np.concatenate([h.constraint_rest_rotation[first], np.tile([0.0, 0.0, 0.0, 1.0], (nd, 1))])
        self.coordinate_rest_rotation = _array(rest, wp.quatd, d)

        # Rows on a coordinate in the correction loop: each limit, each distance constraint, then each stiff
        # motor (bounds unused); limit_joint is each row's joint, -1 for a distance constraint.
        limits = np.asarray(limit_joint, np.int64)
        h.limit_joint = np.concatenate([limits, np.full(nd, -1), h.drive_joint[stiff]]).astype(np.int64)
        h.limit_coordinate = np.concatenate([row_of[limits], len(self.coordinate_joint) + np.arange(nd),
                                             row_of[h.drive_joint[stiff]]]).astype(np.int64)  # fmt: skip
        h.limit_bounds = np.concatenate([np.asarray(limit_bounds, np.float64).reshape(-1, 2),
                                         h.distance_bounds,
                                         np.zeros((len(stiff), 2))])  # fmt: skip
        h.limit_drive = np.concatenate([np.full(len(limits) + nd, -1), stiff]).astype(np.int64)  # -1: no motor
        self.limit_count = len(h.limit_coordinate)

        mode = np.asarray(drive_mode, np.int32)
        gains = np.asarray(drive_gains, np.float64).reshape(-1, 3).copy()
        gains[mode == 1, 2] = 0.0  # velocity mode has no derivative term
        gains[mode == 2] = 0.0  # effort mode: the target is the output
        gains[stiff] = 0.0  # a stiff motor is no PID
        # drive_* arrays are over every drive (targets and integrals are per drive); the force elements are
        # the drives listed in drive_element.
        self.drive_element = _array(forced, wp.int32, d)
        self.drive_coordinate = _array(row_of[h.drive_joint], wp.int32, d)
        h.drive_chain, h.drive_ends = (np.asarray(x, np.int64).reshape(-1, n) for x, n in zip(chains, (3, 2)))
        if not len(h.drive_chain):  # no chains: none, the joint's own anchor, its parent and child
            h.drive_chain = np.stack([np.full(len(h.drive_joint), -1), np.full(len(h.drive_joint), -1),
                                      h.drive_joint], axis=1).reshape(-1, 3)  # fmt: skip
            h.drive_ends = np.stack([h.joint_parent[h.drive_joint], h.joint_child[h.drive_joint]], axis=1).reshape(
                -1, 2
            )
        rows_of = np.append(row_of, -1)  # joint -1 -> row -1
        self.drive_chain = _array(rows_of[h.drive_chain].astype(np.int32), wp.vec3i, d)
        self.drive_ends = _array(h.drive_ends.astype(np.int32), wp.vec2i, d)
        # The coordinate rows the force drives read (`forces.coordinate_geometry`), and whether a drive reads the
        # row's point: every row but a hinge's that no force (a drive on a slider or distance) acts at.
        own, chain = row_of[h.drive_joint[forced]], rows_of[h.drive_chain[forced]]
        read = np.unique(np.concatenate([own, chain.reshape(-1)]))
        read = read[read >= 0]
        forces = kinds[own] != COORDINATES["revolute"]
        pointed = np.union1d(own[forces], chain[forces, 2])
        self.drive_rows = _array(read, wp.int32, d)
        self.drive_row_point = _array((kinds[read] != COORDINATES["revolute"]) | np.isin(read, pointed), wp.int32, d)
        self.drive_mode = _array(mode, wp.int32, d)
        self.drive_gains = _array(gains, wp.vec3d, d)
        self.drive_max_force = _array(np.asarray(drive_max_force, np.float64), wp.float64, d)
        self.limit_coordinate = _array(h.limit_coordinate, wp.int32, d)
        self.limit_bounds = _array(h.limit_bounds, wp.vec2d, d)
        self.limit_drive = _array(h.limit_drive, wp.int32, d)

        # The wrench rows of the force elements on each body: 2 e + side, springs first, then drives.
        ends = np.stack([np.concatenate([h.spring_body0, h.drive_ends[forced, 0]]),
                         np.concatenate([h.spring_body1, h.drive_ends[forced, 1]])], axis=1).reshape(-1)  # fmt: skip
        rows = np.flatnonzero(ends >= 0)  # row 2 e + side on body ends[row]
        rows = rows[np.argsort(ends[rows], kind="stable")]  # by body, each body's in row order
        self.element_count = len(ends) // 2
        per_body = np.bincount(ends[rows], minlength=self.body_count)
        self.body_wrench_start = _array(np.concatenate([[0], np.cumsum(per_body)]), wp.int32, d)
        self.body_wrench_rows = _array(rows, wp.int32, d)

    def set_masses(self, mass: np.ndarray, inertia: np.ndarray) -> None:
        """Every body's mass (kg) and inertia ((n, 3, 3) kg m^2, body frame about the centre of mass), on the
        host and the device (inverses included, and what the lane prediction reads instead of the inertia:
        `rigid.principal_terms`); static bodies keep zero inverses. Checked by the caller
        (`Simulator.set_masses`, the builder)."""
        h, dynamic = self.host, ~self.host.body_static
        h.body_mass[:] = mass
        h.body_inertia[:] = inertia
        inv_inertia = np.zeros_like(h.body_inertia)
        inv_inertia[dynamic] = np.linalg.inv(h.body_inertia[dynamic])
        self.body_inv_mass.assign(np.where(dynamic, 1.0 / np.where(dynamic, h.body_mass, 1.0), 0.0))
        self.body_inertia.assign(h.body_inertia)
        self.body_inv_inertia.assign(inv_inertia)
        moments, axes = principal_axes(h.body_inertia, dynamic)
        self.body_axes.assign(axes)
        wp.launch(
            rigid_kernels.principal_terms, self.body_count,
            inputs=[self.body_inertia, self.body_inv_inertia, wp.array(moments, dtype=wp.vec3d, device=self.device)],
            outputs=[self.body_principal, self.body_euler, self.body_inv_principal], device=self.body_inertia.device,
        )  # fmt: skip

    def state(self) -> State:
        """A new State at the initial poses and velocities."""
        h, d = self.host, self.device
        return State(
            body_x=_array(h.body_x, wp.vec3d, d),
            body_q=_array(h.body_q, wp.quatd, d),
            body_v=_array(h.body_v, wp.vec3d, d),
            body_w=_array(h.body_w, wp.vec3d, d),
        )

    def control(self) -> Control:
        """A new Control with no load."""
        zeros = np.zeros((self.body_count, 3))
        return Control(
            body_force=_array(zeros, wp.vec3d, self.device), body_torque=_array(zeros, wp.vec3d, self.device)
        )

    def worlds(self, start: int, stop: int) -> Model:
        """A Model of worlds [start, stop) of this one, with their current masses (`Simulator.set_masses`): the
        simulator steps a world alone this way, and a thread steps its share of the worlds."""
        if not 0 <= start < stop <= self.world_count:
            raise ValueError(f"worlds [{start}, {stop}) do not exist ({self.world_count} worlds)")
        if self.limit_count:
            raise ValueError("a model with limits, distance constraints or stiff motors does not split into worlds")
        h, count = self.host, stop - start

        def rows(values, per_world: int):
            return values[start * per_world : stop * per_world]

        def shifted(indices, per_world: int):  # body indices into the new model; WORLD stays
            i = rows(indices, per_world)
            return np.where(i >= 0, i - start * self.world_body_count, i)

        nb, nc, nj = self.world_body_count, self.world_constraint_count, self.world_joint_count
        nf = len(h.force_body) // self.world_count
        ns, nd = self.spring_count // self.world_count, self.drive_count // self.world_count
        return Model(
            self.device,
            gravity=h.gravity,
            body_name=rows(self.body_name, nb),
            **{
                f"body_{k}": rows(getattr(h, f"body_{k}"), nb)
                for k in ("mass", "inertia", "static", "x", "q", "v", "w")
            },  # fmt: skip
            constraint_kind=rows(h.constraint_kind, nc),
            constraint_body0=shifted(h.constraint_body0, nc),
            constraint_body1=shifted(h.constraint_body1, nc),
            **{
                f"constraint_{k}": rows(getattr(h, f"constraint_{k}"), nc)
                for k in ("anchor0", "anchor1", "axis0", "axis1", "rest_rotation", "rest_angle")
            },  # fmt: skip
            constraint_joint=rows(self.constraint_joint, nc) - start * nj,
            joint_name=rows(self.joint_name, nj),
            joint_type=rows(self.joint_type, nj),
            joint_parent=shifted(h.joint_parent, nj),
            joint_child=shifted(h.joint_child, nj),
            joint_constraint_start=np.append(rows(h.joint_constraint_start[:-1], nj), stop * nc) - start * nc,
            force_body=shifted(h.force_body, nf),
            force_force=rows(h.force_force, nf),
            force_torque=rows(h.force_torque, nf),
            force_until=rows(h.force_until, nf),
            world_count=count,
            joint_loop=rows(h.joint_loop, nj) if len(h.joint_loop) else (),
            spring_name=rows(self.spring_name, ns),
            spring_body0=shifted(h.spring_body0, ns),
            spring_body1=shifted(h.spring_body1, ns),
            **{f"spring_{k}": rows(getattr(h, f"spring_{k}"), ns) for k in ("anchor0", "anchor1", "params")},
            drive_name=rows(self.drive_name, nd),
            drive_joint=rows(h.drive_joint, nd) - start * nj,
            **{
                f"drive_{k}": rows(getattr(h, f"drive_{k}"), nd)
                for k in ("mode", "target", "gains", "max_force", "motor", "stiff")
            },  # fmt: skip
            drive_chain=np.where(rows(h.drive_chain, nd) >= 0, rows(h.drive_chain, nd) - start * nj, -1),
            drive_ends=shifted(h.drive_ends, nd),
        )

    def joint_constraints(self, joint: int) -> range:
        """The indices of the basic constraints of `joint`."""
        start = self.host.joint_constraint_start
        return range(int(start[joint]), int(start[joint + 1]))
