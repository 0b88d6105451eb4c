"""How a step that fails is said: the iteration policy, divergence, degenerate loops, runaway loads, NaN.

A correction that runs out of iterations or diverges raises a SimulationError (or warns, `on_max_iterations`)
naming the step, the error left and the worst joints; a non-finite state names its bodies; a load that alone
would fling a body is named as the cause."""

from __future__ import annotations

import warnings

import numpy as np

from . import diagnose
from .model import State
from .solver import SingularSystemError
from .steps import SimulationError, diverging
from .transforms import quat_from_axis_angle, quat_mul


class Failures:
    """How a `Simulator` says a failing step (a part of it: it reads the simulator's errors and state)."""

    def _may_iterate(
        self, iterations: int, error: float, what: str, best: float, final: bool, stopped: bool = False,
        sweeps: int = 0, counted: bool = False,
    ) -> bool:  # fmt: skip
        """Whether the correction may take another iteration. On its limit, or when it diverges (the error
        grew 1000-fold over the best this step): False, and on the `final` try raise or warn naming the
        worst joints. `stopped`: a correction that is not an iteration to a limit stopped over its tolerance
        (the velocity correction's solve), said as such, with its `sweeps` where it took some. `counted`: the
        step is already on the clock (a velocity correction taken when the state is read, `Simulator.state`)."""
        diverges = diverging(error, best, iterations)
        if iterations < self.max_iterations and not diverges:
            return True
        if not final:
            return False
        if self.linear is None:  # the sweeps keep no per-constraint errors: measure them
            self._predict.launch()
            (self._position_errors if what == "joint" else self._velocity_errors).launch()
        joints = self.joint_errors_from(self.errors.numpy())
        bad = [j for j in np.argsort(joints)[::-1][:5] if joints[j] > 0]
        worst = ", ".join(f"{self.model.joint_name[j]!r} ({joints[j]:.3g})" for j in bad)
        tolerance = self.tolerance if what == "joint" else self.velocity_tolerance
        hint = (
            diagnose.mass_ratio_note(self.model)
            or "a smaller dt, a looser tolerance or smaller mass ratios between jointed bodies may help"
        )
        failure = f"did not reach {tolerance:g} in {self.max_iterations} iterations (max error {error:.3g})"
        if not diverges and what == "velocity" and self.linear is None:  # the iterative solver's, either schedule
            stopped, sweeps = True, sweeps or iterations
        if stopped:
            after = f" after {sweeps} sweep{'s' if sweeps != 1 else ''}" if sweeps else ""
            failure = f"left {error:.3g}{after}, over its tolerance of {tolerance:g}"
        elif diverges:
            failure = (f"diverged after {iterations} iterations (error grew from {best:.3g} to {error:.3g}, with the "
                       f"step halved {self.max_substep_depth} times already; {hint})")  # fmt: skip
        step, time = (self.step_count, self.time) if counted else (self.step_count + 1, self.time + self.dt)
        msg = f"step {step} (t = {time:.6g} s): the {what} correction {failure}"
        if worst:
            msg += f"; worst joints: {worst}"
        runaway = self._runaway_note()  # the cause, where a load no joint can hold is one
        if runaway:
            msg += f"; {runaway}"
        if self.on_max_iterations == "raise":
            raise SimulationError(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=3)
        return False

    def _check_loops(self) -> None:
        """Refuse a degenerate loop at build (`diagnose.degenerate_loop`): one whose redundant rows, regularised
        by the factorization as if consistent, are stretched by a motion they allow to first order, so that the
        correction could never converge. J comes from the velocity-error kernel at unit velocities, and at poses
        moved along the allowed motions; the built state and its factor are restored. Scenes of more than
        `diagnose.LOOP_CHECK_DOFS` dynamic degrees of freedom are not checked (a dense SVD)."""
        m, st = self.model, self._state
        dynamic = np.flatnonzero(~m.host.body_static)
        if not 0 < 6 * len(dynamic) <= diagnose.LOOP_CHECK_DOFS:
            return
        x0, q0 = st.body_x.numpy(), st.body_q.numpy()
        length = diagnose.length_scale(m)

        def times(u: np.ndarray) -> np.ndarray:  # J u, u in m/s (angular ones times the length scale)
            v, w = np.zeros((m.body_count, 3)), np.zeros((m.body_count, 3))
            v[dynamic], w[dynamic] = u.reshape(-1, 6)[:, :3], u.reshape(-1, 6)[:, 3:] / length
            st.body_v.assign(v)
            st.body_w.assign(w)
            self._velocity_errors.launch()
            return -self.rhs.numpy().reshape(-1)

        def moved(u: np.ndarray | None, s: float):  # the pose moved by s length scales along u
            x, q = x0.copy(), q0.copy()
            if u is not None:
                x[dynamic] += s * length * u.reshape(-1, 6)[:, :3]
                turn = s * u.reshape(-1, 6)[:, 3:]
                for k, b in enumerate(dynamic):
                    angle = float(np.linalg.norm(turn[k]))
                    if angle > 0.0:
                        q[b] = quat_mul(quat_from_axis_angle(turn[k], angle), q[b])
            st.body_x.assign(x)
            st.body_q.assign(q)
            self._frames.launch()
            return times

        try:
            note = diagnose.degenerate_loop(m, times, moved, 6 * len(dynamic))
        finally:
            self._state.copy_from(m.state())
            self._update_frames()
        if note:
            raise SingularSystemError(note)

    def _runaway_note(self) -> str:
        """`diagnose.runaway_note` of this step's loads."""
        force, torque = self.control.body_force.numpy(), self.control.body_torque.numpy()
        return diagnose.runaway_note(self.model, self.dt, force, torque)

    def _check_finite(self, state: State, step: int) -> None:
        """Counted on the device (two numbers come back); only a failure reads the state to name the bodies."""
        self.summary.zero_()
        self._check_states[id(state)].launch()
        self._report_nonfinite(state, step)
        if self.batch is not None:
            self.batch.measure(state)

    def _report_nonfinite(self, state: State, step: int) -> None:
        count, spin = self.summary.numpy()
        if not count:
            self._spin = float(spin)
            return
        # The device sums each body's squared components: a NaN, an Inf, or a value whose square overflows
        # (|x| > ~1e154, finite yet beyond arithmetic) counts. Recount the same way here to name those bodies.
        arrays = [
            a.numpy().reshape(self.model.body_count, -1)
            for a in (state.body_x, state.body_q, state.body_v, state.body_w)
        ]
        with np.errstate(over="ignore", invalid="ignore"):
            sums = sum(np.sum(a * a, axis=1) for a in arrays)
        bad = np.flatnonzero(~np.isfinite(sums))
        if not bad.size:  # a sum at the edge of overflow rounded the other way: the largest is the culprit
            bad = np.array([int(np.argmax(sums))])
        names = ", ".join(repr(self.model.body_name[b]) for b in bad[:10])
        if all(np.isfinite(a[bad]).all() for a in arrays):
            kind = f"values up to {max(np.abs(a[bad]).max() for a in arrays):.3g}, too large to square"
        else:
            kind = "NaN or Inf"
        raise SimulationError(
            f"step {step}: the simulation diverged ({kind}) in {bad.size} bod{'y' if bad.size == 1 else 'ies'}: {names}"
        )
