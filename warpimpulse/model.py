"""Model (static arrays on the device), State (body poses and velocities) and Control (forces)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .builder import SceneBuilder
from .joints import ConstraintKind
from .topology import Topology, analyze


def _array(values, dtype, device) -> wp.array:
    return wp.array(np.ascontiguousarray(values), dtype=dtype, device=device)


@dataclass
class State:
    x: wp.array  # centre of mass, world
    q: wp.array  # orientation (x, y, z, w)
    v: wp.array  # linear velocity, world
    w: wp.array  # angular velocity, world

    def copy_from(self, other: State) -> None:
        for name in ("x", "q", "v", "w"):
            wp.copy(getattr(self, name), getattr(other, name))


@dataclass
class Control:
    force: wp.array  # world force at the centre of mass, constant over a step
    torque: wp.array  # world torque


class Model:
    """Everything about a scene that does not change while it runs, as device arrays."""

    def __init__(self, builder: SceneBuilder, topology: Topology, device) -> None:
        self.builder = builder
        self.device = wp.get_device(device)
        self.topology = topology
        self.body_count = len(builder.bodies)
        self.joint_count = len(builder.joints)
        self.constraint_count = len(builder.constraints)
        self.gravity = wp.vec3d(*builder.gravity)
        d = self.device
        bodies, cons = builder.bodies, builder.constraints

        mass = np.array([b.mass for b in bodies])
        inertia = np.array([b.inertia for b in bodies]).reshape(-1, 3, 3)
        dynamic = np.array([not b.static for b in bodies])
        inv_inertia = np.zeros_like(inertia)
        inv_inertia[dynamic] = np.linalg.inv(inertia[dynamic])
        self.body_mass = mass
        self.body_inv_mass = _array(np.where(dynamic, 1.0 / np.where(dynamic, mass, 1.0), 0.0), wp.float64, d)
        self.body_inertia = _array(inertia, wp.mat33d, d)
        self.body_inv_inertia = _array(inv_inertia, wp.mat33d, d)

        self.kinds = sorted({ConstraintKind(c.kind) for c in cons})
        self.constraint_kind = _array([int(c.kind) for c in cons], wp.int32, d)
        self.constraint_body0 = _array([c.body0 for c in cons], wp.int32, d)
        self.constraint_body1 = _array([c.body1 for c in cons], wp.int32, d)
        self.constraint_anchor0 = _array([c.anchor0 for c in cons], wp.vec3d, d)
        self.constraint_anchor1 = _array([c.anchor1 for c in cons], wp.vec3d, d)
        self.constraint_axis0 = _array([c.axis0 for c in cons], wp.vec3d, d)
        self.constraint_axis1 = _array([c.axis1 for c in cons], wp.vec3d, d)
        self.constraint_rest_rotation = _array([c.rest_rotation for c in cons], wp.quatd, d)
        self.constraint_rest_angle = _array([c.rest_angle for c in cons], wp.float64, d)
        self.constraint_joint = np.array([c.joint for c in cons], dtype=np.int64)
        self.body_rows_start = _array(topology.body_rows_start, wp.int32, d)
        self.body_rows = _array(topology.body_rows, wp.int32, d)

    @classmethod
    def from_builder(cls, builder: SceneBuilder, device=None) -> Model:
        device = wp.get_device(device)
        return cls(builder, analyze(builder, level_order=device.is_cuda), device)

    def state(self) -> State:
        """A new State at the builder's initial poses and velocities."""
        b, d = self.builder.bodies, self.device
        return State(
            x=_array([x.position for x in b], wp.vec3d, d),
            q=_array([x.orientation for x in b], wp.quatd, d),
            v=_array([x.linear_velocity for x in b], wp.vec3d, d),
            w=_array([x.angular_velocity for x in b], wp.vec3d, d),
        )

    def control(self) -> Control:
        zeros = np.zeros((self.body_count, 3))
        return Control(force=_array(zeros, wp.vec3d, self.device), torque=_array(zeros, wp.vec3d, self.device))
