"""The simulator's launches: each stage's kernel recorded once, bound by parameter name to its arrays.

A recorded launch (`launch.record`) finds each kernel parameter among the Model, Frames, Control, the State it
reads or writes and the simulator's scratch arrays; graphs captured from them replay a step's stages without
Python work. Step sizes other than dt (substeps, composed stages) get their own launches, recorded on first use."""

from __future__ import annotations

import math

import warp as wp

from .kernels import carry as carry_kernels
from .kernels import forces as force_kernels
from .kernels import impulses as impulse_kernels
from .kernels import inertia as inertia_kernels
from .kernels import iterative as iterative_kernels
from .kernels import limits as limit_kernels
from .kernels import rigid as rigid_kernels
from .kernels import step as step_kernels
from .kernels import worlds as world_kernels
from .launch import Launches, capture, record
from .model import State
from .solver import CholeskySolver


class Recording:
    """The recorded launches of a `Simulator` (a part of it: they bind its arrays and scratch by name)."""

    def _record(self, kernel, dim: int, data_in: State | None = None, data_out: State | None = None, **values):
        """A recorded launch whose parameters are bound by name to the Model, Frames, Control and the
        simulator's scratch arrays (`launch.record`)."""
        sources = (self.model, self.frames, self.control, self)
        return record(kernel, dim, self.model.device, sources, data_in, data_out, **values)

    def _capture(self, *work) -> wp.Graph:
        return capture(self.model.device, *work)

    def _record_launches(self) -> None:
        s, (nb, nc) = self._state, self._counts
        self._rows = self._row_arrays()  # one struct for both schedules' row launches
        self._inertia = self._record(inertia_kernels.world_inverse_inertia, nb, s)
        self._frames = self._record(self.kernels.frames, nc, s)
        self._velocity_errors = self._record(self.kernels.velocity_errors, nc, s)
        self._apply = self._record(impulse_kernels.apply_impulses, nb, data_out=s)
        self._sweep_velocities = self._record(iterative_kernels.sweep_velocities, 1, s, s, constraint_count=nc)
        self._check_states = {id(st): self._record(rigid_kernels.summarize_state, nb, st) for st in (s, self.pred)}
        # Batched worlds: per-world summaries, and right-hand sides masked to the worlds still iterating.
        self._world_checks = {}
        self._mask = []
        if self.batch is not None:
            self._world_checks = {id(st): self._record(world_kernels.summarize_worlds, nb, st) for st in (s, self.pred)}
            self._mask = [self._record(world_kernels.mask_worlds, nc, rhs=self.rhs)]
        prepare = self.linear.prepare_launches if self.linear is not None else []
        frames = [self._inertia, self._frames, *prepare, *self._limit_system_launches()]
        self._frames_graph = self._capture(*frames)
        # Accept the prediction (already checked for NaN/Inf) as the new state and factor K there, in one replay.
        self._accept_work = (lambda: self._state.copy_from(self.pred), *frames)
        self._accept_graph = self._capture(*self._accept_work)
        self._save_velocities = self._capture(
            lambda: wp.copy(self._v0, s.body_v), lambda: wp.copy(self._w0, s.body_w), self.limit_impulse.zero_
        )
        self._direct = isinstance(self.linear, CholeskySolver)  # one solve is a fixed launch sequence
        if self._direct:
            solve = self.linear.solve_launches(self.rhs, self.impulse)
            self._velocity_fix_work = (*self._mask, *solve, self._apply, self._velocity_errors)
            self._velocity_fix = self._capture(*self._velocity_fix_work)
        self._use_step_size(self.dt)

    def _limit_system_launches(self) -> list:
        """The rows' system S (limits and stiff motors) with the joints holding, at the current state and factor
        (`kernels/limits.py`): one solve with the factor per row; with CG (no factor to reuse) the free bodies'
        mobility."""
        s, nl, nc = self._state, self.model.limit_count, self.model.constraint_count
        if nl == 0:
            return []
        coupled = isinstance(self.linear, CholeskySolver)
        launches = [self._record(limit_kernels.limit_sides, nl, s)]
        if coupled:
            launches.append(self._record(limit_kernels.limit_coupling, (nl, nc), s))
            for l in range(nl):
                rows = slice(l * nc, (l + 1) * nc)
                launches += self.linear.solve_launches(self.limit_coupling[rows], self.limit_response[rows])
        launches.append(self._record(limit_kernels.limit_matrix, (nl, nl), s, coupled=int(coupled)))
        return launches

    def _use_step_size(self, h: float, stage: int = 0) -> None:
        """Point the launches that depend on the step size at h (recorded once per h, then cached); with the carry,
        at the c of the `stage`-th stage of size h in a composed step (`composition.stage_keys`)."""
        key = (h, stage if self.carry else 0)
        if key not in self._launches_by_h:
            s, p, (nb, nc) = self._state, self.pred, self._counts
            if self._forced:
                predict = self._coupled_prediction(h)
            else:
                group = rigid_kernels.LANES if self.model.device.is_cpu else 1  # bodies a thread
                predict = self._record(rigid_kernels.predict, -(-nb // group), s, p, h=h, group_size=group)
                if self._kicked and self._dampers.names:  # beside kicks: the dampers stiff for h, implicit
                    predict = Launches([predict, self._implicit_dampers(h)])
            integrate = self._record(force_kernels.integrate_drives, self.model.drive_count, s, h=h)
            errors = self._record(self.kernels.position_errors, nc, p, inv_h=1.0 / h)
            sweep = self._record(iterative_kernels.sweep_positions, 1, s, s, h=h, constraint_count=nc)
            # Measure a prediction: its joint errors, NaN/Inf bodies and fastest spin.
            start = dict(start_x=s.body_x, start_q=s.body_q, start_v=s.body_v, start_w=s.body_w)
            limits = self._record(limit_kernels.limit_errors, self.model.limit_count, p, h=h, rows=self._rows, **start)
            measure = [errors, limits, self.summary.zero_, self._check_states[id(p)]]
            if self.batch is not None:
                measure += [self.world_summary.zero_, self._world_checks[id(p)]]
            nl, coupled = self.model.limit_count, int(self._direct)
            correct_limits, correct_limit_velocities = (
                self._record(limit_kernels.correct_rows, int(nl > 0), s, velocity=v, coupled=coupled, h=h,
                             body_v=s.body_v, body_w=s.body_w, rows=self._rows)
                for v in (0, 1)
            )  # fmt: skip
            iterate = iteration = iterate_first = first_iteration = None
            if self._direct:  # solve, apply at t0, predict again, measure
                solve = self.linear.solve_launches(self.rhs, self.impulse)
                iteration = (*self._mask, *solve, self._apply, correct_limits, predict, *measure)
                iterate = iterate_first = self._capture(*iteration)
                first_iteration = iteration
                carry_in, newton, carry_out = [], [], []
                if self.carry:  # the first solves rhs + c, then measures the next c (`carry`)
                    c, c_next, *_ = self._carry_arrays(key)
                    carry_in = [self._record(carry_kernels.carry_in, nc, carry=c, rhs_out=self.rhs)]
                    carry_out = [self._record(carry_kernels.carry_out, nc, carry=c, rhs_in=self.rhs,
                                              carry_next_out=c_next)]  # fmt: skip
                if self.newton:  # the first solves again with rhs - E lambda (`newton`)
                    newton = [
                        self._record(impulse_kernels.impulse_responses, nb, s, h=h),
                        self._record(self.kernels.arm_corrections, nc, p, h=h),
                        *self.linear.solve_launches(self.newton_rhs, self.impulse),
                    ]
                if carry_in or newton:
                    first_iteration = (*carry_in, *self._mask, *solve, *newton, self._apply, correct_limits, predict,
                                       *measure, *carry_out)  # fmt: skip
                    iterate_first = self._capture(*first_iteration)
            self._launches_by_h[key] = (predict, errors, sweep, self._capture(predict, *measure), iterate,
                                      iterate_first, ((predict, *measure), first_iteration, iteration), integrate,
                                      correct_limits, correct_limit_velocities, self._kick(h))  # fmt: skip
        (self._predict, self._position_errors, self._sweep_positions, self._evaluate, self._iterate,
         self._iterate_first, self._loop_work, self._integrate_drives, self._correct_limits,
         self._correct_limit_velocities, self._half_kick) = self._launches_by_h[key]  # fmt: skip
        self._h, self._key = h, key

    def _carry_arrays(self, key: tuple[float, int]) -> tuple[wp.array, ...]:
        """(c, the c measured in the step, the values measured in the last kept steps, the newest first) for
        `key`, (step size, stage of that size) (`carry`): a stage's rows at dt, which the fused kernel shares;
        for a stage of a split or halved step, the rows of its substep size (`_substep_carries`); else arrays
        of their own (a step size set by the accuracy controller, say)."""
        if key in self._carry_rows:
            r = self._carry_rows[key]
            past = (self._carry_past[carry_kernels.PAST * r + k] for k in range(carry_kernels.PAST))
            return self._carry[r], self._carry_next[r], *past
        for depth in range(1, self.max_substep_depth + 1):  # a stage of a split or halved step: its size's rows
            if key in self._carry_other:
                break
            h = self.dt / 2**depth
            if key in {(g * h, k) for g, k in self._fractions}:
                self._substep_carries(h)
        if key not in self._carry_other:
            c = wp.zeros(self.model.constraint_count, dtype=wp.vec3d, device=self.model.device)
            unknown = wp.vec3d(math.nan, math.nan, math.nan)
            past = (wp.full_like(c, unknown) for _ in range(carry_kernels.PAST))
            self._carry_other[key] = (c, wp.zeros_like(c), *past)
        return self._carry_other[key]

    def _substep_carries(self, h: float) -> tuple[wp.array, wp.array, wp.array]:
        """The carried right-hand sides of the substeps of size h of split or halved steps (c, the measured c,
        the past; a row a stage as at dt): the fused kernel's substep launches take the arrays
        (`FusedSteps._substep_launch`), the parallel schedule's steps their rows (`_carry_other`), so both
        take the same c."""
        arrays = self._substep_carry.get(h)
        if arrays is None:
            arrays = tuple(wp.empty_like(a) for a in (self._carry, self._carry_next, self._carry_past))
            arrays[0].zero_()
            arrays[1].zero_()
            arrays[2].fill_(wp.vec3d(math.nan, math.nan, math.nan))
            carry, carry_next, carry_past = self._substep_carry[h] = arrays
            past = carry_kernels.PAST
            for r, (g, k) in enumerate(self._fractions if self.carry else ()):
                self._carry_other[(g * h, k)] = (
                    carry[r],
                    carry_next[r],
                    *(carry_past[past * r + i] for i in range(past)),
                )
        return arrays

    def _keep_carry(self, key: tuple[float, int]) -> None:
        """A kept step of `key` (step size, stage) whose first solve ran: the value it measured joins the past
        and c is extrapolated for the next step (`carry`, kernels/carry.py)."""
        c, c_next, *past = self._carry_arrays(key)
        wp.launch(carry_kernels.carry_keep, c.shape[0], inputs=[c_next], outputs=[c, *past],
                  device=self.model.device)  # fmt: skip

    def _carries_of(self, key: tuple[float, int]) -> tuple[wp.array, ...]:
        """What steps of `key` (step size, stage) carry to the next (`carry`): c and the values measured in the
        last kept steps."""
        c, _, *past = self._carry_arrays(key)
        return c, *past

    def _carries(self) -> dict[tuple[float, int], tuple[wp.array, ...]]:
        """`_carries_of` every (step size, stage) that has them (`carry`)."""
        return {k: self._carries_of(k) for k in (*self._carry_rows, *self._carry_other)} if self.carry else {}

    def _forget_carry(self, world: int | None = None) -> None:
        """No c to carry, for one world or all: its state was set from outside the step (`reset`, `set_state`)."""
        nc = self.model.world_constraint_count
        rows = slice(None) if world is None else slice(world * nc, (world + 1) * nc)
        for c, *past in self._carries().values():
            c[rows].zero_()
            for p in past:
                p[rows].fill_(wp.vec3d(math.nan, math.nan, math.nan))

    def _coupled_prediction(self, h: float) -> Launches:
        """RK4 over all bodies at once, the springs and drives evaluated at every stage, then the implicit dampers
        on the prediction (`kernels/forces.py`)."""
        m, s, p, stage = self.model, self._state, self.pred, self._stage
        start = dict(start_x=s.body_x, start_q=s.body_q, start_v=s.body_v, start_w=s.body_w)
        launches = []
        for k in range(4):
            at = s if k == 0 else stage
            launches += self._wrench_launches(at)
            launches.append(
                self._record(force_kernels.rk4_stage, m.body_count, at, p if k == 3 else stage, stage=k, h=h, **start)
            )
        return Launches([*launches, self._implicit_dampers(h)])

    def _implicit_dampers(self, h: float) -> wp.Launch:
        """The dampers stiff for h (`dampers.pick`) on the prediction, implicit (`forces.implicit_dampers`)."""
        dampers = int(len(self._dampers.names) > 0)  # one thread takes them in turn (`implicit_dampers_all`)
        return self._record(force_kernels.implicit_dampers, dampers, data_out=self.pred, h=h,
                            damper_drive=self._dampers.drive, damper_gain=self._dampers.gain,
                            damper_spring=self._dampers.spring)  # fmt: skip

    def _wrench_launches(self, at: State) -> list:
        """Every force element's wrench rows at the state `at`: the springs, the drives' coordinate rows, the
        drives (`kernels/forces.py`)."""
        m = self.model
        return [
            self._record(force_kernels.spring_wrenches, m.spring_count, at),
            self._record(force_kernels.coordinate_geometries, m.drive_rows.shape[0], at),
            self._record(
                force_kernels.drive_wrenches,
                m.force_drive_count,
                at,
                row_offset=m.spring_count,
                drive_gains=self._dampers.drive_gains,
            ),  # fmt: skip
        ]

    def _kick(self, h: float) -> Launches:
        """The half kick about a split base step of h (`StepOptions.split_forces`): the elements' wrenches at the
        state's poses acting for h / 2 (`forces.kick`); nothing where the elements are not split."""
        if not self._kicked:
            return Launches([])
        s = self._state
        return Launches([*self._wrench_launches(s), self._record(force_kernels.kick, self.model.body_count, data_out=s,
                                                                    dt=0.5 * h)])  # fmt: skip

    def prepare_substeps(self) -> None:
        """Record the launches of every substep size a step may take (dt / 2**k, k <= max_substep_depth) now,
        instead of on first use: recording captures graphs, and a capture on a CPU takes in every launch of the
        process, so threads that step simulators at once (`threads.py`) must find nothing left to capture."""
        for k in range(self.max_substep_depth + 1):
            self._use_step_size(self.dt / 2**k)
            self._device_loops()
            if self.batch is not None:
                self.batch.device_loop()
        self._use_step_size(self.dt)
        if self.schedule == "fused":  # and the fused kernel's launch (a one-world share steps by it)
            self._fused_launch(self.dt)

    def _update_frames(self) -> None:
        """P_i, J_ib and K at the current state; factor K for the coming solves."""
        wp.capture_launch(self._frames_graph)
        if self.linear is not None:
            self.linear.check()
        if self.reuse_factor:  # a new factor: the fused kernel's record starts again (`kernels/step.py` FACTOR_*)
            self._forget_factor()

    def _forget_factor(self) -> None:
        """The fused kernel's factor record after a factorization of the host's, as a new simulator's (its count
        aside): of the current state, no hold, no stage's solves known (`kernels/step.py` `older_factor`)."""
        state = self._factor_state.numpy().copy()
        for column in (step_kernels.FACTOR_AGE, step_kernels.FACTOR_HOLD, step_kernels.FACTOR_BACKOFF,
                       step_kernels.FACTOR_SERVED):  # fmt: skip
            state[column] = 0
        state[step_kernels.FACTOR_FRESH_SOLVES :] = -1
        self._factor_state.assign(state)
