"""What a simulator's state reads as: body poses and velocities, joint coordinates, rates and errors, energy.

Accessors of `Simulator` over its State and Model, as numpy arrays in world frames and SI units (m, rad, m/s,
rad/s, J); with batched worlds each takes `world=` or returns a leading world dimension."""

from __future__ import annotations

import numpy as np

from . import coordinates
from .transforms import quat_rotate, quat_to_matrix
from .types import DRIVE_MODES


class Readout:
    """The read-outs of a `Simulator` (a part of it: it reads the simulator's State, Model and Frames)."""

    def positions(self, world: int | None = None) -> np.ndarray:
        """(n, 3) centres of mass, world frame (m)."""
        return self._per_world(self._state.body_x.numpy().copy(), world)

    def orientations(self, world: int | None = None) -> np.ndarray:
        """(n, 4) quaternions (x, y, z, w), body to world (USD's Gf.Quat constructors take w first)."""
        return self._per_world(self._state.body_q.numpy().copy(), world)

    def linear_velocities(self, world: int | None = None) -> np.ndarray:
        """(n, 3) centre-of-mass velocities, world frame (m/s)."""
        return self._per_world(self.state.body_v.numpy().copy(), world)

    def angular_velocities(self, world: int | None = None) -> np.ndarray:
        """(n, 3) angular velocities, world frame (rad/s)."""
        return self._per_world(self.state.body_w.numpy().copy(), world)

    def _joint_index(self, joint: int | str, world: int | None = None) -> int:
        """The model's index of `joint` (index or name); with `world`, of that world's joint of this index or
        of this name in the scene ("j3" for "world2/j3")."""
        names = self.model.joint_name
        first = 0
        if world is not None:
            first = self._world_rows(world).start // self.model.world_body_count * self.model.world_joint_count
            names = names[first : first + self.model.world_joint_count]
            if self.model.world_count > 1:
                names = [n.partition("/")[2] for n in names]
        if isinstance(joint, str):
            if joint not in names:
                raise ValueError(f"no joint named {joint!r}")
            return first + names.index(joint)
        if isinstance(joint, (bool, np.bool_)) or not isinstance(joint, (int, np.integer)):
            raise ValueError(f"a joint index or name is expected, got {joint!r}")
        if not 0 <= int(joint) < len(names):
            raise ValueError(f"joint index {joint} does not exist ({len(names)} joints)")
        return first + int(joint)

    def _state_arrays(self) -> tuple[np.ndarray, ...]:
        """Every body's position, orientation, linear and angular velocity, flat over the worlds."""
        return tuple(getattr(self.state, f"body_{k}").numpy().copy() for k in ("x", "q", "v", "w"))

    def joint_coordinates(self, joint: int | str, world: int | None = None) -> np.ndarray:
        """The joint's coordinates, zero at the build pose: a revolute's angle (rad, right-handed about its
        axis), a prismatic's offset (m), cylindrical [offset, angle], universal [angle about the parent axis,
        angle about the child axis], planar [x, y, angle] in the plane, a ball's relative rotation as a
        quaternion (x, y, z, w) in the parent's frame, a fixed joint's empty array (`coordinates.py`). With
        batched worlds, `world` picks the world and `joint` is then its index or name in the scene."""
        return coordinates.coordinates(self.model, self._joint_index(joint, world), *self._state_arrays())

    def joint_velocities(self, joint: int | str, world: int | None = None) -> np.ndarray:
        """The rates of `joint_coordinates` (rad/s, m/s); a ball joint's relative angular velocity (rad/s) in
        its parent's frame."""
        return coordinates.velocities(self.model, self._joint_index(joint, world), *self._state_arrays())

    @property
    def redundant_rows(self) -> int:
        """Constraint rows of loop-closing joints that the last factorization found redundant with the tree (a
        planar four-bar has 3): information, not an error; they are regularised (`CholeskySolver`)."""
        return getattr(self.linear, "redundant_rows", 0)

    def joint_errors_from(self, constraint_errors: np.ndarray) -> np.ndarray:
        out = np.zeros(self.model.joint_count)
        np.maximum.at(out, self.model.constraint_joint, constraint_errors)
        return out

    def joint_errors(self, world: int | None = None) -> np.ndarray:
        """The position error of every joint at the current state (max over its constraints, m or rad); with
        batched worlds (W, joints) or one `world`'s."""
        self.pred.copy_from(self._state)
        self._position_errors.launch()
        errors = self.joint_errors_from(self.errors.numpy())
        m = self.model
        if world is not None:
            w = self._world_rows(world).start // m.world_body_count
            return errors[w * m.world_joint_count : (w + 1) * m.world_joint_count]
        return errors if m.world_count == 1 else errors.reshape(m.world_count, -1)

    def _per_world_sum(self, per_body: np.ndarray, world: int | None) -> float | np.ndarray:
        """A sum over bodies, per world: a number for a one-world model or one `world`, else (W,)."""
        per_world = per_body.reshape(self.model.world_count, -1).sum(axis=1)
        if world is not None:
            return float(per_world[self._world_rows(world).start // self.model.world_body_count])
        return float(per_world[0]) if self.model.world_count == 1 else per_world

    def _kinetic_per_body(self) -> np.ndarray:
        m = self.model.host.body_mass
        _, q, v, w = self._state_arrays()
        r = quat_to_matrix(q)
        iw = np.einsum("nij,njk,nlk->nil", r, self.model.host.body_inertia, r)
        return 0.5 * m * np.sum(v * v, axis=1) + 0.5 * np.einsum("ni,nij,nj->n", w, iw, w)

    def kinetic_energy(self, world: int | None = None) -> float | np.ndarray:
        """Translational plus rotational kinetic energy, J; with batched worlds (W,) or one `world`'s."""
        return self._per_world_sum(self._kinetic_per_body(), world)

    def potential_energy(self, world: int | None = None) -> float | np.ndarray:
        """Gravity's potential energy plus the elastic energy of the springs and joint springs, J (zero for
        gravity at the world origin, for a spring at its rest length). Motors and dampers are not conservative
        and store none. With batched worlds (W,) or one `world`'s."""
        h, m = self.model.host, self.model
        x = self._state.body_x.numpy()
        gravity = np.atleast_1d(self._per_world_sum(-h.body_mass * (x @ h.gravity), None))
        springs = np.zeros(0)
        if len(h.spring_params):
            q = self._state.body_q.numpy()
            ends = []
            for body, anchor in ((h.spring_body0, h.spring_anchor0), (h.spring_body1, h.spring_anchor1)):
                world_end = body < 0  # an anchor on the world is a world point
                pose_q = np.where(world_end[:, None], [0.0, 0.0, 0.0, 1.0], q[body])
                pose_x = np.where(world_end[:, None], 0.0, x[body])
                ends.append(pose_x + quat_rotate(pose_q, anchor))
            stretch = np.linalg.norm(ends[1] - ends[0], axis=1) - h.spring_params[:, 2]
            springs = 0.5 * h.spring_params[:, 0] * stretch**2
        joint_springs = ~h.drive_motor & (h.drive_mode == DRIVE_MODES.index("position"))
        ns, nd = m.spring_count // m.world_count, m.drive_count // m.world_count  # each world's, world-major
        energy = []
        for w in range(m.world_count):
            e = float(gravity[w])
            if ns:
                e += float(np.sum(springs[w * ns : (w + 1) * ns]))
            for d in w * nd + np.flatnonzero(joint_springs[w * nd : (w + 1) * nd]):
                offset = self.joint_coordinates(int(h.drive_joint[d]))[0] - h.drive_target[d]
                e += 0.5 * float(h.drive_gains[d, 0]) * offset**2
            energy.append(e)
        if world is not None:
            return energy[self._world_rows(world).start // m.world_body_count]
        return energy[0] if m.world_count == 1 else np.array(energy)

    def energy(self, world: int | None = None) -> float | np.ndarray:
        """Kinetic plus potential energy (`potential_energy`), J: conserved by a scene without loads, motors,
        dampers or limits; with batched worlds (W,) or one `world`'s."""
        return self.kinetic_energy(world) + self.potential_energy(world)
