"""Simulator.step(): the impulse loop of the method paper (sections 4.2-4.5; docs/architecture.md, "One step").

    predict every body over h (RK4) -> joint errors d(t0+h) -> within tolerance? else solve
    K lambda = -d/h, apply the impulses at t0, and predict again -> the last prediction is the new state
    -> frames and K at t0+h, factored once -> velocity correction K lambda = -J v, exact in one solve.
The factorization made at t0+h serves the next step's joint correction, which happens at the same time.
"""

from __future__ import annotations

import math
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np
import warp as wp

from . import accuracy as accuracy_control
from . import capabilities, checks, composition, coordinates, diagnose
from .contacts import BROAD_PHASES, CONTACT_SOLVERS, Contacts, ContactStage
from .files import write_atomically
from .kernels import carry as carry_kernels
from .kernels import constraints as constraint_kernels
from .kernels import forces as force_kernels
from .kernels import impulses as impulse_kernels
from .kernels import inertia as inertia_kernels
from .kernels import iterative as iterative_kernels
from .kernels import limits as limit_kernels
from .kernels import loop as loop_kernels
from .kernels import rigid as rigid_kernels
from .kernels import step as step_kernels
from .kernels import worlds as world_kernels
from .launch import Launches, capture, record, run
from .model import Model, State
from .options import StepOptions
from .options import resolve as resolve_options
from .solver import CGSolver, CholeskySolver, Frames, loop_tolerance_for
from .steps import SimulationError, StepStats, diverging
from .transforms import quat_rotate, quat_to_matrix
from .types import DRIVE_MODES, FORMULATIONS, NEWTON_BODIES, SCHEDULES, SOLVERS
from .verbosity import verbose as show_warp_messages
from .worlds import Batch, WorldStats

POLICIES = ("raise", "warn")
ROWS_FALLBACK = "joint limits, stiff motors or distance rows (impacts and saturation are not reversible)"
"""Why a scene with such rows takes its steps at order 2 whatever order was asked: a composed step would run
them backwards in its negative substeps (`StepStats.fallback`)."""
VELOCITY_ALTERNATIONS = 10
"""Rounds of (joint velocity correction, contact velocity sweeps) at t0+h before the last joint correction: the
two blocks converge linearly into each other (a cart on its wheels: about 0.7 a round)."""


STATE = ("x", "q", "v", "w")  # the state arrays in a checkpoint (State.body_x, ...)


class CheckpointError(ValueError):
    """A checkpoint that cannot be loaded into this simulator; the message names the file and the reason."""


def _combined(parts: list[StepStats]) -> StepStats:
    """The stats of one step taken as consecutive substeps."""
    return StepStats(
        sum(p.joint_iterations for p in parts),
        sum(p.velocity_iterations for p in parts),
        max(p.max_joint_error for p in parts),
        parts[-1].max_velocity_error,
        all(p.converged for p in parts),
        sum(p.linear_iterations for p in parts),
        sum(p.substeps for p in parts),
        min(p.order for p in parts),
        next((p.fallback for p in parts if p.fallback), ""),
        parts[-1].contacts,
        max(p.max_penetration for p in parts),
        sum(p.contact_sweeps for p in parts),
        min((p.step_size for p in parts if not math.isnan(p.step_size)), default=math.nan),
        sum(p.error_estimate for p in parts),
    )


