"""Checkpoints: a simulator's state saved to a file and loaded back bit for bit, or refused whole.

A checkpoint holds the state, the clock, the drives' integrals, the carried right-hand sides and the scene's
fingerprint (`diagnose.fingerprint`: bodies, joints, every force element, limit, row and contact setting);
every check runs before anything is assigned, so a refused load leaves the simulator as it was."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np
import warp as wp

from . import checks, diagnose
from .files import write_atomically
from .kernels import carry as carry_kernels

STATE = ("x", "q", "v", "w")  # the state arrays in a checkpoint (State.body_x, ...)


class CheckpointError(ValueError):
    """A checkpoint that cannot be loaded into this simulator; the message names the file and the reason."""


class Checkpoints:
    """Checkpoints of a `Simulator` (a part of it: its state, clock and fingerprint to a file and back)."""

    def save_checkpoint(self, path) -> None:
        """Write the full state to an .npz file; `load_checkpoint` continues bit-identically.

        The file also holds the scene's fingerprint (`diagnose.fingerprint`), so that a checkpoint is never
        loaded into another scene of the same body count. Written as the output files are
        (`files.write_atomically`): a failed write raises WriteError and leaves the previous checkpoint."""
        # The state as the steps left it: a velocity correction still due (`Simulator.state`) is saved as due, so
        # that neither saving nor resuming changes the trajectory.
        data = {name: getattr(self._state, f"body_{name}").numpy() for name in STATE}
        data.update(time=self.time, step_count=self.step_count, user_force=self._user_force,
                    handout_due=bool(self._handout),
                    user_torque=self._user_torque, dt=self.dt, bodies=self.model.body_count,
                    stages=np.array(self.scheme.stages), fallback=self._fallback,
                    drive_target=self.drive_target.numpy(), drive_integral=self.drive_integral.numpy())  # fmt: skip
        data.update({f"scene_{key}": np.array(value) for key, value in self._fingerprint.items()})
        for key, arr in getattr(self.linear, "_warm", {}).items():
            data[f"warm_{key}"] = arr.numpy()
        if self.carry:  # the first iterations' carried right-hand sides and their past, a row a (step size, stage)
            carries = self._carries()
            data.update(carry_h=np.array([h for h, _ in carries]), carry_stage=np.array([k for _, k in carries]),
                        carry=np.stack([c.numpy() for c, *_ in carries.values()]),
                        carry_past=np.stack([[p.numpy() for p in past] for _, *past in carries.values()]))  # fmt: skip
        if self.reuse_factor:  # the factor in use may be of an earlier state (`reuse_factor`): kept as it is
            data.update(factor=self.linear.values.numpy(), factor_state=self._factor_state.numpy())
        write_atomically(path, lambda tmp: np.savez(tmp, **data), ".npz")

    def load_checkpoint(self, path) -> None:
        """Continue from a checkpoint of this scene. Everything in the file is read and checked before any of
        it is assigned: a refused or unreadable checkpoint raises CheckpointError (a ValueError naming the
        file) and leaves the simulator as it was."""
        path = Path(path)
        data = self._read_checkpoint(path)
        for name in STATE:
            getattr(self._state, f"body_{name}").assign(data[name])
        if "drive_target" in data:  # motors' targets and PID integrals; whether an element acts decides the step
            self._handout = False
            self.drive_target.assign(data["drive_target"])
            self.drive_integral.assign(data["drive_integral"])
            self._follow_elements()
        due = bool(data.get("handout_due", False))  # older files hold handed-out states
        self._handout = due and self.defer_velocities
        self.time, self.step_count = float(data["time"]), int(data["step_count"])
        self._clock = (0.0, 0) if self.accuracy is None else (self.time, self.step_count)
        if self.accuracy is not None:
            self.accuracy.reset()
        self._user_force, self._user_torque = data["user_force"], data["user_torque"]
        self._fallback = str(data["fallback"]) if "fallback" in data else ""
        warm = getattr(self.linear, "_warm", None)  # CG warm starts; another solver's are not used
        if warm is not None:
            warm.clear()
            for key in data:
                if key.startswith("warm_"):
                    warm[key[5:]] = wp.array(data[key], dtype=wp.vec3d, device=self.model.device)
        self._forget_carry()
        if self.carry and "carry" in data:
            sizes = data["carry_h"].tolist()  # an older checkpoint has no stages: the first stage of each size
            stages = data["carry_stage"].tolist() if "carry_stage" in data else [0] * len(sizes)
            for k, (h, stage, c) in enumerate(zip(sizes, stages, data["carry"])):
                mine = self._carries_of((h, stage))
                mine[0].assign(c)
                if "carry_past" in data:  # else (an older checkpoint) unknown: c is extrapolated once it is known
                    for p, past in zip(mine[1:], data["carry_past"][k]):
                        p.assign(past)
        self._active_forces = None
        self._update_frames()
        if due and not self.defer_velocities:  # a state saved with its velocity correction due, resumed here
            self._correct_velocities()
        if self.reuse_factor and "factor" in data:  # the factor the run went on with, not one of this state
            self.linear.values.assign(data["factor"])
            self._factor_state.assign(data["factor_state"])
        self._check_finite(self._state, self.step_count)  # and the spin that sets the next step's substeps

    def _read_checkpoint(self, path: Path) -> dict[str, np.ndarray]:
        """Every array of the checkpoint at `path`, checked against this simulator."""

        def refuse(why: str) -> CheckpointError:
            return CheckpointError(f"{path}: {why}")

        try:
            npz = np.load(path, allow_pickle=False)
            if not isinstance(npz, np.lib.npyio.NpzFile):  # a lone .npy array
                raise ValueError(path)
            with npz:
                data = {key: npz[key] for key in npz.files}
        except FileNotFoundError:
            raise refuse("no such checkpoint file") from None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as err:  # ValueError: pickled data
            why = err.strerror if isinstance(err, OSError) and err.strerror else "truncated, corrupt or another format"
            raise refuse(f"not a readable warpimpulse checkpoint ({why})") from None
        n, nc = self.model.body_count, self.model.constraint_count
        shapes = {"x": (n, 3), "q": (n, 4), "v": (n, 3), "w": (n, 3), "user_force": (n, 3), "user_torque": (n, 3),
                  "time": (), "step_count": (), "dt": (), "bodies": ()}  # fmt: skip
        missing = [key for key in (*shapes, *(f"scene_{k}" for k in self._fingerprint)) if key not in data]
        if missing:
            raise refuse(f"not a warpimpulse checkpoint of this version: it has no {', '.join(missing)}")
        for key, shape in shapes.items():  # scalars first: the body count and dt make the clearest message
            if data[key].dtype.kind not in "iuf" or (shape == () and data[key].shape != ()):
                raise refuse(f"'{key}' is not {'a number' if shape == () else 'an array of numbers'}")
        if int(data["bodies"]) != n or float(data["dt"]) != self.dt:
            raise refuse(
                f"checkpoint of {int(data['bodies'])} bodies at dt={float(data['dt'])} does not match this "
                f"simulator ({n} bodies, dt={self.dt})"
            )
        for key, digest in self._fingerprint.items():
            theirs = str(data[f"scene_{key}"])
            if theirs != digest:
                count, here = theirs.split(":")[0], digest.split(":")[0]
                how = f"{count} in the checkpoint, {here} here" if count != here else f"{here}, with other values"
                raise refuse(f"checkpoint of another scene: its {diagnose.FINGERPRINT_PARTS[key]} differ from this "
                             f"simulator's ({how})")  # fmt: skip
        if "stages" in data and (data["stages"].dtype.kind != "f" or data["stages"].ndim != 1):
            raise refuse("'stages' is not a list of numbers")
        stages = tuple(float(g) for g in data["stages"]) if "stages" in data else (1.0,)
        if stages != self.scheme.stages:
            raise refuse(
                f"checkpoint taken with the composition {stages} of the base step; this simulator composes "
                f"{self.scheme.stages} (order {self.order}): resuming would not continue the run"
            )
        nd = self.model.drive_count
        shapes.update(drive_target=(nd,), drive_integral=(nd,))
        for key, shape in shapes.items():
            if key not in data:  # a checkpoint of a version without motors' targets: they stay as they are
                continue
            if data[key].dtype.kind not in "iuf":
                raise refuse(f"'{key}' is not an array of numbers")
            if data[key].shape != shape:
                raise refuse(f"'{key}' has shape {data[key].shape}, expected {shape}")
            if not np.all(np.isfinite(data[key])):
                raise refuse(f"'{key}' contains NaN or Inf")
            if np.abs(data[key]).max(initial=0.0) > checks.LARGEST:
                raise refuse(f"'{key}' holds values too large for double precision (> {checks.LARGEST:g})")
        if "fallback" in data and (data["fallback"].dtype.kind != "U" or data["fallback"].shape != ()):
            raise refuse("'fallback' is not a string")
        if data["step_count"].dtype.kind == "f" or int(data["step_count"]) < 0 or float(data["time"]) < 0.0:
            raise refuse(f"step count {data['step_count']} at time {data['time']} is not a place in a run")
        if np.abs(np.linalg.norm(data["q"], axis=1) - 1.0).max(initial=0.0) > 1e-6:
            raise refuse("an orientation is not a unit quaternion")
        for key in data:
            if key.startswith("warm_") and (data[key].dtype.kind not in "iuf" or data[key].shape != (nc, 3)
                                            or not np.all(np.isfinite(data[key]))):  # fmt: skip
                raise refuse(f"'{key}' has shape {data[key].shape} or non-finite values; expected ({nc}, 3) numbers")
        if "carry" in data:  # the carried right-hand sides (`carry`): a row of (nc, 3) for each step size
            sizes, carry = data.get("carry_h", np.zeros(0)), data["carry"]
            if (carry.dtype.kind not in "iuf" or sizes.ndim != 1 or carry.shape != (len(sizes), nc, 3)
                    or not np.all(np.isfinite(carry))):  # fmt: skip
                raise refuse(f"'carry' has shape {carry.shape} or non-finite values; expected ({len(sizes)}, {nc}, 3)")
            if not (sizes.dtype.kind == "f" and np.all(np.isfinite(sizes)) and np.all(sizes != 0.0)):
                raise refuse("'carry_h' is not a list of step sizes")
            stages = data.get("carry_stage", np.zeros(len(sizes), dtype=np.int64))
            if stages.dtype.kind not in "iu" or stages.shape != sizes.shape or np.any(stages < 0):
                raise refuse(f"'carry_stage' is not a list of {len(sizes)} stage counts (integers >= 0)")
            past = data.get("carry_past")  # the values measured in the last steps, NaN where unknown
            shape = (len(sizes), carry_kernels.PAST, nc, 3)
            if past is not None and (past.dtype.kind != "f" or past.shape != shape or np.any(np.isinf(past))):
                raise refuse(f"'carry_past' has shape {past.shape} or infinite values; expected {shape}")
        return data
