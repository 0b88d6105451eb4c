"""The parallel schedule: a step as stage launches and graph replays, the host deciding between them.

What a GPU runs (and a CPU where the fused step lacks a feature, `capabilities.py`), as the paper's stages:
predict; correct the joints (while an error is over the tolerance: solve, apply the impulses at t0, predict
again; a loop decided on the device where it can be, `kernels/loop.py`); the contacts and rows in the same loop;
accept the prediction and factor K at t0+h; correct the velocities; hand the state out. A stage that fails is
undone and the step redone as two halves; a fast spin splits the step before it starts."""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from . import composition
from .kernels import loop as loop_kernels
from .kernels import step as step_kernels
from .launch import run
from .steps import ROWS_FALLBACK, SimulationError, StepStats, combined

VELOCITY_ALTERNATIONS = 10
"""Rounds of (joint velocity correction, contact velocity sweeps) at t0+h before the last joint correction: the
two blocks converge linearly into each other (a cart on its wheels: about 0.7 a round)."""


class ParallelSteps:
    """The parallel schedule of a `Simulator` (a part of it: its stages launch the simulator's recorded work)."""

    def _device_loops(self) -> tuple[wp.Graph, wp.Graph | None, wp.Graph | None] | None:
        """The parallel schedule's loops at the current step size as graphs decided on the device (captured
        once per step size): the joint correction, accepting the prediction with its factor and velocity
        correction, and the velocity correction alone (the last two None with limits or split systems, whose
        velocity rows the host sequences; the last is a deferred one, `defer_velocities`). None where the
        host keeps its loops: other solvers, batched worlds (`worlds.py` decides per world), and the fused
        schedule's rare parallel steps (a fused share must find nothing to capture when threads step it)."""
        if not self._direct or self.batch is not None or self.schedule != "parallel":
            return None
        if self._key not in self._loops_by_h:
            first, first_iteration, iteration = self._loop_work
            errors = ((self.errors, self.model.constraint_world), (self.limit_error, self._limit_world))
            correct = self._capture_loop(first, iteration, errors, self.tolerance, self.max_iterations,
                                         first_iteration=first_iteration)  # fmt: skip
            finish = fix = None
            if not self.model.limit_count and not self._split_systems:
                first = (*self._accept_work, self._integrate_drives, self._half_kick, self._velocity_errors)
                finish = self._capture_loop(first, self._velocity_fix_work, errors[:1], self.velocity_tolerance,
                                            step_kernels.VELOCITY_SOLVES)  # fmt: skip
                fix = self._capture_loop((self._velocity_errors,), self._velocity_fix_work, errors[:1],
                                         self.velocity_tolerance, step_kernels.VELOCITY_SOLVES)  # fmt: skip
            self._loops_by_h[self._key] = (correct, finish, fix)
        return self._loops_by_h[self._key]

    def _capture_loop(self, first: tuple, iteration: tuple, errors: tuple, tolerance: float, limit: int,
                      first_iteration: tuple | None = None, **loop) -> wp.Graph:  # fmt: skip
        """A correction loop as one graph (`kernels/loop.py`): the work `first` (which measures), then
        `iteration` (which measures again) while, in any world, the largest of the `errors` ((error array, the
        world of each error) pairs) is over `tolerance` and the policy allows (at most `limit` iterations),
        decided on the device; the host reads the records after it (`_loop_record`). `first_iteration`, when
        it is other work, takes the first iteration's place (the Newton step's, `newton`). `loop`: the
        per-world records of batched worlds (`worlds.Batch`), else the one world's."""
        worlds = self.model.world_count if loop else 1
        decide = [
            *(self._record(loop_kernels.loop_reduce, e.shape[0], errors=e, error_world=w, **loop) for e, w in errors),
            self.loop_go.zero_,
            self._record(loop_kernels.loop_decide, worlds, tolerance=tolerance, max_iterations=limit, **loop),
        ]
        start = [self._record(loop_kernels.loop_start, worlds, **loop)]
        if not loop:  # the one world starts in the loop (batched worlds: the host writes which)
            start.append(lambda: self.loop_batch.fill_(1))
        body = (*iteration, *decide)
        loop_work = [lambda: wp.capture_while(self.loop_go, lambda: run(*body))]
        if first_iteration is not None and first_iteration is not iteration:
            once = (*first_iteration, *decide)
            loop_work.insert(0, lambda: wp.capture_if(self.loop_go, lambda: run(*once)))
        return self._capture(*start, *first, *decide, *loop_work)

    def _velocity_record(self) -> tuple[int, float]:
        """(iterations, velocity error) of the velocity-correction loop graph just replayed; a NaN or Inf raises,
        naming the bodies."""
        vel_err, _, vel_it = self._loop_record()
        if not math.isfinite(vel_err):
            self._max_error("velocity")
        return vel_it, vel_err

    def _loop_record(self) -> tuple[float, float, int]:
        """(largest error, best error, iterations) of the one-world loop graph just replayed."""
        record = self.loop_state.numpy()[0]
        last, best = float(record[loop_kernels.LOOP_LAST]), float(record[loop_kernels.LOOP_BEST])
        return last, best, int(record[loop_kernels.LOOP_ITERATIONS])

    def _step_parallel(self, hand_out: bool = True) -> StepStats:
        """One step by the parallel schedule: stage launches and graph replays, the host deciding between them.
        `hand_out`: its state is handed out, so its velocities are corrected (`defer_velocities`)."""
        self._update_forces()
        stages, fallback = self.scheme.stages, self._fallback
        if fallback:  # a non-reversible event in this step: composing it would not raise the order
            stages, self._fallback = (1.0,), ""
        elif len(stages) > 1 and self.model.limit_count:
            stages, fallback = (1.0,), ROWS_FALLBACK
        elif len(stages) > 1 and self._contacts_ahead(stages):
            stages, fallback = (1.0,), "contacts"
        depth = self._spin_depth(max(abs(g) for g in stages))
        stats = combined([self._advance(self.dt / 2**depth, depth, stages) for _ in range(2**depth)])
        stats.order = self.order if len(stages) == len(self.scheme.stages) else 2
        stats.fallback = fallback
        if self.defer_velocities and hand_out:
            self._hand_out_velocities(stats)
        self._use_step_size(self.dt)
        self._advance_clock(1)
        return stats

    def _hand_out_velocities(self, stats: StepStats) -> None:
        """The velocity correction the step's base steps deferred (`defer_velocities`), at its end: as the fused
        kernel does it in the step whose state it hands out, and reported in the step's `stats` under the
        iteration policy."""
        iterations, error, solves = self._correct_velocities()
        stats.velocity_iterations += iterations
        stats.linear_iterations += solves
        stats.max_velocity_error = error
        self._finish_step(stats, self._h)

    def _contacts_ahead(self, stages: tuple[float, ...]) -> bool:
        """Whether a composed step could meet a contact: any collider within the contact margin of another (or
        of a ground) along its free motion from t0 to the furthest the stages reach forward. Contacts, impacts
        and friction are not reversible, so such a step is taken at order 2 (`StepStats.fallback`)."""
        if self.contact_stage is None:
            return False
        reach = self.dt * max(1.0, *np.cumsum(stages))
        self._use_step_size(reach)
        wp.capture_launch(self._evaluate)
        return self.contact_stage.detect(reach) > 0

    def _advance(self, h: float, depth: int, stages: tuple[float, ...]) -> StepStats:
        """One step of h composed of base steps of g h for g in `stages`; on a failed stage, the whole step is
        undone and redone as two halves."""
        final = depth >= self.max_substep_depth
        whole = len(stages) == 1
        wp.capture_launch(self._save_velocities if whole else self._save_start)
        parts = []
        keys = composition.stage_keys(stages)
        for g, k in keys:
            part, ok = self._base_step(g * h, final, k)
            parts.append(part)
            if not ok:
                if whole:  # undo this attempt's impulses: the frames of t0 still hold
                    wp.copy(self._state.body_v, self._v0)
                    wp.copy(self._state.body_w, self._w0)
                else:  # back to the start of the composed step, its drives' integrals and its frames
                    self._state.copy_from(self._start)
                    wp.copy(self.drive_integral, self._integral0)
                    self._update_frames()
                halves = combined([self._advance(0.5 * h, depth + 1, stages) for _ in range(2)])
                halves.joint_iterations += sum(p.joint_iterations for p in parts)  # the failed attempt's work
                halves.velocity_iterations += sum(p.velocity_iterations for p in parts)
                halves.linear_iterations += sum(p.linear_iterations for p in parts)
                return halves
        if self.carry:  # the step is kept: so are the c its stages measured (`composition.stage_keys`)
            for (g, k), part in zip(keys, parts):
                if part.joint_iterations:
                    self._keep_carry((g * h, k))
        stats = combined(parts)
        stats.substeps = 1
        return stats

    def _base_step(self, h: float, final: bool, stage: int = 0) -> tuple[StepStats, bool]:
        """The paper's step of h (h < 0 runs it backwards), the `stage`-th of its size in a composed step (whose
        carried right-hand side it takes): its stats, and False when it failed and a smaller step may still
        succeed (not `final`; the state then holds this attempt's impulses)."""
        self._use_step_size(h, stage)
        self._half_kick.launch()  # split force elements: their first half kick (`StepOptions.split_forces`)
        if self.contact_stage is None:
            joint_it, joint_err, linear_iterations, ok = self._correct_joints(final)
        else:
            joint_it, joint_err, linear_iterations, ok = self._correct_with_contacts(h, final)
        if ok:
            self._report_nonfinite(self.pred, self.step_count + 1)  # measured with the last prediction
            if not final and self._turns(h) > 1.0:
                ok = False  # a body turned further than max_rotation in the step: halve it (whips spin up in one)
        if not ok:
            return StepStats(joint_it, 0, joint_err, math.inf, False, linear_iterations, 1), False
        finish = None if self.defer_velocities else (self._device_loops() or (None, None, None))[1]
        if finish is not None:  # accept, factor and correct the velocities by one graph
            wp.capture_launch(finish)
            self.linear.check()  # a lost pivot raises here, before the corrected velocities are used
            vel_it, vel_err = self._velocity_record()
            linear_iterations += vel_it
            return self._finish_step(StepStats(joint_it, vel_it, joint_err, vel_err, True, linear_iterations, 1), h)
        wp.capture_launch(self._accept_graph)
        if self.linear is not None:
            self.linear.check()
        self._integrate_drives.launch()
        self._half_kick.launch()  # the second, at the accepted poses
        if self.defer_velocities:  # accepted and factored; the velocities are the next step's (`defer_velocities`)
            return self._finish_step(StepStats(joint_it, 0, joint_err, math.nan, True, linear_iterations, 1), h)

        if self.linear is None:
            vel_it, _ = self._sweep(self._sweep_velocities, self.velocity_tolerance, "velocity", True)
            if self.model.limit_count:  # no constraints, only limits (distance constraints)
                self._correct_limit_velocities.launch()
            self._velocity_errors.launch()
            vel_err = self._max_error("velocity")
        else:
            vel_it, vel_err, solves = self._correct_velocities()
            linear_iterations += solves
        return self._finish_step(StepStats(joint_it, vel_it, joint_err, vel_err, True, linear_iterations, 1), h)

    def _correct_velocities(self) -> tuple[int, float, int]:
        """The velocity correction of the state (its factor made): its iterations, the velocity error it leaves
        and its linear iterations (rows, limits and stiff motors, take one more solve first). Decided on the
        device where the parallel schedule's loops are (`_device_loops`), else by the host."""
        fix = (self._device_loops() or (None, None, None))[2]
        if fix is not None:
            wp.capture_launch(fix)
            vel_it, vel_err = self._velocity_record()
            return vel_it, vel_err, vel_it
        vel_it = solves = 0
        self._velocity_errors.launch()
        if self.model.limit_count:  # joints exact, then the limits, then the joints take up their reaction
            solves += self._fix_velocities()
            self._correct_limit_velocities.launch()
            self._velocity_errors.launch()
        vel_err = self._max_error("velocity")
        # One exact solve (and one on its round-off, `VELOCITY_SOLVES`), except with the split systems (section 4.6),
        # which iterate side by side.
        limit = self.max_iterations if self._split_systems else step_kernels.VELOCITY_SOLVES
        while vel_err > self.velocity_tolerance and vel_it < limit:
            solves += self._fix_velocities()
            vel_it += 1
            vel_err = self._max_error("velocity")
        return vel_it, vel_err, solves

    def _finish_step(self, stats: StepStats, h: float) -> tuple[StepStats, bool]:
        """The end of an accepted base step of h: the velocity correction's outcome under the iteration policy,
        the contacts' velocity phase, and whether everything converged."""
        vel_err = stats.max_velocity_error
        if vel_err > self.velocity_tolerance and self.linear is not None:
            # One exact solve should leave round-off: a linear solver that stopped short (CG on an
            # ill-conditioned K) is reported under the same policy as an iteration limit.
            self._velocity_failed(vel_err)
        if self.contact_stage is not None:
            self._contact_velocities(h, stats)
        stats.converged = (
            stats.max_joint_error <= self.tolerance
            and (stats.max_velocity_error <= self.velocity_tolerance or math.isnan(vel_err))  # NaN: deferred
            and stats.max_penetration <= self.tolerance
        )
        return stats, True

    def _fix_velocities(self) -> int:
        """The velocity correction's solve from the velocity errors just measured, applied, and the errors
        measured again; returns the linear iterations it took."""
        if self._direct:
            wp.capture_launch(self._velocity_fix)
            return 1
        iterations = self.linear.solve(self.rhs, self.impulse, "velocity")
        self._apply.launch()
        self._velocity_errors.launch()
        return iterations

    def _spin_depth(self, reach: float) -> int:
        """k such that 2**k substeps turn the fastest body of the state at most max_rotation in each base
        step, the longest of which is `reach` substeps long (k <= max_substep_depth)."""
        return self._depth_of(self._spin, reach)

    def _depth_of(self, spin: float, reach: float = 1.0) -> int:
        """The substep depth of a step whose fastest body spins at `spin` (rad/s), its longest base step
        `reach` substeps long; at least the depth its stiff dampers kept in RK4 need (`_damper_depth`)."""
        turns = 0.0 if self.max_rotation is None else spin * abs(reach * self.dt) / self.max_rotation
        return max(self._halvings(turns), self._damper_depth())

    def _damper_depth(self) -> int:
        """k such that the dampers and springs kept in RK4 at order 4 or 6 (`dampers.pick`'s `kept`) are not stiff
        in substeps of dt / 2**k (k <= max_substep_depth). Split up front, not halved on failure, whose failed
        attempts cost a damped gimbal 7x the solves (tests/test_mjcf.py) and dm_control's fish 2.6x."""
        return self._halvings(self._dampers.stiffness * abs(self.dt))

    def _halvings(self, over: float) -> int:
        """The k that brings a step `over` times too long to within bounds in 2**k substeps (k <= max_substep_depth)."""
        return 0 if over <= 1.0 else min(math.ceil(math.log2(over)), self.max_substep_depth)

    def _turns(self, h: float) -> float:
        """How many times max_rotation the fastest body of the last prediction turns in a step of h (either
        way; 0 when steps are never split)."""
        return 0.0 if self.max_rotation is None else self._spin * abs(h) / self.max_rotation

    def _correct_joints(self, final: bool) -> tuple[int, float, int, bool]:
        """Impulses at t0 until the predicted joints hold: (iterations, error, linear iterations, ok).

        ok is False when the correction failed and a smaller step may still succeed (not `final`)."""
        if self.linear is None and not self.model.limit_count:
            sweeps, err = self._sweep(self._sweep_positions, self.tolerance, "joint", final)
            wp.capture_launch(self._evaluate)
            err = self._max_error("joint")
            return sweeps, err, 0, err <= self.tolerance or final
        loops = self._device_loops()
        if loops is not None:
            return self._correct_on_device(loops[0], final)
        iterations, linear_iterations, best = 0, 0, math.inf
        wp.capture_launch(self._evaluate)
        while True:
            err = self._max_error("joint")
            best = min(best, err)
            if err <= self.tolerance:
                return iterations, err, linear_iterations, True
            if not self._may_iterate(iterations, err, "joint", best, final):
                return iterations, err, linear_iterations, final
            if self._direct:
                wp.capture_launch(self._iterate_first if iterations == 0 else self._iterate)
                linear_iterations += 1 + int(self.newton and iterations == 0)
            else:
                if self.linear is not None:  # else only limits and distance constraints: no system to solve
                    linear_iterations += self.linear.solve(self.rhs, self.impulse, "joint" if iterations == 0 else None)
                    self._apply.launch()
                self._correct_limits.launch()
                wp.capture_launch(self._evaluate)
            iterations += 1

    def _correct_on_device(self, loop: wp.Graph, final: bool) -> tuple[int, float, int, bool]:
        """`_correct_joints` by the loop graph (`_device_loops`): the same launches in the same order, the loop
        decided on the device; the host reads its record and applies the iteration policy's outcome."""
        wp.capture_launch(loop)
        err, best, iterations = self._loop_record()
        if not math.isfinite(err):
            self._max_error("joint")  # raises, naming the bodies with a NaN or Inf
        solves = iterations + self._newton_solves(iterations)
        if err <= self.tolerance:
            return iterations, err, solves, True
        self._may_iterate(iterations, err, "joint", best, final)  # stopped: on the final try raise or warn
        return iterations, err, solves, final

    def _newton_solves(self, iterations):
        """The Newton step's second solves in joint corrections of `iterations` iterations (an int, or an array
        of them a world): one where a correction iterated at all, when `newton` is on."""
        return int(self.newton) * (iterations > 0)

    def _joint_iteration(self) -> int:
        """One joint correction from the current prediction: impulses at t0, predict again, measure. Returns
        the linear solves it took."""
        if self.linear is None:
            self._sweep_positions.launch()
            wp.capture_launch(self._evaluate)
            return 0
        if self._direct:
            wp.capture_launch(self._iterate)
            return 1
        solves = self.linear.solve(self.rhs, self.impulse, None)
        self._apply.launch()
        self._correct_limits.launch()
        wp.capture_launch(self._evaluate)
        return solves

    def _correct_with_contacts(self, h: float, final: bool) -> tuple[int, float, int, bool]:
        """`_correct_joints` with the contacts in the same loop (method paper's way; docs/contacts.md): correct the
        joints first and detect on that prediction (it holds the motion motors and loops impose, which the free
        prediction does not); then, until every joint and every contact holds to the tolerance, correct the
        joints (one direct solve: the joints as one block), predict, and close the contacts' predicted gaps
        with push-only impulses at t0 (Gauss-Seidel around that block), and predict again. The error returned
        is the larger of the joints' and the deepest penetration."""
        cs = self.contact_stage
        joint_it, _, linear_iterations, ok = self._correct_joints(final)  # the joints' (and motors') motion first
        if not ok:
            return joint_it, math.inf, linear_iterations, False
        cs.detect(h)
        cs.couple(h)  # contacts on jointed bodies: rows solved with the joints, limits and motors
        self._contact_sweeps = 0
        iterations, best = joint_it, math.inf
        joints = self.model.constraint_count > 0
        while True:
            joint_err = self._max_error("joint") if joints else 0.0
            self._penetration = cs.measure(h)
            err = max(joint_err, self._penetration)
            best = min(best, err)
            if err <= self.tolerance:
                return iterations, joint_err, linear_iterations, True
            if not self._may_iterate(iterations, err, "joint", best, final):
                return iterations, joint_err, linear_iterations, final
            if joint_err > self.tolerance:
                linear_iterations += self._joint_iteration()
                cs.measure(h)
            self._contact_sweeps += cs.solve_positions(h)
            wp.capture_launch(self._evaluate)
            iterations += 1

    def _contact_velocities(self, h: float, stats: StepStats) -> None:
        """Restitution and friction at t0+h, alternated with the joints' velocity correction (at most
        `VELOCITY_ALTERNATIONS` rounds), then a last joint correction: the joints hold to the tolerance at the
        end of the step, the contacts' velocities as far as the rounds brought them (their positions are held
        to the tolerance by the next step's position phase)."""
        cs = self.contact_stage
        sweeps = cs.solve_velocities(h)
        if self.model.constraint_count:
            self._velocity_errors.launch()
            err = self._max_error("velocity")
            rounds = 0
            while err > self.velocity_tolerance and rounds <= VELOCITY_ALTERNATIONS:
                if self.linear is None:
                    self._sweep(self._sweep_velocities, self.velocity_tolerance, "velocity", True)
                else:
                    self._fix_velocities()
                    if self.model.limit_count:  # the limits and stiff motors, as in the joint-only step
                        self._correct_limit_velocities.launch()
                        self._velocity_errors.launch()
                        self._fix_velocities()
                stats.velocity_iterations += 1
                rounds += 1
                if rounds <= VELOCITY_ALTERNATIONS:
                    sweeps += cs.solve_velocities(h, first=False)
                self._velocity_errors.launch()
                err = self._max_error("velocity")
            if err > self.velocity_tolerance:
                self._velocity_failed(err)
            stats.max_velocity_error = err
        stats.contacts = cs.count
        stats.max_penetration = self._penetration
        stats.contact_sweeps = self._contact_sweeps + sweeps

    def _sweep(self, launch: wp.Launch, tolerance: float, what: str, final: bool) -> tuple[int, float]:
        sweeps, best = 0, math.inf
        while True:
            launch.launch()
            err = float(self.sweep_error.numpy()[0])
            best = min(best, err)
            if err <= tolerance or not self._may_iterate(sweeps, err, what, best, final):
                return sweeps, err
            sweeps += 1

    def _max_error(self, what: str) -> float:
        """The largest constraint error of the `what` ("joint" or "velocity") correction just measured."""
        err = float(self.errors.numpy().max()) if self.model.constraint_count else 0.0
        if what == "joint" and self.model.limit_count:
            err = max(err, float(self.limit_error.numpy().max()))
        if not math.isfinite(err):
            if what == "joint":
                self._check_finite(self.pred, self.step_count + 1)
            self._check_finite(self._state, self.step_count)
            raise SimulationError(f"step {self.step_count + (what == 'joint')}: {what} errors are not finite")
        return err
