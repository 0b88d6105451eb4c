"""The fused schedule: whole steps, many a launch, as one kernel on a CPU.

`kernels/step.py` runs the paper's stages of every step of a batch in one launch (predict, correct the joints,
rows, accept and factor, correct the velocities where the state is handed out), stopping at a step it cannot
take alone (a spin that splits it, a failed correction) and handing that step to the parallel schedule. The host
reads one status row a step back, or one summary row of the batch."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import warp as wp

from .kernels import limits as limit_kernels
from .kernels import step as step_kernels
from .launch import Packed, record
from .steps import StepStats, combined

# A status row's columns, read by each `step()` (`Simulator._status_stats`): a global each.
_JOINT, _VELOCITY = step_kernels.STATUS_JOINT_ITERATIONS, step_kernels.STATUS_VELOCITY_ITERATIONS
_JOINT_ERROR, _VELOCITY_ERROR = step_kernels.STATUS_JOINT_ERROR, step_kernels.STATUS_VELOCITY_ERROR
_LINEAR = step_kernels.STATUS_LINEAR_ITERATIONS
_bare = object.__new__
_CODE, _SPIN = step_kernels.STATUS_CODE, step_kernels.STATUS_SPIN


class FusedSteps:
    """The fused schedule of a `Simulator` (a part of it: one kernel over its arrays, the host reading a row a step)."""

    def _take_fused_kernels(self) -> None:
        """The fused kernels for the scene's kinds and rows and for how its force elements act now (coupled,
        kicked or not at all: `Simulator._follow_elements`), and the elements they take."""
        rows = self.model.limit_count > 0  # limits, stiff motors, distance constraints (kernels/limits.py)
        self._fused = step_kernels.fused(self._fused_kinds, self._forced, rows, self._kicked)
        self._elements = self._force_elements()

    def _force_elements(self) -> step_kernels.ForceElements | step_kernels.Absent:
        """The force elements and the coupled prediction's scratch, for the fused kernel (`Absent` without)."""
        if not (self._forced or self._kicked):
            return step_kernels.Absent()
        elements = step_kernels.ForceElements()
        m = self.model
        for field in step_kernels.ForceElements.vars:
            if hasattr(m, field):
                setattr(elements, field, getattr(m, field))
        elements.drive_target, elements.drive_integral = self.drive_target, self.drive_integral
        elements.drive_gains = self._dampers.drive_gains  # without the implicit dampers' terms
        elements.damper_drive, elements.damper_gain = self._dampers.drive, self._dampers.gain
        elements.damper_spring = self._dampers.spring
        elements.integral0 = self._integral0
        elements.wrench_force, elements.wrench_torque = self.wrench_force, self.wrench_torque
        elements.coordinate_world_axis, elements.coordinate_world_point = (
            self.coordinate_world_axis,
            self.coordinate_world_point,
        )
        elements.stage_x, elements.stage_q = self._stage.body_x, self._stage.body_q
        elements.stage_v, elements.stage_w = self._stage.body_v, self._stage.body_w
        elements.rk4_sum_x, elements.rk4_sum_q = self.rk4_sum_x, self.rk4_sum_q
        elements.rk4_sum_v, elements.rk4_sum_w = self.rk4_sum_v, self.rk4_sum_w
        return elements

    def _row_arrays(self) -> limit_kernels.Rows:
        """The rows of the correction loop and their scratch, for the row kernels of both schedules (empty
        without)."""
        rows = limit_kernels.Rows()
        m, nl = self.model, self.model.limit_count
        if not nl:
            return rows
        for field in limit_kernels.Rows.vars:
            source = self if hasattr(self, field) else m
            if hasattr(source, field):
                setattr(rows, field, getattr(source, field))
        rows.coupling_rows = self.limit_coupling.reshape((nl, m.constraint_count))
        rows.response_rows = self.limit_response.reshape((nl, m.constraint_count))
        return rows

    def _fused_launch(self, h: float) -> wp.Graph | Packed:
        """The fused kernel's launch for steps of h: on a CPU one packed launch (its arguments packed once, a call
        then costs ~0.3 us against a graph replay's ~1.7), its step size set in place; on a GPU a graph captured
        once per h."""
        launch = self._fused_by_h.get(h)
        if launch is not None:
            return launch
        if self._views is not None and self._fused_by_h:  # the one packed launch, for another h
            (packed,) = self._fused_by_h.values()
            packed.set("h", h)
            self._fused_by_h = {h: packed}
            return packed
        reach = max(abs(g) for g in self._fused_stages)
        launch = self._record_fused(h, reach, self.max_substep_depth == 0, (self._carry, self._carry_next,
                                                                            self._carry_past))  # fmt: skip
        self._fused_by_h[h] = self._capture(launch) if self._views is None else Packed(launch)
        return self._fused_by_h[h]

    def _tick_launches(self) -> tuple[Callable[[], object], Callable[[], object]]:
        """`step()`'s packed launches of one step of dt (CPU), kept until dt changes: [0] hands its state out, [1]
        leaves its velocity correction to `state` (`defer_velocities`). Each reads batch words of its own that
        nothing writes, so that a tick writes only its starting spin."""
        reach = max(abs(g) for g in self._fused_stages)
        carries = (self._carry, self._carry_next, self._carry_past)
        final = self.max_substep_depth == 0
        launches = tuple(
            Packed(self._record_fused(self.dt, reach, final, carries, words)).launch for words in self._tick_words
        )
        self._tick = (self.dt, launches)
        return launches

    def _record_fused(
        self, h: float, reach: float, final: bool, carries: tuple[wp.array, ...], batch: wp.array | None = None
    ) -> wp.Launch:
        """The fused kernel's launch for steps of h: `reach` sizes its spin split (0: none), `final` says its steps
        cannot be halved, `carries` are the carried right-hand sides its stages take (c, the measured c, the past;
        a row a stage, `stage_carry`), `batch` its batch words (the host's `_batch` unless given)."""
        p = self.pred
        direct = self.linear is not None
        kernel = self._fused.cholesky_steps if direct else self._fused.iterative_steps
        sources = (self.model, self.frames, self.control, self)
        if direct:
            sources = (self.linear.fused_args, *sources, self.linear.device_pattern, self.linear)
        carry, carry_next, carry_past = carries
        return record(
            kernel, 1, self.model.device, sources, data_out=self._state,
            h=h, stages=self._stages, reach=reach, batch_in=self._batch if batch is None else batch,
            defer=int(self.defer_velocities), max_rotation=self.max_rotation or 0.0, final=int(final),
            spin_in=self._spin_in,
            pred_x=p.body_x, pred_q=p.body_q, pred_v=p.body_v, pred_w=p.body_w, x0=self._start.body_x,
            q0=self._start.body_q, v0=self._v0, w0=self._w0, status_out=self._status,
            elements=self._elements, limit_rows=self._rows if self.model.limit_count else step_kernels.Absent(),
            newton=int(self.newton), carrying=int(self.carry),
            stage_carry=self._stage_carry, carry=carry, carry_next=carry_next, carry_past=carry_past,
            refactor_every=self._refactor_every, stale_factor_rate=self._stale_factor_rate,
            factor_state=self._factor_state,
        )  # fmt: skip

    def _substep_launch(self, depth: int) -> Packed:
        """The packed launch (CPU) of the substeps of a step the spin splits into 2**depth: steps of
        dt / 2**depth without a split of their own (reach 0: the parallel schedule sizes a split once, at the
        step's start, and halves a substep only where it turned too far), halvable unless depth is the deepest.
        Their carried right-hand sides are `_substep_carries(h)`, which the parallel schedule's steps of that
        size take too, so both schedules take a split step alike."""
        h = self.dt / 2**depth
        launch = self._substep_by_h.get(h)
        if launch is None and depth == 0:  # whole steps (no deeper split allowed): the steps' own c
            main = (self._carry, self._carry_next, self._carry_past)
            launch = self._substep_by_h[h] = Packed(self._record_fused(h, 0.0, True, main))
        if launch is None:
            arrays = self._substep_carries(h)
            launch = Packed(self._record_fused(h, 0.0, depth >= self.max_substep_depth, arrays))
            self._substep_by_h[h] = launch
        return launch

    def _splits_fused(self) -> bool:
        """Whether a split or halved step is taken by fused launches (`_split_step`), not the parallel schedule."""
        return self._views is not None and self.linear is not None and self.accuracy is None

    def _split_step(self, row: np.ndarray | None, hand_out: bool) -> StepStats:
        """The step whose status `row` (SPLIT or RETRY; None: a step split up front, `_damper_depth`) stopped a
        fused launch, the parallel schedule's way
        (`_step_parallel`: a spin split into 2**depth substeps, the depth from the spin at the step's start; a
        failed step undone and taken as two halves, `_advance`) but by the fused kernel on a CPU, where the
        parallel schedule's launches cost about 13x the step (measured on a 7-hinge arm at order 4)."""
        columns = step_kernels
        self._update_forces()
        order, fallback = self._fused_order
        if row is None or int(row[columns.STATUS_CODE]) == columns.SPLIT:
            depth = self._spin_depth(max(abs(g) for g in self._fused_stages))
            parts = self._fused_substeps(depth, 2**depth)
        else:
            parts = [self._halved(row, 0)]
        stats = combined(parts)
        stats.order, stats.fallback = order, fallback
        if self.defer_velocities and hand_out:
            self._hand_out_velocities(stats)
        self._use_step_size(self.dt)
        self._advance_clock(1)
        return stats

    def _halved(self, row: np.ndarray, depth: int) -> StepStats:
        """A composed substep of dt / 2**depth that the kernel handed back failed (`row`; its start restored)
        taken as two halves, its failed attempt's work counted in them, as `_advance` does."""
        columns = step_kernels
        failed = [
            int(row[c])
            for c in (
                columns.STATUS_JOINT_ITERATIONS,
                columns.STATUS_VELOCITY_ITERATIONS,
                columns.STATUS_LINEAR_ITERATIONS,
            )
        ]  # (the halves' launches write the rows)
        if len(self._fused_stages) > 1:
            self._update_frames()  # of the restored start: a later stage may have failed
        halves = combined(self._fused_substeps(depth + 1, 2))
        halves.joint_iterations += failed[0]
        halves.velocity_iterations += failed[1]
        halves.linear_iterations += failed[2]
        return halves

    def _fused_substeps(self, depth: int, count: int) -> list[StepStats]:
        """`count` composed substeps of dt / 2**depth by the fused kernel, their velocities left to the step's
        hand-out (`_split_step`): the stats of the runs of those that went OK, and of each one it handed back,
        halved (`_halved`), or at the deepest taken by the parallel schedule, which reports its failure."""
        columns = step_kernels
        order, fallback = self._fused_order
        launch = self._substep_launch(depth)
        status, summary_view, batch_view, spin_view = self._views
        parts: list[StepStats] = []
        while count:
            batch_view[0], batch_view[1], spin_view[0] = count, 0, self._spin
            launch.launch()
            summary = summary_view.tolist()
            ok = int(summary[columns.STATUS_CODE])
            if ok:
                parts.append(self._status_stats(summary, ok, order, fallback))
                self._spin = summary[columns.STATUS_SPIN]
                count -= ok
                if not count:
                    break
            row = status[ok].copy()  # the status rows are the next launch's
            code = int(row[columns.STATUS_CODE])
            self._spin = float(row[columns.STATUS_SPIN])
            count -= 1
            if code in (columns.SINGULAR, columns.VELOCITY):  # the substep was kept
                self.linear.check()  # a lost pivot raises
                parts.append(self._status_stats(row.tolist(), 1, order, fallback))
                if code == columns.VELOCITY:
                    self._velocity_failed(row[columns.STATUS_FAILED_VELOCITY])
                    parts[-1].converged = False
            elif depth >= self.max_substep_depth:  # its failure is reported, or warned of and gone on from
                if len(self._fused_stages) > 1:
                    self._update_frames()
                parts.append(self._advance(self.dt / 2**depth, depth, self._fused_stages))
            else:
                parts.append(self._halved(row, depth))
        return parts

    def _steps_alike(self, limit: int) -> int:
        """How many of the next steps (at most `limit`) share this step's active model forces (`_update_forces`
        decides by the same comparison); the answer holds until that step, so it is kept."""
        until = self.model.host.force_until
        if not len(until):
            return limit
        start, count = self._alike
        if not start <= self.step_count < start + count:
            times = self._clock_at(self.step_count + np.arange(self.FUSED_BATCH))
            active = times[:, None] < until[None, :]
            differ = np.flatnonzero((active != active[0]).any(axis=1))
            self._alike = (self.step_count, int(differ[0]) if len(differ) else self.FUSED_BATCH)
            start, count = self._alike
        return min(limit, start + count - self.step_count)

    def _fused_steps(self, n: int, combine: bool, out: list[StepStats], lazy: bool) -> int:
        """n steps by the fused schedule, as few launches as the forces allow, their stats appended to `out`
        (`_steps`' `combine`); a step it hands back (a spin split, a failed correction) is split, halved or
        reported (`_handed_back`). `lazy`: the last step leaves its velocity correction to `state` too
        (`_lazy_call`). Returns the count of steps taken."""
        done = 0
        columns = step_kernels
        order, fallback = self._fused_order
        while done < n:
            self._update_forces()
            batch = self._steps_alike(min(n - done, self.FUSED_BATCH))
            hand_out = not lazy and done + batch == n
            status, summary = self._run_fused(batch, hand_out)  # the batch's one read-back
            self._handout = self.defer_velocities and not hand_out
            first = int(summary[columns.STATUS_CODE])  # the OK steps, which the kernel stops after
            if first:
                out += self._fused_stats(status, first, summary, order, fallback, combine)
            self._advance_clock(first)
            done += first
            if first < batch:
                hand_out = not lazy and done + 1 == n
                out.append(self._handed_back(status[first], hand_out))
                self._handout = self.defer_velocities and not hand_out
                done += 1
            elif first:
                self._spin = summary[columns.STATUS_SPIN]
            if self.linear is not None:
                self.linear.check()  # and the redundant loop rows of the last factorization
        return done

    def _fused_step(self) -> StepStats:
        """One step (`step()`, the call a controller makes each tick, on a CPU): `_fused_steps`' work for n = 1
        without its loop's bookkeeping, `_lazy_call`, `_run_fused` and `_advance_clock` written out (their calls
        were a third of the host's time of a tick): one launch of one step, whose velocity correction `state`
        takes if it is read."""
        if self._forces_timed or self._active_forces is None:
            self._update_forces()
        lazy = self.defer_velocities and not self._read
        self._read = False
        dt, launches = self._tick
        if dt != self.dt:
            launches = self._tick_launches()
        views = self._views
        views[3][0] = self._spin
        launches[lazy]()
        summary = views[1].tolist()
        self._handout = lazy
        if summary[_CODE]:  # the step went OK
            order, fallback = self._fused_order
            stats = self._status_stats(summary, 1, order, fallback)
            if fallback:
                self._note_fallbacks([stats], self.time)
            self.step_count = count = self.step_count + 1
            time, start = self._clock
            self.time = time + (count - start) * self.dt
            self._spin = summary[_SPIN]
            if self._loop_rows_counted:  # a lost pivot stops the step (SINGULAR): only loop rows to count
                self.linear.check()
            return stats
        start = self.time
        stats = self._handed_back(views[0][0], not lazy)
        if self.linear is not None:
            self.linear.check()  # and the redundant loop rows of the last factorization
        self._note_fallbacks([stats], start)
        return stats

    def _handed_back(self, row: np.ndarray, hand_out: bool) -> StepStats:
        """The step whose status `row` stopped a fused launch: taken again where nothing of it was kept (SPLIT,
        RETRY; split or halved in fused launches on a CPU, `_split_step`, else by the parallel schedule), else
        (SINGULAR, VELOCITY) reported from the row. `hand_out`: its state is handed out (`defer_velocities`)."""
        columns = step_kernels
        code = int(row[columns.STATUS_CODE])
        self._spin = float(row[columns.STATUS_SPIN])
        # (The controller's steps take many sizes: no substep arrays a size for them.)
        fused = self._splits_fused()
        if fused and (code == columns.SPLIT or (code == columns.RETRY and self.max_substep_depth > 0)):
            return self._split_step(row, hand_out)
        if code in (columns.SPLIT, columns.RETRY):  # nothing of this step was kept
            if code == columns.RETRY and len(self._fused_stages) > 1:
                self._update_frames()  # of the restored start: a later stage may have failed
            return self._step_parallel(hand_out)
        if code == columns.SINGULAR:
            self.linear.check()
        stats = self._status_stats(row.tolist(), 1, *self._fused_order)
        if code == columns.VELOCITY:
            sweeps = int(row[columns.STATUS_VELOCITY_ITERATIONS]) if self.linear is None else 0
            self._velocity_failed(row[columns.STATUS_FAILED_VELOCITY], sweeps)
            stats.converged = False
        self._advance_clock(1)
        return stats

    @classmethod
    def _fused_stats(
        cls, status: np.ndarray, ok: int, summary: list[float], order: int, fallback: str, combine: bool
    ) -> list[StepStats]:
        """The StepStats of the `ok` fused steps that went OK, one a status row; with `combine` (or one step), one
        StepStats of them all: the kernel's summary row, which sums them up as `combined` would (the host's numpy
        reductions of a batch cost ~12 us a launch, a StepStats a step ~0.5 us)."""
        if combine or ok == 1:
            return [cls._status_stats(summary, ok, order, fallback)]
        return [cls._status_stats(row, 1, order, fallback) for row in status[:ok].tolist()]

    @staticmethod
    def _status_stats(row: list[float], steps: int, order: int, fallback: str) -> StepStats:
        """A StepStats of a status row (or of the summary row of `steps` steps). Made without `__init__`: the
        figures a row holds set on a bare instance, the fields it has no figure for or whose figure is the default
        left at their class defaults (a dataclass keeps a field's default as a class attribute), in half the time
        of the 14-field `__init__` (each `step()` makes one)."""
        stats = _bare(StepStats)
        stats.joint_iterations = int(row[_JOINT])
        stats.velocity_iterations = int(row[_VELOCITY])
        stats.max_joint_error = row[_JOINT_ERROR]
        stats.max_velocity_error = row[_VELOCITY_ERROR]
        stats.linear_iterations = int(row[_LINEAR])
        if steps != 1:
            stats.substeps = steps
        if order != 2:
            stats.order = order
        if fallback:
            stats.fallback = fallback
        return stats

    def _run_fused(self, batch: int, hand_out: bool) -> tuple[np.ndarray, list[float]]:
        """Up to `batch` steps of dt by the fused kernel, from the spin of the last step: their status rows and
        the summary row's values (`warpimpulse/split.py` runs them on several threads instead). `hand_out`: the
        last step's state is handed out, so its velocities are corrected (`defer_velocities`)."""
        launch = self._fused_by_h.get(self.dt) or self._fused_launch(self.dt)
        if self._views is None:
            self._batch.assign(np.array([batch, int(hand_out)], dtype=np.int32))
            self._spin_in.fill_(self._spin)
            wp.capture_launch(launch)
            status = self._status.numpy()
            return status, status[-1].tolist()
        status, summary, batch_view, spin_view = self._views
        batch_view[0], batch_view[1], spin_view[0] = batch, hand_out, self._spin
        launch.launch()
        return status, summary.tolist()
