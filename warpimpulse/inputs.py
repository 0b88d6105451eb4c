"""What a user sets on a simulator between steps: loads, masses and inertias, motor targets, actuator controls.

Each setter runs the builder's checks (`checks.py`) and names the body, joint or actuator at fault; with batched
worlds each takes `world=` or a leading world dimension."""

from __future__ import annotations

import math

import numpy as np

from . import checks
from .worlds import WorldStats


class Inputs:
    """The setters of a `Simulator` (a part of it: they write its Control, masses and targets, checked)."""

    def set_external_forces(self, force=None, torque=None, world: int | None = None) -> None:
        """World forces (N, at the centres of mass) and torques (N m), (n, 3) each, held until set again; with
        batched worlds (W, n, 3) for all of them, or (n, 3) for one `world`."""
        if force is not None:
            rows, values = self._world_values(force, "force", world)
            self._user_force = self._user_force.copy()
            self._user_force[rows] = values
        if torque is not None:
            rows, values = self._world_values(torque, "torque", world)
            self._user_torque = self._user_torque.copy()
            self._user_torque[rows] = values
        self._active_forces = None

    def _world_values(self, values, what: str, world: int | None, shape=(3,)) -> tuple[slice, np.ndarray]:
        """The body rows of `world` (all when None) and `values` checked for them, flattened to (rows, *shape):
        (n, *shape) for one world or a one-world model, (W, n, *shape) for all batched worlds. A bad value names
        its body."""
        m = self.model
        if world is None:
            lead = (m.body_count,) if m.world_count == 1 else (m.world_count, m.world_body_count)
            rows = slice(None)
        else:
            lead, rows = (m.world_body_count,), self._world_rows(world)
        arr = checks.numbers(values, what)
        if arr.shape != (*lead, *shape):
            raise ValueError(f"{what} must have shape {(*lead, *shape)}, got {arr.shape}")
        arr = arr.reshape(-1, *shape)
        names = m.body_name[rows]
        checks.finite_rows({what: arr.reshape(len(arr), -1)}, lambda i: f"body {names[i]!r}:")
        return rows, arr

    def _world_rows(self, world: int) -> slice:
        """The body rows of `world`, checked."""
        m = self.model
        if isinstance(world, (bool, np.bool_)) or not isinstance(world, (int, np.integer)):
            raise ValueError(f"a world index is expected, got {world!r}")
        if not 0 <= int(world) < m.world_count:
            raise ValueError(f"world {world} does not exist ({m.world_count} worlds)")
        return slice(int(world) * m.world_body_count, (int(world) + 1) * m.world_body_count)

    def _per_world(self, values: np.ndarray, world: int | None) -> np.ndarray:
        """Per-body values as the accessors give them: (n, ...) for one `world` or a one-world model, else
        with a leading world dimension (W, n, ...)."""
        m = self.model
        if world is not None:
            return values[self._world_rows(world)]
        return values if m.world_count == 1 else values.reshape(m.world_count, m.world_body_count, *values.shape[1:])

    @property
    def stopped(self) -> dict[int, str]:
        """Batched worlds that have stopped, by index, with why (the others go on); empty for one world."""
        return self.batch.stopped if self.batch is not None else {}

    @property
    def world_stats(self) -> WorldStats | None:
        """Each batched world's figures of the last step (None for one world)."""
        return self.batch.stats if self.batch is not None else None

    def set_masses(self, mass=None, inertia=None, world: int | None = None) -> None:
        """Change bodies' masses (kg) and inertias (kg m^2, body frame about the centre of mass: (3, 3) tensors
        or 3 principal moments) without rebuilding: (n,) and (n, 3, 3) or (n, 3), with a leading world
        dimension for all batched worlds, or for one `world`. Static bodies keep theirs (values there are
        ignored). The factorization is refreshed at once."""
        m = self.model
        masses, inertias = m.host.body_mass.copy(), m.host.body_inertia.copy()
        if mass is not None:
            rows, values = self._world_values(mass, "mass", world, shape=())
            masses[rows] = values
        if inertia is not None:
            arr = np.asarray(inertia, dtype=np.float64)
            if arr.shape[-1:] == (3,) and arr.shape[-2:] != (3, 3):
                arr = arr[..., :, None] * np.eye(3)  # principal moments
            rows, values = self._world_values(arr, "inertia", world, shape=(3, 3))
            inertias[rows] = values
        dynamic = ~m.host.body_static
        checks.mass_properties(masses, inertias, dynamic, lambda b: f"set_masses: body {m.body_name[b]!r}")
        inertias = 0.5 * (inertias + inertias.transpose(0, 2, 1))  # symmetric to the last bit, as the builder's
        masses[~dynamic], inertias[~dynamic] = 0.0, 0.0
        m.set_masses(masses, inertias)
        if self.batch is not None:
            self.batch.forget(range(m.world_count) if world is None else [world])
        self._update_frames()

    def set_motor_target(self, motor: int, target: float) -> None:
        """The target of a motor (`SceneBuilder.add_motor`'s index): rad or m in position mode, rad/s or m/s
        in velocity mode; held until set again."""
        m = self.model
        motors = np.flatnonzero(m.host.drive_motor)
        if isinstance(motor, bool) or not isinstance(motor, (int, np.integer)) or not 0 <= motor < len(motors):
            raise ValueError(f"motor {motor!r} does not exist ({len(motors)} motors)")
        drive = int(motors[motor])
        target = float(target)
        if not math.isfinite(target):
            raise ValueError(f"motor {motor} ({m.drive_name[drive]!r}): target must be finite, got {target}")
        self._write_targets(drive, target)

    def set_controls(self, values) -> None:
        """Set actuators' inputs as MuJoCo's `ctrl` does (`SceneBuilder.add_actuator`, `load_mjcf`): `values` is
        one number per actuator in order, or {name or index: value} for some of them (the others keep theirs).
        Each sets its motor's target to gain * clip(value, ctrl range) + bias, held until set again."""
        m = self.model
        names, h = m.actuator_name, m.host
        if not isinstance(values, dict):  # every actuator at once, as a controller sets them each tick
            arr = checks.numbers(values, "set_controls: values").reshape(-1)
            if len(arr) != len(names):
                raise ValueError(f"set_controls: {len(names)} actuators, got {len(arr)} values")
            bad = np.flatnonzero(~np.isfinite(arr))
            if len(bad):
                raise ValueError(f"set_controls: actuator {names[bad[0]]!r}: control must be finite, got {arr[bad[0]]}")
            self._set_targets(h.actuator_drive, arr, h.actuator_map.T)
            return
        rows, controls = [], []
        for key, value in values.items():
            if isinstance(key, str):
                if key not in names:
                    raise ValueError(f"set_controls: no actuator named {key!r}")
                key = names.index(key)
            if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or not 0 <= key < len(names):
                raise ValueError(f"set_controls: actuator {key!r} does not exist ({len(names)} actuators)")
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f"set_controls: actuator {names[key]!r}: control must be finite, got {value}")
            rows.append(int(key))
            controls.append(value)
        self._set_targets(h.actuator_drive[rows], np.array(controls), h.actuator_map[rows].T)

    def _set_targets(self, drives: np.ndarray, controls: np.ndarray, actuators: np.ndarray) -> None:
        """The `drives`' targets from their actuators' `controls`: gain * clip(control, ctrl range) + bias, with
        `actuators` the rows (gain, bias, low, high) of `Model.host.actuator_map`; written in place on a CPU."""
        gain, bias, low, high = actuators
        self._write_targets(drives, gain * np.clip(controls, low, high) + bias)

    def _target_values(self) -> np.ndarray:
        """The drives' targets: a view of their array on a CPU (written in place), a copy from a GPU."""
        return self._targets if self._targets is not None else self.drive_target.numpy()

    def _write_targets(self, drives, values) -> None:
        """Drive targets set (in place through their CPU array's view; assigned on a GPU), then whether the force
        elements act (`Simulator._follow_elements`)."""
        targets = self._target_values()
        targets[drives] = values
        if self._targets is None:
            self.drive_target.assign(targets)
        self._follow_elements()

    def forces_active(self) -> bool:
        """Whether something does work on the bodies in the coming step, so that `energy()` is not conserved:
        an external force or torque (the model's, before its `until`, or one set with `set_external_forces`),
        or a motor."""
        m = self.model
        return bool(np.any(m.host.drive_motor) or np.any(self.time < m.host.force_until)
                    or np.any(self._user_force) or np.any(self._user_torque))  # fmt: skip

    def _update_forces(self) -> None:
        """The Control of this step: the user's loads plus the model's forces still active (t < until)."""
        h = self.model.host
        if not self._forces_timed and self._active_forces is not None:  # no model forces: ~1 us a call saved
            return
        active = self.time < h.force_until
        key = tuple(active.tolist())
        if key == self._active_forces:
            return
        self._active_forces = key
        force, torque = self._user_force.copy(), self._user_torque.copy()
        np.add.at(force, h.force_body[active], h.force_force[active])
        np.add.at(torque, h.force_body[active], h.force_torque[active])
        self.control.body_force.assign(force)
        self.control.body_torque.assign(torque)