class Simulator:
    """Steps a Model in time with the impulse method; reads and writes its State as numpy arrays.

    Frames: positions, velocities and angular velocities are world frame; quaternions are (x, y, z, w).
    """

    def __init__(
        self,
        model: Model,
        dt: float | None = None,
        tolerance: float | None = None,
        velocity_tolerance: float | None = None,
        solver: str = "auto",
        max_iterations: int = 100,
        on_max_iterations: str = "raise",
        order: int = 2,
        contact_solver: str = "pgs",
        contact_margin: float = 0.005,
        accuracy: float | None = None,
        verbose: bool = False,
        options: StepOptions | None = None,
        **legacy,
    ) -> None:
        """Args:
        model: the scene (`SceneBuilder.finalize()`).
        dt: the step (s); with `accuracy`, the interval each `step()` advances (a frame, a control tick), taken as
            whole steps of at most dt (default `accuracy.DEFAULT_INTERVAL`).
        tolerance: the largest joint error a step may leave (m for translational constraints, rad for
            rotational ones); the joint correction iterates until every joint holds to it.
        velocity_tolerance: the same for the constraint velocities after the step (m/s, rad/s); defaults to
            `tolerance`.
        solver: "auto", "cholesky", "cg" or "iterative" (`types.SOLVERS`). "auto" is "cholesky": one exact
            factorization a step serves the velocity correction and the next joint correction, and it is
            linear in the joints of a tree or a star. "cg" iterates on the same matrix; "iterative" is the
            paper's joint-by-joint baseline without a system.
        max_iterations: joint-correction iterations (solves or sweeps) before the step fails.
        on_max_iterations: "raise" a SimulationError naming the worst joints, or "warn" and go on with
            `StepStats.converged` False.
        verbose: turn Warp's info messages back on (`Module ... load` lines as kernels are loaded); they are
            off by default (`warpimpulse.verbosity`).
        order: 2, 4 or 6 in time. 2 is the paper's step; 4 and 6 compose it symmetrically, some substeps
            running backwards (`composition.py`). Spin splits and halving on failure apply to whole composed
            steps. Without `tolerance`, the tolerance follows the order (`composition.default_tolerance`:
            1e-6 at order 2, 10 dt^(order+1) in [1e-12, 1e-6] at 4 and 6) so that it does not cap the order.
        contact_solver: "pgs" or "paper" (`contacts.CONTACT_SOLVERS`): how the contacts' push-only impulses are
            found in the correction loop. Contacts hold to `tolerance` (m) like the joints.
        contact_margin: shapes closer than this (m) on the predicted state are contacts (speculative ones push
            only if the corrections close them).
        accuracy: m. Instead of a fixed step: the order, the joint tolerance (unless given) and the step size are
            chosen so that the body centres stay within about this of the exact trajectory over
            `sim.accuracy.horizon` seconds (1 s unless set), the step size following an error estimate
            (`accuracy.py`, docs/accuracy.md); `StepStats.error_estimate` reports it. Contacts and batched worlds
            are refused; scenes with limits, stiff motors or distance rows are controlled at order 2.
        options: the performance switches (`StepOptions`): schedule, formulation, composition scheme, Newton step,
            carried right-hand side, deferred velocity correction, kernel specialization, spin splits, halving
            depth and the contacts' broad phase and sweeps. Each chooses itself from the scene and the machine
            by default. `legacy`: the same switches as keywords, the old spelling, deprecated (a
            DeprecationWarning names the new one).
        """
        if not isinstance(model, Model):
            raise TypeError(f"model must be a Model (from SceneBuilder.finalize()), got {type(model).__name__}")
        self.options = options = resolve_options(options, legacy, type(self).__name__)
        schedule, formulation, scheme = options.schedule, options.formulation, options.scheme
        newton, carry, defer_velocities = options.newton, options.carry, options.defer_velocities
        specialize, max_rotation, max_substep_depth = (
            options.specialize,
            options.max_rotation,
            options.max_substep_depth,
        )
        broad_phase, contact_sweeps = options.broad_phase, options.contact_sweeps
        plan = None
        if accuracy is not None:
            plan = accuracy_control.plan(model, accuracy, dt, tolerance, order)
            dt, order, tolerance = plan.dt, plan.order, plan.tolerance
        elif dt is None:
            raise ValueError("dt (the step, s) is required unless accuracy (m) is given")
        dt = checks.positive(dt, "dt", " (seconds)")
        self.order = checks.integer(order, "order", 2)
        self.scheme = composition.scheme(self.order, scheme)
        tolerance = composition.default_tolerance(dt, self.order) if tolerance is None else tolerance
        tolerance = checks.positive(tolerance, "tolerance", " (m or rad)")
        velocity_tolerance = tolerance if velocity_tolerance is None else velocity_tolerance
        velocity_tolerance = checks.positive(velocity_tolerance, "velocity_tolerance", " (m/s or rad/s)")
        max_iterations = checks.integer(max_iterations, "max_iterations", 1)
        max_substep_depth = checks.integer(max_substep_depth, "max_substep_depth", 0)
        contact_margin = checks.positive(contact_margin, "contact_margin", " (m)")
        contact_sweeps = checks.integer(contact_sweeps, "contact_sweeps", 1)
        if contact_solver not in CONTACT_SOLVERS:
            raise ValueError(f"unknown contact_solver {contact_solver!r}; expected one of {CONTACT_SOLVERS}")
        if broad_phase not in BROAD_PHASES:
            raise ValueError(f"unknown broad_phase {broad_phase!r}; expected one of {BROAD_PHASES}")
        if max_rotation is not None:
            max_rotation = checks.positive(max_rotation, "max_rotation", " (rad), or None")
        if not isinstance(formulation, str) or formulation not in ("auto", *FORMULATIONS):
            raise ValueError(f"unknown formulation {formulation!r}; expected auto or one of {FORMULATIONS}")
        if not isinstance(solver, str) or solver not in SOLVERS:
            raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
        if not isinstance(schedule, str) or schedule not in SCHEDULES:
            raise ValueError(f"unknown schedule {schedule!r}; expected one of {SCHEDULES}")
        if not isinstance(on_max_iterations, str) or on_max_iterations not in POLICIES:
            raise ValueError(f"on_max_iterations must be one of {POLICIES}, got {on_max_iterations!r}")
        if newton not in (None, True, False):
            raise ValueError(
                f"newton must be True, False or None (on for {NEWTON_BODIES} bodies or more), got {newton!r}"
            )
        if newton and (solver not in ("auto", "cholesky") or model.constraint_count == 0):
            raise ValueError(f"newton needs joints and the cholesky solver; got solver {solver!r} and "
                             f"{model.constraint_count} constraints")  # fmt: skip
        if carry not in (None, True, False):
            raise ValueError(f"carry must be True, False or None (on where it is supported), got {carry!r}")
        carried = solver in ("auto", "cholesky") and model.constraint_count > 0
        carried = carried and model.colliders is None
        if carry and not carried:
            raise ValueError(
                f"carry needs joints, the cholesky solver and no contacts; got solver {solver!r}, "
                f"{model.constraint_count} constraints and {'' if model.colliders is not None else 'no '}colliders"
            )
        if verbose:
            show_warp_messages()
        if solver == "iterative" and model.limit_count:
            raise ValueError(
                "solver 'iterative' has no joint limits, stiff motors or distance constraints: use 'cholesky' or 'cg'"
            )
        if solver == "iterative" and model.element_count:
            raise ValueError(
                "solver 'iterative' predicts each body alone with a constant force; the scene's springs, joint "
                "springs or motors couple bodies in the prediction: use 'cholesky' or 'cg'"
            )
        self.model = model
        self.dt = dt
        self.tolerance = tolerance
        self.velocity_tolerance = velocity_tolerance
        self.max_iterations = max_iterations
        self.on_max_iterations = on_max_iterations
        self.max_substep_depth = max_substep_depth
        self.max_rotation = max_rotation
        self.solver_name = "cholesky" if solver == "auto" else solver
        self.specialized = specialize
        self.time = 0.0
        self.step_count = 0
        self._clock = (0.0, 0)  # (time, step count) the clock counts steps of dt from (`_set_step_size`)

        self.state = model.state()
        self.pred = model.state()
        self.control = model.control()
        self._user_force = np.zeros((model.body_count, 3))
        self._user_torque = np.zeros((model.body_count, 3))
        self._active_forces: tuple | None = None
        self.frames = Frames(model)
        self.kernels = constraint_kernels.specialized(
            frozenset(model.kinds) if specialize else constraint_kernels.ALL_KINDS
        )
        nc = model.constraint_count
        d = model.device
        self.errors = wp.zeros(nc, dtype=wp.float64, device=d)
        self.rhs = wp.zeros(nc, dtype=wp.vec3d, device=d)
        self.impulse = wp.zeros(nc, dtype=wp.vec3d, device=d)
        self.sweep_error = wp.zeros(1, dtype=wp.float64, device=d)
        loops = bool(model.topology.loop_joints)  # their redundant rows take E's approximation worse (docs)
        wanted = newton if newton is not None else model.body_count >= NEWTON_BODIES and not loops
        self.newton = bool(wanted and self.solver_name == "cholesky" and nc > 0)
        # The Newton step's scratch: the bodies' velocity changes from its impulses, its right-hand side.
        self.response_v = wp.zeros(model.body_count if self.newton else 0, dtype=wp.vec3d, device=d)
        self.response_w = wp.zeros_like(self.response_v)
        self.newton_rhs = wp.zeros(nc if self.newton else 0, dtype=wp.vec3d, device=d)
        # The first iteration's carried right-hand side (`carry`, kernels/carry.py): a row of c (and of the value
        # measured in the step, taken when it is kept) for each step size of a stage at dt, the others' on demand.
        self.carry = bool(carried if carry is None else carry)
        self._fractions = tuple(dict.fromkeys((*self.scheme.stages, 1.0)))  # 1.0: a composed step's order-2 fallback
        self._carry_rows = {g * dt: r for r, g in enumerate(self._fractions)}
        rows = len(self._fractions) if self.carry else 0
        self._carry = wp.zeros((rows, nc), dtype=wp.vec3d, device=d)
        self._carry_next = wp.zeros_like(self._carry)
        self._carry_other: dict[float, tuple[wp.array, wp.array]] = {}  # halved and split step sizes
        self.linear = None
        if nc == 0:  # free bodies only: nothing to solve
            pass
        elif self.solver_name == "cholesky":
            self.linear = CholeskySolver(
                model, self.frames, formulation=formulation, loop_tolerance=loop_tolerance_for(tolerance)
            )
        elif self.solver_name == "cg":
            self.linear = CGSolver(model, self.frames)
        self._counts = (model.body_count, nc)
        # The scene's features the schedules take or not (`capabilities.TABLE`, docs/capabilities.md).
        self.features = capabilities.scene_features(
            model, self.solver_name, self.order, self._split_systems, self.newton
        )
        self._forced = model.element_count > 0  # state-dependent forces: the coupled RK4 prediction
        if self._forced:
            self._stage = model.state()
            sums = model.state()  # the weighted sums of the RK4 stage derivatives
            self.rk4_sum_x, self.rk4_sum_q, self.rk4_sum_v, self.rk4_sum_w = (
                sums.body_x,
                sums.body_q,
                sums.body_v,
                sums.body_w,
            )
            self.wrench_force = wp.zeros(2 * model.element_count, dtype=wp.vec3d, device=d)
            self.wrench_torque = wp.zeros(2 * model.element_count, dtype=wp.vec3d, device=d)
        self.drive_target = wp.array(model.host.drive_target, dtype=wp.float64, device=d)
        self.drive_integral = wp.zeros(model.drive_count, dtype=wp.float64, device=d)
        nl = model.limit_count
        self.limit_impulse = wp.zeros(nl, dtype=wp.float64, device=d)  # accumulated over the step, push only
        (self.limit_value, self.limit_rate, self.limit_error, self.limit_velocity_impulse, self.limit_rhs,
         self.limit_delta, self.limit_low, self.limit_high, self.limit_goal, self.limit_before,
         self.limit_scratch) = (wp.zeros(nl, dtype=wp.float64, device=d) for _ in range(11))  # fmt: skip
        self.limit_mask = wp.zeros(nl, dtype=wp.int32, device=d)
        self.limit_matrix = wp.zeros(nl * nl, dtype=wp.float64, device=d)  # the rows' system S
        self.limit_work = wp.zeros(nl * nl, dtype=wp.float64, device=d)
        self.limit_side_body = wp.zeros(2 * nl, dtype=wp.int32, device=d)  # each row's Jacobian g, both sides
        self.limit_side_lin = wp.zeros(2 * nl, dtype=wp.vec3d, device=d)
        self.limit_side_ang = wp.zeros(2 * nl, dtype=wp.vec3d, device=d)
        self.limit_coupling = wp.zeros(nl * nc, dtype=wp.vec3d, device=d)  # J M^-1 g^T of each limit
        self.limit_response = wp.zeros(nl * nc, dtype=wp.vec3d, device=d)  # K^-1 J M^-1 g^T
        self.batch: Batch | None = None  # the per-world side of batched worlds (`worlds.py`)
        if model.world_count > 1:
            capabilities.refuse("worlds", self.features, f"{model.world_count} worlds")
            if nc == 0:
                raise ValueError(f"the worlds schedule needs joints; the {model.world_count} worlds have none")
            self.world_summary = wp.zeros((model.world_count, 2), dtype=wp.float64, device=d)
            self.world_active = wp.ones(model.world_count, dtype=wp.int32, device=d)
            self.batch = Batch(self)
        if defer_velocities not in (None, True, False):
            raise ValueError(
                f"defer_velocities must be True, False or None (on where it is exact), got {defer_velocities!r}"
            )
        why = self._velocities_needed()
        if defer_velocities and why:
            raise ValueError(f"defer_velocities needs a step whose velocities enter the next only through its "
                             f"joint correction; this simulator has {why}")  # fmt: skip
        self.defer_velocities = bool(defer_velocities is not False and not why)
        self._launches_by_h: dict[float, tuple] = {}
        self._loops_by_h: dict[float, tuple] = {}  # the parallel schedule's device-decided loops (`_device_loops`)
        self._v0 = wp.zeros_like(self.state.body_v)
        self._w0 = wp.zeros_like(self.state.body_w)
        self.summary = wp.zeros(2, dtype=wp.float64, device=d)  # NaN/Inf bodies, largest |w|
        # The joint-correction loop's record and its go-on flag, decided on the device (`kernels/loop.py`).
        self.loop_state = wp.zeros((1, loop_kernels.LOOP_WIDTH), dtype=wp.float64, device=d)
        self.loop_batch = wp.ones(1, dtype=wp.int32, device=d)  # the one world stays in its "batch"
        self.loop_active = wp.zeros(1, dtype=wp.int32, device=d)
        self.loop_go = wp.zeros(1, dtype=wp.int32, device=d)
        self._limit_world = wp.zeros(model.limit_count, dtype=wp.int32, device=d)  # one world's limits
        self._fingerprint = diagnose.fingerprint(model)
        self._spin = 0.0  # rad/s: the largest |w| of the last prediction checked (the state before its velocity fix)
        self._record_launches()
        self._start = model.state()  # the state at the start of a composed step, restored if a stage fails
        self._integral0 = wp.zeros_like(self.drive_integral)  # the drives' integrals there (stages integrate them)
        self._save_start = self._capture(
            lambda: self._start.copy_from(self.state), lambda: wp.copy(self._integral0, self.drive_integral)
        )
        self._fallback = ""  # why the next step must be taken at order 2 (`fall_back`)
        self.contact_stage = None
        self._penetration, self._contact_sweeps = 0.0, 0  # of the (sub)step's position phase
        if model.colliders is not None:
            self.contact_stage = ContactStage(
                model, self.frames, self.control, self.state, self.pred, self.tolerance, self.velocity_tolerance,
                contact_margin, contact_solver, broad_phase, contact_sweeps, self if self._direct else None,
            )  # fmt: skip
        self.schedule, self.schedule_note = self._pick_schedule(schedule, specialize)
        self._update_frames()
        self._check_finite(self.state, 0)
        self.accuracy = None if plan is None else accuracy_control.Controller(self, plan)
        """The step-size controller where `accuracy` was given (`accuracy.Controller`: its plan, horizon, step)."""

    # ---------------------------------------------------------------- launches
    @property
    def _split_systems(self) -> bool:
        """Whether the Cholesky solver factors the tree's and the loop joints' systems apart (formulation "split",
        section 4.6), which iterate their velocity correction side by side."""
        return getattr(getattr(self.linear, "pattern", None), "formulation", "") == "split"

    def _velocities_needed(self) -> str:
        """Why a step's velocities must be corrected before the next step (`defer_velocities`), or ""."""
        m = self.model
        reasons = (
            (self.solver_name != "cholesky" or m.constraint_count == 0, f"the {self.solver_name!r} solver"),
            (self._split_systems, "the split formulation"),
            (m.element_count > 0, "force elements (springs, joint springs, drives)"),
            (m.limit_count > 0, "joint limits, stiff motors or distance constraints"),
            (m.colliders is not None, "contacts"),
            (m.world_count > 1, "batched worlds"),
        )
        return ", ".join(why for needed, why in reasons if needed)

    def _record(self, kernel, dim: int, data_in: State | None = None, data_out: State | None = None, **values):
        """A recorded launch whose parameters are bound by name to the Model, Frames, Control and the
        simulator's scratch arrays (`launch.record`)."""
        sources = (self.model, self.frames, self.control, self)
        return record(kernel, dim, self.model.device, sources, data_in, data_out, **values)

    def _capture(self, *work) -> wp.Graph:
        return capture(self.model.device, *work)

    def _record_launches(self) -> None:
        s, (nb, nc) = self.state, self._counts
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
        self._accept_work = (lambda: self.state.copy_from(self.pred), *frames)
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
        s, nl, nc = self.state, self.model.limit_count, self.model.constraint_count
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

    def _use_step_size(self, h: float) -> None:
        """Point the launches that depend on the step size at h (recorded once per h, then cached)."""
        if h not in self._launches_by_h:
            s, p, (nb, nc) = self.state, self.pred, self._counts
            if self._forced:
                predict = self._coupled_prediction(h)
            else:
                group = rigid_kernels.LANES if self.model.device.is_cpu else 1  # bodies a thread
                predict = self._record(rigid_kernels.predict, -(-nb // group), s, p, h=h, group_size=group)
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
                    c, c_next = self._carry_arrays(h)
                    carry_in = [self._record(carry_kernels.carry_in, nc, carry=c, rhs_out=self.rhs)]
                    carry_out = [self._record(carry_kernels.carry_out, nc, carry=c, rhs_in=self.rhs,
                                              carry_next_out=c_next)]  # fmt: skip
                if self.newton:  # the first solves again with rhs - E lambda (`newton`)
                    newton = [
                        self._record(impulse_kernels.impulse_responses, nb, s),
                        self._record(self.kernels.arm_corrections, nc, p, h=h),
                        *self.linear.solve_launches(self.newton_rhs, self.impulse),
                    ]
                if carry_in or newton:
                    first_iteration = (*carry_in, *self._mask, *solve, *newton, self._apply, correct_limits, predict,
                                       *measure, *carry_out)  # fmt: skip
                    iterate_first = self._capture(*first_iteration)
            self._launches_by_h[h] = (predict, errors, sweep, self._capture(predict, *measure), iterate,
                                      iterate_first, ((predict, *measure), first_iteration, iteration), integrate,
                                      correct_limits, correct_limit_velocities)  # fmt: skip
        (self._predict, self._position_errors, self._sweep_positions, self._evaluate, self._iterate,
         self._iterate_first, self._loop_work, self._integrate_drives, self._correct_limits,
         self._correct_limit_velocities) = self._launches_by_h[h]  # fmt: skip
        self._h = h

    def _carry_arrays(self, h: float) -> tuple[wp.array, wp.array]:
        """(c, the c measured in the step) for steps of h (`carry`): a stage's rows at dt, which the fused kernel
        shares, or arrays of their own for a halved or split step size."""
        if h in self._carry_rows:
            r = self._carry_rows[h]
            return self._carry[r], self._carry_next[r]
        if h not in self._carry_other:
            c = wp.zeros(self.model.constraint_count, dtype=wp.vec3d, device=self.model.device)
            self._carry_other[h] = (c, wp.zeros_like(c))
        return self._carry_other[h]

    def _keep_carry(self, h: float) -> None:
        """A kept step of h whose first solve ran: its c becomes the value it measured (`carry`)."""
        wp.copy(*self._carry_arrays(h))

    def _carries(self) -> dict[float, wp.array]:
        """c of every step size that has one (`carry`)."""
        return {h: self._carry_arrays(h)[0] for h in (*self._carry_rows, *self._carry_other)} if self.carry else {}

    def _forget_carry(self, world: int | None = None) -> None:
        """No c to carry, for one world or all: its state was set from outside the step (`reset`, `set_state`)."""
        nc = self.model.world_constraint_count
        rows = slice(None) if world is None else slice(world * nc, (world + 1) * nc)
        for c in self._carries().values():
            c[rows].zero_()

    def _device_loops(self) -> tuple[wp.Graph, wp.Graph | None, wp.Graph | None] | None:
        """The parallel schedule's loops at the current step size as graphs decided on the device (captured
        once per step size): the joint correction, accepting the prediction with its factor and velocity
        correction, and the velocity correction alone (the last two None with limits or split systems, whose
        velocity rows the host sequences; the last is a deferred one, `defer_velocities`). None where the
        host keeps its loops: other solvers, batched worlds (`worlds.py` decides per world), and the fused
        schedule's rare parallel steps (a fused share must find nothing to capture when threads step it)."""
        if not self._direct or self.batch is not None or self.schedule != "parallel":
            return None
        if self._h not in self._loops_by_h:
            first, first_iteration, iteration = self._loop_work
            errors = ((self.errors, self.model.constraint_world), (self.limit_error, self._limit_world))
            correct = self._capture_loop(first, iteration, errors, self.tolerance, self.max_iterations,
                                         first_iteration=first_iteration)  # fmt: skip
            finish = fix = None
            if not self.model.limit_count and not self._split_systems:
                first = (*self._accept_work, self._integrate_drives, self._velocity_errors)
                finish = self._capture_loop(first, self._velocity_fix_work, errors[:1], self.velocity_tolerance, 1)
                fix = self._capture_loop((self._velocity_errors,), self._velocity_fix_work, errors[:1],
                                         self.velocity_tolerance, 1)  # fmt: skip
            self._loops_by_h[self._h] = (correct, finish, fix)
        return self._loops_by_h[self._h]

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

    def _coupled_prediction(self, h: float) -> Launches:
        """RK4 over all bodies at once, the springs and drives evaluated at every stage (`kernels/forces.py`)."""
        m, s, p, stage = self.model, self.state, self.pred, self._stage
        start = dict(start_x=s.body_x, start_q=s.body_q, start_v=s.body_v, start_w=s.body_w)
        launches = []
        for k in range(4):
            at = s if k == 0 else stage
            launches.append(self._record(force_kernels.spring_wrenches, m.spring_count, at))
            launches.append(
                self._record(force_kernels.drive_wrenches, m.force_drive_count, at, row_offset=m.spring_count)
            )
            launches.append(
                self._record(force_kernels.rk4_stage, m.body_count, at, p if k == 3 else stage, stage=k, h=h, **start)
            )
        return Launches(launches)

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

    # ---------------------------------------------------------------- forces
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
        (n, *shape) for one world or a one-world model, (W, n, *shape) for all batched worlds."""
        m = self.model
        if world is None:
            lead = (m.body_count,) if m.world_count == 1 else (m.world_count, m.world_body_count)
            return slice(None), self._checked(values, (*lead, *shape), what).reshape(-1, *shape)
        return self._world_rows(world), self._checked(values, (m.world_body_count, *shape), what)

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
        bad = dynamic & ~(masses > 0.0)
        if not bad.any():
            sym = np.abs(inertias - inertias.transpose(0, 2, 1)).max(axis=(1, 2)) <= 1e-9 * np.abs(inertias).max()
            bad = dynamic & ~sym
            bad[dynamic] |= np.linalg.eigvalsh(0.5 * (inertias[dynamic] + inertias[dynamic].transpose(0, 2, 1)))[
                :, 0] <= 0.0  # fmt: skip
        if bad.any():
            b = int(np.flatnonzero(bad)[0])
            raise ValueError(f"body {m.body_name[b]!r}: mass {masses[b]} and inertia {inertias[b].tolist()} must be "
                             "positive (definite, symmetric)")  # fmt: skip
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
        values = self.drive_target.numpy()
        values[drive] = target
        self.drive_target.assign(values)

    @staticmethod
    def _checked(values, shape, what) -> np.ndarray:
        arr = checks.numbers(values, what)
        if arr.shape != shape:
            raise ValueError(f"{what} must have shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{what} contains NaN or Inf")
        if np.abs(arr).max(initial=0.0) > checks.LARGEST:
            raise ValueError(f"{what} holds values too large for double precision (> {checks.LARGEST:g})")
        return arr

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
        if not len(h.force_until) and self._active_forces is not None:  # no model forces: ~1 us a call saved
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

    # ---------------------------------------------------------------- schedules
    FUSED_BATCH = 256  # steps a fused launch may take: the status rows read back at once

    def _pick_schedule(self, schedule: str, specialize: bool) -> tuple[str, str]:
        """The schedule that runs ("fused" or "parallel") and, when it is not the one asked, why."""
        cuda = self.model.device.is_cuda
        if schedule == "parallel" or (schedule == "auto" and cuda):
            return "parallel", ""
        gap = capabilities.first_gap("fused", self.features, "falls back")
        if gap is not None:
            return "parallel", gap[1].note
        rows = self.model.limit_count > 0  # limits, stiff motors, distance constraints (kernels/limits.py)
        kinds = frozenset(self.model.kinds) if specialize else constraint_kernels.ALL_KINDS
        self._fused = step_kernels.fused(frozenset(int(k) for k in kinds), self._forced, rows)
        self._elements = self._force_elements()
        # A row a step, and the launch's OK steps summed up in the last (`kernels/step.py` `finish`).
        self._status = wp.zeros(
            (self.FUSED_BATCH + 1, step_kernels.STATUS_WIDTH), dtype=wp.float64, device=self.model.device
        )
        # The batch size, whether its last step's state is handed out (`defer_velocities`) and the starting spin
        # of a launch, written by the host before each replay.
        self._batch = wp.zeros(2, dtype=wp.int32, device=self.model.device)
        self._spin_in = wp.zeros(1, dtype=wp.float64, device=self.model.device)
        # CPU arrays' memory, read and written without a copy
        self._views = None if cuda else (self._status.numpy(), self._batch.numpy(), self._spin_in.numpy())
        # A step with rows is taken at order 2, as the parallel schedule takes it (ROWS_FALLBACK).
        self._fused_stages = (1.0,) if rows else self.scheme.stages
        self._stages = wp.array(self._fused_stages, dtype=wp.float64, device=self.model.device)
        rows = [self._carry_rows[g * self.dt] for g in self._fused_stages]
        self._stage_carry = wp.array(rows, dtype=wp.int32, device=self.model.device)
        self._fused_by_h: dict[float, wp.Graph] = {}
        self._alike = (0, 0)  # (step, count): the steps from `step` on that share its forces
        return "fused", ""

    def _force_elements(self) -> step_kernels.ForceElements:
        """The force elements and the coupled prediction's scratch, for the fused kernel (empty without)."""
        elements = step_kernels.ForceElements()
        if not self._forced:
            return elements
        m = self.model
        for field in step_kernels.ForceElements.vars:
            if hasattr(m, field):
                setattr(elements, field, getattr(m, field))
        elements.drive_target, elements.drive_integral = self.drive_target, self.drive_integral
        elements.integral0 = self._integral0
        elements.wrench_force, elements.wrench_torque = self.wrench_force, self.wrench_torque
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

    def _fused_launch(self, h: float) -> wp.Graph:
        """The fused kernel's launch for steps of h, recorded and captured once per h."""
        if h not in self._fused_by_h:
            p = self.pred
            direct = self.linear is not None
            kernel = self._fused.cholesky_steps if direct else self._fused.iterative_steps
            sources = (self.model, self.frames, self.control, self)
            if direct:
                sources = (self.linear.fused_args, *sources, self.linear.device_pattern, self.linear)
            launch = record(
                kernel, 1, self.model.device, sources, data_out=self.state,
                h=h, stages=self._stages, reach=max(abs(g) for g in self._fused_stages), batch_in=self._batch,
                defer=int(self.defer_velocities),
                max_rotation=self.max_rotation or 0.0, final=int(self.max_substep_depth == 0), spin_in=self._spin_in,
                pred_x=p.body_x, pred_q=p.body_q, pred_v=p.body_v, pred_w=p.body_w, x0=self._start.body_x,
                q0=self._start.body_q, v0=self._v0, w0=self._w0, status_out=self._status, elements=self._elements,
                limit_rows=self._rows, newton=int(self.newton), carrying=int(self.carry),
                stage_carry=self._stage_carry, carry=self._carry, carry_next=self._carry_next,
            )  # fmt: skip
            self._fused_by_h[h] = self._capture(launch)
        return self._fused_by_h[h]

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

    def _fused_steps(self, n: int, combine: bool, out: list[StepStats]) -> int:
        """n steps by the fused schedule, as few launches as the forces allow, their stats appended to `out`
        (`_steps`' `combine`); a step it hands back (a spin split, a failed correction) is taken by the parallel
        schedule, which splits, halves or reports it. Returns the count of steps taken."""
        done = 0
        columns = step_kernels
        order, fallback = self.order, ""
        if len(self._fused_stages) < len(self.scheme.stages):
            order, fallback = 2, ROWS_FALLBACK
        while done < n:
            self._update_forces()
            batch = self._steps_alike(min(n - done, self.FUSED_BATCH))
            status = self._run_fused(batch, done + batch == n)  # the one read-back of the batch
            summary = status[-1].tolist()  # the OK steps, which the kernel stops after
            first = int(summary[columns.STATUS_CODE])
            if first:
                out += self._fused_stats(status[:first], summary, order, fallback, combine)
            self._advance_clock(first)
            done += first
            if first < batch:
                row = status[first]
                code = int(row[columns.STATUS_CODE])
                self._spin = float(row[columns.STATUS_SPIN])
                if code in (columns.SPLIT, columns.RETRY):  # nothing of this step was kept
                    if code == columns.RETRY and len(self._fused_stages) > 1:
                        self._update_frames()  # of the restored start: a later stage may have failed
                    out.append(self._step_parallel(done + 1 == n))
                    done += 1
                else:
                    if code == columns.SINGULAR:
                        self.linear.check()
                    stats = self._status_stats(row.tolist(), 1, order, fallback)
                    if code == columns.VELOCITY:
                        self._velocity_failed(row[columns.STATUS_FAILED_VELOCITY])
                        stats.converged = False
                    out.append(stats)
                    self._advance_clock(1)
                    done += 1
            elif first:
                self._spin = summary[columns.STATUS_SPIN]
            if self.linear is not None:
                self.linear.check()  # and the redundant loop rows of the last factorization
        return done

    @classmethod
    def _fused_stats(
        cls, status: np.ndarray, summary: list[float], order: int, fallback: str, combine: bool
    ) -> list[StepStats]:
        """The StepStats of fused steps that went OK, one a status row; with `combine` (or one step), one StepStats
        of them all: the kernel's summary row, which sums them up as `_combined` would (the host's numpy
        reductions of a batch cost ~12 us a launch, a StepStats a step ~0.5 us)."""
        if combine or len(status) == 1:
            return [cls._status_stats(summary, len(status), order, fallback)]
        return [cls._status_stats(row, 1, order, fallback) for row in status.tolist()]

    @staticmethod
    def _status_stats(row: list[float], steps: int, order: int, fallback: str) -> StepStats:
        """A StepStats of a status row (or of the summary row of `steps` steps)."""
        c = step_kernels
        return StepStats(
            int(row[c.STATUS_JOINT_ITERATIONS]), int(row[c.STATUS_VELOCITY_ITERATIONS]), row[c.STATUS_JOINT_ERROR],
            row[c.STATUS_VELOCITY_ERROR], True, int(row[c.STATUS_LINEAR_ITERATIONS]), steps, order, fallback,
        )  # fmt: skip

    def _advance_clock(self, steps: int) -> None:
        """The step count and time after `steps` more whole steps (the time from the count: no summed drift)."""
        self.step_count += steps
        self.time = self._clock_at(self.step_count)

    def _clock_at(self, count):
        """The time (s) at step `count` (a number or an array): count dt, from where the step size was last set."""
        time, start = self._clock
        return time + (count - start) * self.dt

    def _set_step_size(self, h: float) -> None:
        """Take steps of h from the current time on (the accuracy controller's hook, `accuracy.py`). The carried
        right-hand sides stay: those of the last step size start the first iteration nearer than nothing, and the
        iterations after it hold the tolerance whatever it started from (`carry`)."""
        if h not in self._carry_rows:
            self._carry_rows = {g * h: r for r, g in enumerate(self._fractions)}
        self.dt = h
        self._clock = (self.time, self.step_count)
        self._alike = (0, 0)

    def _run_fused(self, batch: int, hand_out: bool) -> np.ndarray:
        """Up to `batch` steps of dt by the fused kernel, from the spin of the last step: their status rows
        (`warpimpulse/split.py` runs them on several threads instead). `hand_out`: the last step's state is
        handed out, so its velocities are corrected (`defer_velocities`)."""
        graph = self._fused_launch(self.dt)
        if self._views is None:
            self._batch.assign(np.array([batch, int(hand_out)], dtype=np.int32))
            self._spin_in.fill_(self._spin)
            wp.capture_launch(graph)
            return self._status.numpy()
        status, batch_view, spin_view = self._views
        batch_view[0], batch_view[1], spin_view[0] = batch, int(hand_out), self._spin
        wp.capture_launch(graph)
        return status

    def _velocity_failed(self, error: float) -> None:
        """A velocity correction that left more than the tolerance, under the iteration-limit policy (the
        message says what it left: it is one solve, or the contacts' few rounds, not an iteration limit)."""
        if not math.isfinite(error):
            self._max_error("velocity")
        self._may_iterate(self.max_iterations, error, "velocity", error, True, stopped=True)

    # ---------------------------------------------------------------- the step
    def step(self, n: int = 1) -> StepStats:
        """Advance n steps of dt; each is taken as 2**k substeps when a body spins faster than
        max_rotation / dt. A (sub)step whose joint correction diverges or runs out of iterations is redone as
        two half steps, down to dt / 2**max_substep_depth, before the failure is reported. At order 4 or 6 a
        (sub)step is a whole composed step: the spin split and the halving apply to it, never to one of its
        stages.

        The fused schedule takes the n steps in one launch where nothing needs the host between them. The
        velocities are corrected at the last step, the others' left to the next step's joint correction
        (`defer_velocities`). For n > 1 the stats are combined: iterations and substeps summed, the largest
        joint error, the last velocity error.

        Batched worlds (`SceneBuilder.replicate`) step together, each converging on its own; a world whose
        step fails stops alone (`stopped`, by index) and the others go on (`worlds.py`); `world_stats` holds
        each world's figures of the step, and the StepStats returned the largest over the worlds."""
        if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            raise ValueError(f"n must be an integer >= 1, got {n!r}")
        if self.accuracy is not None:  # n intervals of dt, in steps the controller sizes
            return self.accuracy.step(n)
        stats = self._steps(n, combine=n > 1)
        stats = stats[0] if len(stats) == 1 else _combined(stats)
        stats.step_size = self.dt
        return stats

    def _steps(self, n: int, combine: bool = False) -> list[StepStats]:
        """n steps' stats, one a step; with `combine`, a run of fused steps may be one StepStats of them all
        (`_combined`'s figures, substeps the steps' count), for a caller that combines them anyway."""
        if self.batch is not None:
            return [self.batch.step() for _ in range(n)]
        if self.schedule != "fused":
            return [self._step_parallel(i == n - 1) for i in range(n)]
        out: list[StepStats] = []
        done = 0
        while done < n:
            if self._fallback:  # a step that records why it was not composed: the parallel schedule's bookkeeping
                out.append(self._step_parallel(done + 1 == n))
                done += 1
            else:
                done += self._fused_steps(n - done, combine, out)
        return out

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
        stats = _combined([self._advance(self.dt / 2**depth, depth, stages) for _ in range(2**depth)])
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

    def fall_back(self, reason: str) -> None:
        """Take the next step at order 2, recording `reason` in its StepStats. For whatever makes a step
        non-reversible (contacts, impacts, friction, a state edited within the step): a symmetric composition
        only raises the order of a symmetric step, and its backward substeps would run such an event
        backwards."""
        self._fallback = str(reason) or "unspecified"

    def _advance(self, h: float, depth: int, stages: tuple[float, ...]) -> StepStats:
        """One step of h composed of base steps of g h for g in `stages`; on a failed stage, the whole step is
        undone and redone as two halves."""
        final = depth >= self.max_substep_depth
        whole = len(stages) == 1
        wp.capture_launch(self._save_velocities if whole else self._save_start)
        parts = []
        for g in stages:
            part, ok = self._base_step(g * h, final)
            parts.append(part)
            if not ok:
                if whole:  # undo this attempt's impulses: the frames of t0 still hold
                    wp.copy(self.state.body_v, self._v0)
                    wp.copy(self.state.body_w, self._w0)
                else:  # back to the start of the composed step, its drives' integrals and its frames
                    self.state.copy_from(self._start)
                    wp.copy(self.drive_integral, self._integral0)
                    self._update_frames()
                halves = _combined([self._advance(0.5 * h, depth + 1, stages) for _ in range(2)])
                halves.joint_iterations += sum(p.joint_iterations for p in parts)  # the failed attempt's work
                halves.velocity_iterations += sum(p.velocity_iterations for p in parts)
                halves.linear_iterations += sum(p.linear_iterations for p in parts)
                return halves
        if self.carry:  # the step is kept: so are the c it measured
            for g, part in zip(stages, parts):
                if part.joint_iterations:
                    self._keep_carry(g * h)
        stats = _combined(parts)
        stats.substeps = 1
        return stats

    def _base_step(self, h: float, final: bool) -> tuple[StepStats, bool]:
        """The paper's step of h (h < 0 runs it backwards): its stats, and False when it failed and a smaller
        step may still succeed (not `final`; the state then holds this attempt's impulses)."""
        self._use_step_size(h)
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
        # One exact solve, except with the split systems (section 4.6), which iterate side by side.
        while vel_err > self.velocity_tolerance and vel_it < (self.max_iterations if self._split_systems else 1):
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
        `reach` substeps long."""
        turns = 0.0 if self.max_rotation is None else spin * abs(reach * self.dt) / self.max_rotation
        return 0 if turns <= 1.0 else min(math.ceil(math.log2(turns)), self.max_substep_depth)

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

    def contacts(self) -> Contacts:
        """The contacts of the last step at the current state (`contacts.Contacts`: bodies, points, normals,
        depths, normal and friction impulses), numpy; empty for a scene without colliders."""
        if self.contact_stage is None:
            e = np.zeros(0)
            return Contacts(e.astype(np.int32), e.astype(np.int32), np.zeros((0, 3)), np.zeros((0, 3)), e, e,
                            np.zeros((0, 3)))  # fmt: skip
        return self.contact_stage.contacts()

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
            self._check_finite(self.state, self.step_count)
            raise SimulationError(f"step {self.step_count + (what == 'joint')}: {what} errors are not finite")
        return err

    def _may_iterate(
        self, iterations: int, error: float, what: str, best: float, final: bool, stopped: bool = False
    ) -> bool:
        """Whether the correction may take another iteration. On its limit, or when it diverges (the error
        grew 1000-fold over the best this step): False, and on the `final` try raise or warn naming the
        worst joints. `stopped`: a correction that is not an iteration to a limit stopped over its tolerance
        (the velocity correction's solve), said as such."""
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
        if stopped:
            failure = f"left {error:.3g}, over its tolerance of {tolerance:g}"
        elif diverges:
            failure = (f"diverged after {iterations} iterations (error grew from {best:.3g} to {error:.3g}, with the "
                       f"step halved {self.max_substep_depth} times already; {hint})")  # fmt: skip
        msg = f"step {self.step_count + 1} (t = {self.time + self.dt:.6g} s): the {what} correction {failure}"
        if worst:
            msg += f"; worst joints: {worst}"
        if self.on_max_iterations == "raise":
            raise SimulationError(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=3)
        return False

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

    def simulate(self, duration: float, callback=None) -> list[StepStats]:
        """Run whole steps covering `duration` seconds; `callback(sim, stats)` after each."""
        steps = int(round(duration / self.dt))
        if callback is None and self.accuracy is None:
            return self._steps(steps) if steps else []
        stats = []
        for _ in range(steps):
            s = self.step()
            stats.append(s)
            if callback is not None:
                callback(self, s)
        return stats

    # ---------------------------------------------------------------- checkpoints
    def save_checkpoint(self, path) -> None:
        """Write the full state to an .npz file; `load_checkpoint` continues bit-identically.

        The file also holds the scene's fingerprint (`diagnose.fingerprint`), so that a checkpoint is never
        loaded into another scene of the same body count. Written as the output files are
        (`files.write_atomically`): a failed write raises WriteError and leaves the previous checkpoint."""
        data = {name: getattr(self.state, f"body_{name}").numpy() for name in STATE}
        data.update(time=self.time, step_count=self.step_count, user_force=self._user_force,
                    user_torque=self._user_torque, dt=self.dt, bodies=self.model.body_count,
                    stages=np.array(self.scheme.stages), fallback=self._fallback,
                    drive_target=self.drive_target.numpy(), drive_integral=self.drive_integral.numpy())  # fmt: skip
        data.update({f"scene_{key}": np.array(value) for key, value in self._fingerprint.items()})
        for key, arr in getattr(self.linear, "_warm", {}).items():
            data[f"warm_{key}"] = arr.numpy()
        if self.carry:  # the first iterations' carried right-hand sides, a row a step size
            carries = self._carries()
            data.update(carry_h=np.array(list(carries)), carry=np.stack([c.numpy() for c in carries.values()]))
        write_atomically(path, lambda tmp: np.savez(tmp, **data), ".npz")

    def load_checkpoint(self, path) -> None:
        """Continue from a checkpoint of this scene. Everything in the file is read and checked before any of
        it is assigned: a refused or unreadable checkpoint raises CheckpointError (a ValueError naming the
        file) and leaves the simulator as it was."""
        path = Path(path)
        data = self._read_checkpoint(path)
        for name in STATE:
            getattr(self.state, f"body_{name}").assign(data[name])
        self.time, self.step_count = float(data["time"]), int(data["step_count"])
        self._clock = (0.0, 0) if self.accuracy is None else (self.time, self.step_count)
        if self.accuracy is not None:
            self.accuracy.reset()
        self._user_force, self._user_torque = data["user_force"], data["user_torque"]
        self._fallback = str(data["fallback"]) if "fallback" in data else ""
        if "drive_target" in data:  # motors' targets and PID integrals
            self.drive_target.assign(data["drive_target"])
            self.drive_integral.assign(data["drive_integral"])
        warm = getattr(self.linear, "_warm", None)  # CG warm starts; another solver's are not used
        if warm is not None:
            warm.clear()
            for key in data:
                if key.startswith("warm_"):
                    warm[key[5:]] = wp.array(data[key], dtype=wp.vec3d, device=self.model.device)
        self._forget_carry()
        if self.carry and "carry" in data:
            for h, c in zip(data["carry_h"].tolist(), data["carry"]):
                self._carry_arrays(h)[0].assign(c)
        self._active_forces = None
        self._update_frames()
        self._check_finite(self.state, self.step_count)  # and the spin that sets the next step's substeps

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
            if str(data[f"scene_{key}"]) != digest:
                raise refuse(f"checkpoint of another scene: its {key} differ from this simulator's")
        if "stages" in data and (data["stages"].dtype.kind != "f" or data["stages"].ndim != 1):
            raise refuse("'stages' is not a list of numbers")
        stages = tuple(float(g) for g in data["stages"]) if "stages" in data else (1.0,)
        if stages != self.scheme.stages:
            raise refuse(
                f"checkpoint taken with the composition {stages} of the base step; this simulator composes "
                f"{self.scheme.stages} (order {self.order}): resuming would not continue the run"
            )
        for key, shape in shapes.items():
            if data[key].shape != shape:
                raise refuse(f"'{key}' has shape {data[key].shape}, expected {shape}")
            if not np.all(np.isfinite(data[key])):
                raise refuse(f"'{key}' contains NaN or Inf")
        if data["step_count"].dtype.kind == "f" or int(data["step_count"]) < 0 or float(data["time"]) < 0.0:
            raise refuse(f"step count {data['step_count']} at time {data['time']} is not a place in a run")
        if np.abs(np.linalg.norm(data["q"], axis=1) - 1.0).max(initial=0.0) > 1e-6:
            raise refuse("an orientation is not a unit quaternion")
        for key in data:
            if key.startswith("warm_") and (data[key].shape != (nc, 3) or not np.all(np.isfinite(data[key]))):
                raise refuse(f"'{key}' has shape {data[key].shape} or non-finite values; expected ({nc}, 3)")
        if "carry" in data:  # the carried right-hand sides (`carry`): a row of (nc, 3) for each step size
            sizes, carry = data.get("carry_h", np.zeros(0)), data["carry"]
            if sizes.ndim != 1 or carry.shape != (len(sizes), nc, 3) or not np.all(np.isfinite(carry)):
                raise refuse(f"'carry' has shape {carry.shape} or non-finite values; expected ({len(sizes)}, {nc}, 3)")
            if not (sizes.dtype.kind == "f" and np.all(np.isfinite(sizes)) and np.all(sizes != 0.0)):
                raise refuse("'carry_h' is not a list of step sizes")
        return data

    # ---------------------------------------------------------------- the state
    def reset(self) -> None:
        """Return to the built state at t = 0, as a new Simulator of the same model: the bodies' initial poses
        and velocities, no user loads (`set_external_forces`), no warm start, the motors' built targets and
        no PID integral."""
        self.state.copy_from(self.model.state())
        self.drive_target.assign(self.model.host.drive_target)
        self.drive_integral.zero_()
        self.time, self.step_count = 0.0, 0
        self._clock = (0.0, 0)
        if self.accuracy is not None:
            self.accuracy.reset()
        if self.batch is not None:
            self.batch.reset()
        n = self.model.body_count
        self._user_force, self._user_torque = np.zeros((n, 3)), np.zeros((n, 3))
        self._active_forces = None
        self._fallback = ""
        getattr(self.linear, "_warm", {}).clear()
        self._forget_carry()
        self._update_frames()
        self._check_finite(self.state, 0)

    def set_state(
        self,
        positions: np.ndarray | None = None,
        orientations: np.ndarray | None = None,
        linear_velocities: np.ndarray | None = None,
        angular_velocities: np.ndarray | None = None,
        world: int | None = None,
    ) -> None:
        """Overwrite part of the state; what is not given stays. The Jacobians and the factorization are
        recomputed at once, so the next step starts from the new state (writing `sim.state` arrays directly
        leaves them stale).

        Args:
            positions: (n, 3) centres of mass, world frame (m).
            orientations: (n, 4) quaternions (x, y, z, w), body to world; normalised (a zero one is refused).
            linear_velocities: (n, 3) centre-of-mass velocities, world frame (m/s).
            angular_velocities: (n, 3) angular velocities, world frame (rad/s).
            world: with batched worlds, the one world these are for; None gives every world's, each array with
                a leading world dimension (W, n, ...).

        All values are checked before any is written. The joints are not projected: a state that breaks them
        is corrected by the next steps' impulses.
        """
        new = {}
        given = {"positions": positions, "orientations": orientations, "linear_velocities": linear_velocities,
                 "angular_velocities": angular_velocities}  # fmt: skip
        for (what, values), field in zip(given.items(), ("body_x", "body_q", "body_v", "body_w")):
            if values is not None:
                new[field] = self._world_values(values, what, world, (4 if field == "body_q" else 3,))
        if "body_q" in new:
            rows, q = new["body_q"]
            norms = np.linalg.norm(q, axis=1)
            if np.any(norms < 1e-9):
                body = self.model.body_name[rows][int(np.argmin(norms))]
                raise ValueError(f"orientations: the quaternion of body {body!r} is zero")
            new["body_q"] = rows, q / norms[:, None]
        for field, (rows, values) in new.items():
            full = getattr(self.state, field).numpy().copy()
            full[rows] = values
            getattr(self.state, field).assign(full)
        self._forget_carry(world)
        if self.accuracy is not None:  # a check under way would compare with another trajectory
            self.accuracy.reset()
        self._update_frames()
        self._check_finite(self.state, self.step_count)

    # ---------------------------------------------------------------- numpy accessors
    # With batched worlds each takes `world=` for one world's (n, ...) rows and gives all of them as (W, n, ...)
    # without it.
    def positions(self, world: int | None = None) -> np.ndarray:
        """(n, 3) centres of mass, world frame (m)."""
        return self._per_world(self.state.body_x.numpy().copy(), world)

    def orientations(self, world: int | None = None) -> np.ndarray:
        """(n, 4) quaternions (x, y, z, w), body to world (USD's Gf.Quat constructors take w first)."""
        return self._per_world(self.state.body_q.numpy().copy(), world)

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
        self.pred.copy_from(self.state)
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
        x = self.state.body_x.numpy()
        gravity = np.atleast_1d(self._per_world_sum(-h.body_mass * (x @ h.gravity), None))
        springs = np.zeros(0)
        if len(h.spring_params):
            q = self.state.body_q.numpy()
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
