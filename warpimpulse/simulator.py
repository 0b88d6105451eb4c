"""Simulator: the impulse loop of the method paper (sections 4.2-4.5; docs/architecture.md, "One step").

    predict every body over h (RK4) -> joint errors d(t0+h) -> within tolerance? else solve
    K lambda = -d/h, apply the impulses at t0, and predict again -> the last prediction is the new state
    -> frames and K at t0+h, factored once -> velocity correction K lambda = -J v, exact in one solve.
The factorization made at t0+h serves the next step's joint correction, which happens at the same time.

This module is the facade: the options a user decides and their checks, the scratch a step needs, the choice of
schedule, and `step()`. The rest of a Simulator lives beside it, a module each: the fused schedule (`fused.py`),
the parallel one (`parallel.py`), its recorded launches (`recording.py`), setters (`inputs.py`), read-outs
(`readout.py`), checkpoints (`checkpoint.py`) and how a failing step is said (`failures.py`).
"""

from __future__ import annotations

import math
import sys

import numpy as np
import warp as wp

from . import accuracy as accuracy_control
from . import capabilities, checks, composition, dampers, diagnose
from .checkpoint import CheckpointError, Checkpoints
from .contacts import BROAD_PHASES, CONTACT_SOLVERS, Contacts, ContactStage
from .failures import Failures
from .fused import FusedSteps
from .inputs import Inputs
from .kernels import carry as carry_kernels
from .kernels import constraints as constraint_kernels
from .kernels import forces as force_kernels
from .kernels import loop as loop_kernels
from .kernels import step as step_kernels
from .launch import Packed
from .model import Model, State
from .options import StepOptions
from .options import resolve as resolve_options
from .parallel import ParallelSteps
from .readout import Readout
from .recording import Recording
from .solver import CGSolver, CholeskySolver, Frames, SingularSystemError, loop_tolerance_for
from .steps import ROWS_FALLBACK, SimulationError, StepStats, combined
from .types import FORMULATIONS, NEWTON_BODIES, REFACTOR_EVERY, SCHEDULES, SOLVERS, STALE_FACTOR_RATE
from .verbosity import verbose as show_warp_messages
from .worlds import Batch

POLICIES = ("raise", "warn")

__all__ = ["ROWS_FALLBACK", "CheckpointError", "SimulationError", "Simulator", "StepStats"]  # with its errors


class Simulator(Readout, Recording, ParallelSteps, FusedSteps, Checkpoints, Inputs, Failures):
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
            off by default (`warpimpulse.verbosity`). It also says on stderr, once each, why steps were taken at
            a lower order than asked (`fallbacks`).
        order: 2, 4 or 6 in time. 2 is the paper's step; 4 and 6 compose it symmetrically, some substeps
            running backwards (`composition.py`). Spin splits and halving on failure apply to whole composed
            steps. Without `tolerance`, the tolerance follows the order (`composition.default_tolerance`:
            1e-6 at order 2, 10 dt^5 at 4 and 200 dt^7 at 6 in [1e-12, 1e-6]) so that it does not cap the order.
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
            carried right-hand side, deferred velocity correction, kept factor, split forces, kernel
            specialization, spin splits, halving depth and the contacts' broad phase and sweeps. Each chooses
            itself from the scene and the machine by default. `legacy`: the same switches as keywords, the old
            spelling, deprecated (a DeprecationWarning names the new one).
        """
        if not isinstance(model, Model):
            raise TypeError(f"model must be a Model (from SceneBuilder.finalize()), got {type(model).__name__}")
        self.options = options = resolve_options(options, legacy, type(self).__name__)
        schedule, formulation, scheme = options.schedule, options.formulation, options.scheme
        newton, carry, defer_velocities = options.newton, options.carry, options.defer_velocities
        reuse_factor = options.reuse_factor
        specialize, max_rotation, max_substep_depth = (
            options.specialize,
            options.max_rotation,
            options.max_substep_depth,
        )
        broad_phase, contact_sweeps = options.broad_phase, options.contact_sweeps
        plan = None
        if accuracy is not None:
            plan = accuracy_control.plan(model, accuracy, dt, tolerance, order, type(self))
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
        self.verbose = bool(verbose)
        self.fallbacks: dict[str, float] = {}
        """Why steps were taken at order 2 although `order` asked for more (`StepStats.fallback`), each reason once
        with the time (s) at the start of the `step` call that first took one, since the build (or `reset`)."""
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

        self._state = model.state()  # read as `state`, which hands it out
        self._handout = False  # the last step left its velocity correction to be taken (`state`)
        self.pred = model.state()
        self.control = model.control()
        self._user_force = np.zeros((model.body_count, 3))
        self._user_torque = np.zeros((model.body_count, 3))
        self._active_forces: tuple | None = None
        self._forces_timed = bool(len(model.host.force_until))  # model forces with an `until`: checked each step
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
        # The Newton step's scratch: the bodies' velocity changes from its impulses and their turns, its rhs.
        self.response_v = wp.zeros(model.body_count if self.newton else 0, dtype=wp.vec3d, device=d)
        self.response_w = wp.zeros_like(self.response_v)
        self.response_turn = wp.zeros_like(self.response_v)
        self.newton_rhs = wp.zeros(nc if self.newton else 0, dtype=wp.vec3d, device=d)
        # The first iteration's carried right-hand side (`carry`, kernels/carry.py): a row of c (and of the value
        # measured in the step, taken when it is kept) for each stage at dt (`composition.stage_keys`: stages of
        # one size keep one each), the other step sizes' on demand. Keys are (step size, stage of that size).
        self.carry = bool(carried if carry is None else carry)
        # (1.0, 0): a composed step's order-2 fallback
        self._fractions = tuple(dict.fromkeys((*composition.stage_keys(self.scheme.stages), (1.0, 0))))
        self._carry_rows = {(g * dt, k): r for r, (g, k) in enumerate(self._fractions)}
        rows = len(self._fractions) if self.carry else 0
        self._carry = wp.zeros((rows, nc), dtype=wp.vec3d, device=d)
        self._carry_next = wp.zeros_like(self._carry)
        # The values measured in the last kept steps of each size (rows PAST r ... PAST r + PAST - 1, the newest
        # first), NaN where unknown: c is extrapolated from them (kernels/carry.py).
        self._carry_past = wp.full(
            (carry_kernels.PAST * rows, nc), wp.vec3d(math.nan, math.nan, math.nan), dtype=wp.vec3d, device=d
        )
        self._carry_other: dict[tuple[float, int], tuple[wp.array, ...]] = {}  # halved and split step sizes
        self._substep_carry: dict[float, tuple[wp.array, ...]] = {}  # their rows, by substep size (`_substep_carries`)
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
        if model.element_count > 0:  # state-dependent forces: the coupled RK4 prediction's scratch
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
            # the force drives' coordinate rows' world axes and points at a stage state (`forces.coordinate_geometry`)
            self.coordinate_world_axis = wp.zeros(model.coordinate_count, dtype=wp.vec3d, device=d)
            self.coordinate_world_point = wp.zeros(model.coordinate_count, dtype=wp.vec3d, device=d)
        self.drive_target = wp.array(model.host.drive_target, dtype=wp.float64, device=d)
        self.drive_integral = wp.zeros(model.drive_count, dtype=wp.float64, device=d)
        # Whether a force element acts now: then the prediction is the coupled RK4 (`_follow_elements`). Whether
        # one can ever sleep is the model's; then the effort drives' targets decide, read through a view on a CPU.
        drives = model.drive_element.numpy() if model.element_count else np.zeros(0, dtype=np.int32)
        gained = model.world_count > 1 or model.spring_count > 0 or np.any(model.drive_gains.numpy()[drives] != 0.0)
        self._always_acting = bool(model.element_count and gained)
        self._effort_drives = None
        if model.element_count and not gained:
            self._effort_drives = drives[model.host.drive_mode[drives] == force_kernels.EFFORT_MODE]
        self._targets = self.drive_target.numpy() if d.is_cpu else None
        self._forced = self._elements_act()
        self._modes: dict[bool, dict] = {}  # the other prediction's kernels and launches, kept for a switch back
        # The drives' damping stiff for dt: implicit (`dampers.py`), unless order 4 or 6 is asked and kept: a
        # scene with rows takes its steps at order 2 whatever the order (ROWS_FALLBACK), so its dampers too
        self._dampers = dampers.pick(model, dt, keep_order=self.order > 2 and model.limit_count == 0)
        self.implicit_dampers: tuple[str, ...] = self._dampers.names
        """The drives (by name) whose damping the prediction takes implicitly: stiff for dt (`dampers.py`)."""
        if (self.implicit_dampers or self._dampers.kept) and verbose:
            print(f"warpimpulse: {self.damper_note()}", file=sys.stderr)
        self.split_forces = self._pick_split_forces(options.split_forces)
        self._kicked = self.split_forces and self._forced  # the elements act as kicks about each base step
        self._forced = self._forced and not self._kicked  # the coupled RK4 prediction
        nl = model.limit_count
        self.limit_impulse = wp.zeros(nl, dtype=wp.float64, device=d)  # accumulated over the step, push only
        (self.limit_value, self.limit_rate, self.limit_error, self.limit_velocity_impulse, self.limit_rhs,
         self.limit_delta, self.limit_low, self.limit_high, self.limit_goal, self.limit_before,
         self.limit_scratch) = (wp.zeros(nl, dtype=wp.float64, device=d) for _ in range(11))  # fmt: skip
        self.limit_mask = wp.zeros(nl, dtype=wp.int32, device=d)
        self.limit_formed = wp.zeros(nl, dtype=wp.int32, device=d)  # the fused step's rows of S formed
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
        # Unless refused, on while no force element acts (`_follow_elements`)
        self._defer_idle = bool(defer_velocities is None and not self._velocities_needed(idle=True))
        self._defer_asked = bool(defer_velocities is not False and not why)
        self.defer_velocities = self._defer_asked or (self._defer_idle and not self._forced)
        self._launches_by_h: dict[float, tuple] = {}
        self._loops_by_h: dict[tuple[float, int], tuple] = {}  # the parallel schedule's loops (`_device_loops`)
        self._v0 = wp.zeros_like(self._state.body_v)
        self._w0 = wp.zeros_like(self._state.body_w)
        self.summary = wp.zeros(2, dtype=wp.float64, device=d)  # NaN/Inf bodies, largest |w|
        # The joint-correction loop's record and its go-on flag, decided on the device (`kernels/loop.py`).
        self.loop_state = wp.zeros((1, loop_kernels.LOOP_WIDTH), dtype=wp.float64, device=d)
        self.loop_batch = wp.ones(1, dtype=wp.int32, device=d)  # the one world stays in its "batch"
        self.loop_active = wp.zeros(1, dtype=wp.int32, device=d)
        self.loop_go = wp.zeros(1, dtype=wp.int32, device=d)
        self._limit_world = wp.zeros(model.limit_count, dtype=wp.int32, device=d)  # one world's limits
        contact_settings = dict(margin=contact_margin, solver=contact_solver, broad_phase=broad_phase,
                                sweeps=contact_sweeps)  # fmt: skip
        self._fingerprint = diagnose.fingerprint(model, contact_settings if model.colliders is not None else None)
        self._spin = 0.0  # rad/s: the largest |w| of the last prediction checked (the state before its velocity fix)
        self._record_launches()
        self._start = model.state()  # the state at the start of a composed step, restored if a stage fails
        self._integral0 = wp.zeros_like(self.drive_integral)  # the drives' integrals there (stages integrate them)
        self._save_start = self._capture(
            lambda: self._start.copy_from(self._state), lambda: wp.copy(self._integral0, self.drive_integral)
        )
        self._fallback = ""  # why the next step must be taken at order 2 (`fall_back`)
        self.contact_stage = None
        self._penetration, self._contact_sweeps = 0.0, 0  # of the (sub)step's position phase
        if model.colliders is not None:
            self.contact_stage = ContactStage(
                model, self.frames, self.control, self._state, self.pred, self.tolerance, self.velocity_tolerance,
                contact_margin, contact_solver, broad_phase, contact_sweeps, self if self._direct else None,
            )  # fmt: skip
        self.schedule, self.schedule_note = self._pick_schedule(schedule, specialize)
        self.reuse_factor = self._pick_reuse_factor(reuse_factor)
        # The fused kernel's record of its factor (`kernels/step.py` FACTOR_*): its age, the factorizations, the
        # hold and its next length, each stage's solves with K of its start
        stages = len(getattr(self, "_fused_stages", ()))
        self._factor_state = wp.array([0] * step_kernels.FACTOR_FRESH_SOLVES + [-1] * stages, dtype=wp.int32, device=d)
        self._refactor_every = REFACTOR_EVERY if self.reuse_factor else 1
        self._stale_factor_rate = STALE_FACTOR_RATE
        self._update_frames()
        if self.redundant_rows:
            self._check_loops()
        self._check_finite(self._state, 0)
        # `step()` is one packed fused launch (`_fused_step`; a GPU's graph replays go through `_steps`)
        self._ticks = self.schedule == "fused" and plan is None and self._views is not None and not self._damper_depth()
        self._loop_rows_counted = self.linear is not None and "loops" in self.features  # `redundant_rows`
        self._read = False  # the velocities were read since the last call (`_lazy_call`)
        self.accuracy = None if plan is None else accuracy_control.Controller(self, plan)
        """The step-size controller where `accuracy` was given (`accuracy.Controller`: its plan, horizon, step)."""

    @property
    def state(self) -> State:
        """The bodies' state at `time` (positions, orientations, velocities; world frame), handed out: read it
        again after each step. With `defer_velocities` a step leaves its velocity correction (the paper's section
        4.2) to the next step's joint correction, which reaches the same velocities, or to this property, which
        takes it first (`_hand_out`: one solve with the factor the step left). A loop of `step()` then costs what
        `step(n)` costs a step and takes its steps bit for bit, and a recorder that reads positions only
        (`positions`, `orientations`) never waits for velocities it does not read. A read of the velocities
        between steps thus moves the next step's start by the correction, within the tolerance, as handing the
        state out at every call did. A velocity correction that leaves more than the tolerance is reported here,
        under the iteration-limit policy, as the step would have reported it."""
        self._read = True
        if self._handout:
            self._hand_out()
        return self._state

    def _lazy_call(self) -> bool:
        """Whether this call's steps all leave their velocity correction to `state` (with `defer_velocities`), or
        its last step takes it itself: for a reader, who read the velocities after the last call, and whose next
        read is then free (one launch, not two: a controller that reads the state every tick pays what handing
        out every step cost). The state the steps reach is the same either way: the correction is the same solve
        on the same state and factor."""
        lazy = self.defer_velocities and not self._read
        self._read = False
        return lazy

    def _hand_out(self) -> None:
        """The velocity correction the last step left (`state`), with the factor of the state's K: on the fused
        schedule one launch of its kernel that takes no step, on the parallel one its velocity pass. One that
        leaves more than the tolerance is reported as the step's would have been."""
        self._handout = False
        if self.schedule == "fused":
            row = self._run_fused(0, True)[0][0]
            error = float(row[step_kernels.STATUS_FAILED_VELOCITY])
            failed = row[step_kernels.STATUS_CODE] == step_kernels.VELOCITY
        else:
            error = self._correct_velocities()[1]
            failed = not error <= self.velocity_tolerance
        if failed:
            self._velocity_failed(error, counted=True)

    # ---------------------------------------------------------------- options the scene decides
    @property
    def _split_systems(self) -> bool:
        """Whether the Cholesky solver factors the tree's and the loop joints' systems apart (formulation "split",
        section 4.6), which iterate their velocity correction side by side."""
        return getattr(getattr(self.linear, "pattern", None), "formulation", "") == "split"

    def _pick_reuse_factor(self, wanted: bool | None) -> bool:
        """Whether the fused kernel keeps K's factor while it serves (`StepOptions.reuse_factor`; None: at order 4
        and 6)."""
        if wanted not in (None, True, False):
            raise ValueError(f"reuse_factor must be True, False or None (on where it pays), got {wanted!r}")
        m = self.model
        reasons = (
            (self.solver_name != "cholesky" or self.linear is None, f"the {self.solver_name!r} solver"),
            (self.schedule != "fused", "the parallel schedule (it factors at every step)"),
            (self._split_systems, "the split formulation"),
            (m.limit_count > 0, "joint limits, stiff motors or distance rows (their system S is formed with K^-1)"),
            (bool(m.topology.loop_joints), "loops (the factorization decides their redundant rows)"),
        )  # fmt: skip
        why = ", ".join(why for needed, why in reasons if needed)
        if wanted and why:
            raise ValueError(f"reuse_factor needs the fused Cholesky step without rows or loops; this simulator has "
                             f"{why}")  # fmt: skip
        # None: at order 4 and 6, whose stages go back and forth about the step and so move the arms of K less
        # than a step of order 2 does (benchmarks/reuse_factor.py: at order 2 and h = 1/120, 1.00-1.05 of the time).
        return bool((wanted or (wanted is None and self.order > 2)) and not why)

    def _pick_split_forces(self, wanted: bool | None) -> bool:
        """Whether the force elements act as two half kicks about each base step (`StepOptions.split_forces`;
        None: wherever they may)."""
        if wanted not in (None, True, False):
            raise ValueError(f"split_forces must be True, False or None (where the forces allow it), got {wanted!r}")
        m = self.model
        reasons = (
            (m.element_count == 0, "no force elements"),
            (m.world_count > 1, "batched worlds"),
            (bool(self._dampers.kept), "springs or dampers stiff for dt kept in RK4 at this order"),
        )  # fmt: skip
        why = ", ".join(why for needed, why in reasons if needed) or self._velocity_forces()
        if wanted and why:
            raise ValueError(f"split_forces needs force elements that depend on the poses alone; this simulator has "
                             f"{why}")  # fmt: skip
        return bool(wanted is not False and not why)

    def _velocity_forces(self) -> str:
        """The first force element whose force depends on the velocities or a history (a damper, a velocity
        drive, a PID's integral), which a kick cannot take, named; "" where there is none."""
        m = self.model
        damped = np.flatnonzero(m.spring_params.numpy()[:, 1] != 0.0) if m.spring_count else ()
        if len(damped):
            return f"a damped spring ({m.spring_name[damped[0]]!r})"
        drives = m.drive_element.numpy()
        modes = m.host.drive_mode[drives]
        gains = self._dampers.drive_gains.numpy()[drives]  # the implicit dampers' terms zeroed: they act apart
        terms = np.where(modes[:, None] == force_kernels.VELOCITY_MODE, gains, gains * [0.0, 1.0, 1.0])  # kp of a
        moving = np.flatnonzero((modes != force_kernels.EFFORT_MODE) & np.any(terms != 0.0, axis=1))  # rate; ki, kd
        if len(moving):
            return f"a drive with a velocity, damping or integral term ({m.drive_name[drives[moving[0]]]!r})"
        return ""

    @property
    def factorizations(self) -> int:
        """K's factorizations by the fused kernel since construction (`reuse_factor` skips some; the host's own,
        after `set_state`, `reset` or a step the parallel schedule took, are not counted)."""
        return int(self._factor_state.numpy()[step_kernels.FACTOR_COUNT])

    def _velocities_needed(self, idle: bool = False) -> str:
        """Why a step's velocities must be corrected before the next step (`defer_velocities`), or ""; `idle`:
        while no force element acts (`_follow_elements`)."""
        m = self.model
        reasons = (
            (self.solver_name != "cholesky" or m.constraint_count == 0, f"the {self.solver_name!r} solver"),
            (self._split_systems, "the split formulation"),
            (m.element_count > 0 and not (idle or self.split_forces), "force elements that read the velocities"),
            (m.limit_count > 0, "joint limits, stiff motors or distance constraints"),
            (m.colliders is not None, "contacts"),
            (m.world_count > 1, "batched worlds"),
        )
        return ", ".join(why for needed, why in reasons if needed)

    def _elements_act(self) -> bool:
        """Whether a force element can push now: a spring, a drive with a gain, or an effort drive whose target
        is not 0. A robot's effort motors at control 0 (an MJCF's actuators, `set_controls`) push nothing, and
        while that holds the step is the one of a scene without them (`_follow_elements`). Batched worlds keep
        the coupled prediction whenever the model has elements."""
        if self._effort_drives is None:
            return self._always_acting
        return bool(np.any(self._target_values()[self._effort_drives] != 0.0))

    # What the step keeps for each answer of `_elements_act`: its fused kernel and force elements, and the
    # launches either schedule recorded for them.
    _BY_ELEMENTS = ("_fused", "_elements", "_fused_by_h", "_tick", "_substep_by_h", "_launches_by_h", "_loops_by_h")

    def _follow_elements(self) -> None:
        """While a force element acts, its kicks about each base step (`split_forces`) or the coupled RK4
        prediction; else each body's own (`predict`), with no kick; the velocity correction deferred where it may be
        (`defer_velocities`: not with the coupled prediction, whose elements read the velocities). Called wherever
        the drives' targets change (the setters, `reset`, a checkpoint). Dormant elements cost the coupled
        prediction a stage and the velocity correction a step for nothing: 2x on gymnasium's ant at order 4
        (benchmarks/skips.py). A velocity correction a dormant step deferred is taken first where the coupled
        prediction follows; each answer's kernels and launches are kept for the next switch."""
        acting = self._elements_act()
        if acting == (self._forced or self._kicked):
            return
        if self._handout and not self.split_forces:  # a deferred velocity correction, before a step that needs
            self._hand_out()  # it done (kicks read no velocity)
        self._modes[not acting] = {name: getattr(self, name) for name in self._BY_ELEMENTS if hasattr(self, name)}
        self._forced = acting and not self.split_forces
        self._kicked = acting and self.split_forces
        self.defer_velocities = self._defer_asked or (self._defer_idle and not self._forced)
        kept = self._modes.get(acting)
        if kept is not None:
            for name, value in kept.items():
                setattr(self, name, value)
        else:
            self._launches_by_h, self._loops_by_h = {}, {}
            if self.schedule == "fused":
                self._take_fused_kernels()
                self._fused_by_h, self._tick, self._substep_by_h = {}, (None, ()), {}
        self._use_step_size(self.dt)

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
        kinds = frozenset(self.model.kinds) if specialize else constraint_kernels.ALL_KINDS
        self._fused_kinds = frozenset(int(k) for k in kinds)
        self._take_fused_kernels()
        # A row a step, and the launch's OK steps summed up in the last (`kernels/step.py` `finish`).
        self._status = wp.zeros(
            (self.FUSED_BATCH + 1, step_kernels.STATUS_WIDTH), dtype=wp.float64, device=self.model.device
        )
        # The batch size, whether its last step's state is handed out (`defer_velocities`) and the starting spin
        # of a launch, written by the host before each replay.
        self._batch = wp.zeros(2, dtype=wp.int32, device=self.model.device)
        self._spin_in = wp.zeros(1, dtype=wp.float64, device=self.model.device)
        # CPU arrays' memory, read and written without a copy: the status rows, and as memoryviews (an element
        # read or written in half numpy's time) their summary row, the batch words and the spin
        status = None if cuda else self._status.numpy()
        self._views = None if cuda else (
            status, memoryview(status[-1]), memoryview(self._batch.numpy()), memoryview(self._spin_in.numpy())
        )  # fmt: skip
        # A step with rows is taken at order 2, as the parallel schedule takes it (ROWS_FALLBACK).
        self._fused_stages = (1.0,) if self.model.limit_count else self.scheme.stages
        fell_back = len(self._fused_stages) < len(self.scheme.stages)
        self._fused_order = (2, ROWS_FALLBACK) if fell_back else (self.order, "")  # the StepStats' order, fallback
        self._stages = wp.array(self._fused_stages, dtype=wp.float64, device=self.model.device)
        rows = [self._carry_rows[(g * self.dt, k)] for g, k in composition.stage_keys(self._fused_stages)]
        self._stage_carry = wp.array(rows, dtype=wp.int32, device=self.model.device)
        self._fused_by_h: dict[float, wp.Graph | Packed] = {}
        # `step()`'s launches (`_tick_launches`): their batch words, one step handed out or not, and (dt, launches)
        self._tick_words = tuple(wp.array([1, out], dtype=wp.int32, device=self.model.device) for out in (1, 0))
        self._tick = (None, ())
        self._substep_by_h: dict[float, Packed] = {}  # the launches of split steps' substeps (`_split_step`)
        self._alike = (0, 0)  # (step, count): the steps from `step` on that share its forces
        return "fused", ""

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
        if (h, 0) not in self._carry_rows:
            self._carry_rows = {(g * h, k): r for r, (g, k) in enumerate(self._fractions)}
        self.dt = h
        self._clock = (self.time, self.step_count)
        self._alike = (0, 0)

    def _velocity_failed(self, error: float, sweeps: int = 0, counted: bool = False) -> None:
        """A velocity correction that left more than the tolerance, under the iteration-limit policy (the
        message says what it left: it is one solve and one on its round-off, or the contacts' few rounds, not an
        iteration limit; the iterative solver's `sweeps` are said). `counted`: its step is on the clock already
        (`_may_iterate`)."""
        if not math.isfinite(error):
            self._max_error("velocity")
        self._may_iterate(
            self.max_iterations, error, "velocity", error, True, stopped=True, sweeps=sweeps, counted=counted
        )

    # ---------------------------------------------------------------- the step
    def step(self, n: int = 1) -> StepStats:
        """Advance n steps of dt; each is taken as 2**k substeps when a body spins faster than
        max_rotation / dt. A (sub)step whose joint correction diverges or runs out of iterations is redone as
        two half steps, down to dt / 2**max_substep_depth, before the failure is reported. At order 4 or 6 a
        (sub)step is a whole composed step: the spin split and the halving apply to it, never to one of its
        stages.

        The fused schedule takes the n steps in one launch where nothing needs the host between them. With
        `defer_velocities` a step's velocity correction is left to the next step's joint correction, or to the
        first read of the velocities (`state`). For n > 1 the stats are combined: iterations and substeps summed,
        the largest joint error, the last velocity error.

        Batched worlds (`SceneBuilder.replicate`) step together, each converging on its own; a world whose
        step fails stops alone (`stopped`, by index) and the others go on (`worlds.py`); `world_stats` holds
        each world's figures of the step, and the StepStats returned the largest over the worlds."""
        lean = n.__class__ is int and n == 1 and self._ticks and not self._fallback  # a control tick
        if not lean:
            if self.accuracy is not None:  # n intervals of dt, in steps the controller sizes
                return self.accuracy.step(n)
            if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
                raise ValueError(f"n must be an integer >= 1, got {n!r}")
        try:
            if lean:
                return self._fused_step()  # its fallbacks noted there
            start = self.time
            steps = self._steps(n, combine=n > 1)
        except SingularSystemError as err:  # a runaway load loses pivots too: name it rather than a joint
            note = self._runaway_note()
            if not note or not err.where:
                raise
            raise SingularSystemError(f"the system matrix is singular at {err.where}: {note}", err.where) from None
        self._note_fallbacks(steps, start)
        return steps[0] if len(steps) == 1 else combined(steps)

    def _note_fallbacks(self, stats: list[StepStats], start: float) -> None:
        """Record (and under `verbose` print) the first time, `start` (s), each reason to fall back to order 2
        was met (`fallbacks`)."""
        for s in stats:
            if s.fallback and s.fallback not in self.fallbacks:
                self.fallbacks[s.fallback] = start
                if self.verbose:
                    print(f"warpimpulse: {self.fallback_note(s.fallback)}", file=sys.stderr)

    def damper_note(self) -> str:
        """The line that names the dampers stiff for dt: taken implicitly (`implicit_dampers`), or at order 4 or
        6 kept in RK4; empty where none is."""
        stiff = self.implicit_dampers or self._dampers.kept
        if not stiff:
            return ""
        names = ", ".join(stiff[:6]) + (f" and {len(stiff) - 6} more" if len(stiff) > 6 else "")
        if self.implicit_dampers:
            return (f"{len(stiff)} damper(s) stiff at dt = {self.dt:.3g} s taken implicitly (first order in the "
                    f"damping): {names}")  # fmt: skip
        split = 2 ** self._damper_depth()
        return (f"{len(stiff)} damper(s) stiff at dt = {self.dt:.3g} s kept in RK4 to keep order {self.order} (each "
                f"step split in {split}; order 2 takes them implicitly, faster): {names}")  # fmt: skip

    def fallback_note(self, reason: str) -> str:
        """The sentence that says why steps were taken at order 2 (a `fallbacks` entry)."""
        return (f"order {self.order} was asked, but steps from t = {self.fallbacks[reason]:.6g} s on were taken at "
                f"order 2 because of {reason}")  # fmt: skip

    def _steps(self, n: int, combine: bool = False) -> list[StepStats]:
        """n steps' stats, one a step; with `combine`, a run of fused steps may be one StepStats of them all
        (`combined`'s figures, substeps the steps' count), for a caller that combines them anyway."""
        if self.batch is not None:
            return [self.batch.step() for _ in range(n)]
        lazy = self._lazy_call()
        if self.schedule != "fused":
            out = [self._step_parallel(not lazy and i == n - 1) for i in range(n)]
            self._handout = lazy
            return out
        out: list[StepStats] = []
        done = 0
        while done < n:
            if self._fallback:  # a step that records why it was not composed: the parallel schedule's bookkeeping
                out.append(self._step_parallel(not lazy and done + 1 == n))
                self._handout = lazy
                done += 1
            elif self._damper_depth():  # split up front for dampers kept in RK4, as a spin split
                hand_out = not lazy and done + 1 == n
                out.append(self._split_step(None, hand_out) if self._splits_fused() else self._step_parallel(hand_out))
                self._handout = self.defer_velocities and not hand_out
                done += 1
            else:
                done += self._fused_steps(n - done, combine, out, lazy)
        return out

    def fall_back(self, reason: str) -> None:
        """Take the next step at order 2, recording `reason` in its StepStats. For whatever makes a step
        non-reversible (contacts, impacts, friction, a state edited within the step): a symmetric composition
        only raises the order of a symmetric step, and its backward substeps would run such an event
        backwards."""
        self._fallback = str(reason) or "unspecified"

    def contacts(self) -> Contacts:
        """The contacts of the last step at the current state (`contacts.Contacts`: bodies, points, normals,
        depths, normal and friction impulses), numpy; empty for a scene without colliders."""
        if self.contact_stage is None:
            e = np.zeros(0)
            return Contacts(e.astype(np.int32), e.astype(np.int32), np.zeros((0, 3)), np.zeros((0, 3)), e, e,
                            np.zeros((0, 3)))  # fmt: skip
        return self.contact_stage.contacts()

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

    # ---------------------------------------------------------------- the state
    def reset(self) -> None:
        """Return to the built state at t = 0, as a new Simulator of the same model: the bodies' initial poses
        and velocities, no user loads (`set_external_forces`), no warm start, the motors' built targets and
        no PID integral."""
        self._state.copy_from(self.model.state())
        self._handout = False
        self.drive_target.assign(self.model.host.drive_target)
        self.drive_integral.zero_()
        self._follow_elements()
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
        self.fallbacks = {}
        getattr(self.linear, "_warm", {}).clear()
        self._forget_carry()
        self._update_frames()
        self._check_finite(self._state, 0)

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
        state = self.state  # handed out: the velocities not given stay as they are read
        for field, (rows, values) in new.items():
            full = getattr(state, field).numpy().copy()
            full[rows] = values
            getattr(state, field).assign(full)
        self._forget_carry(world)
        if self.accuracy is not None:  # a check under way would compare with another trajectory
            self.accuracy.reset()
        self._update_frames()
        self._check_finite(self._state, self.step_count)
