"""Simulator.step(): the impulse loop of the method paper (sections 4.2-4.5; docs/architecture.md, "One step").

    predict every body over h (RK4) -> joint errors d(t0+h) -> within tolerance? else solve
    K lambda = -d/h, apply the impulses at t0, and predict again -> the last prediction is the new state
    -> frames and K at t0+h, factored once -> velocity correction K lambda = -J v, exact in one solve.
The factorization made at t0+h serves the next step's joint correction, which happens at the same time.
"""

from __future__ import annotations

import math
import operator
import sys
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np
import warp as wp

from . import accuracy as accuracy_control
from . import capabilities, checks, composition, diagnose
from .contacts import BROAD_PHASES, CONTACT_SOLVERS, Contacts, ContactStage
from .files import write_atomically
from .kernels import constraints as constraint_kernels
from .kernels import limits as limit_kernels
from .kernels import loop as loop_kernels
from .kernels import step as step_kernels
from .launch import Packed, record
from .model import Model, State
from .options import StepOptions
from .options import resolve as resolve_options
from .parallel import ParallelSteps
from .readout import Readout
from .recording import Recording
from .solver import CGSolver, CholeskySolver, Frames, SingularSystemError, loop_tolerance_for
from .steps import ROWS_FALLBACK, SimulationError, StepStats, combined, diverging
from .transforms import quat_from_axis_angle, quat_mul
from .types import FORMULATIONS, NEWTON_BODIES, SCHEDULES, SOLVERS
from .verbosity import verbose as show_warp_messages
from .worlds import Batch, WorldStats

POLICIES = ("raise", "warn")
STATE = ("x", "q", "v", "w")  # the state arrays in a checkpoint (State.body_x, ...)


# A status row's figures in StepStats' order (`Simulator._status_stats`): one C call where indexing the row by
# each column's name takes five.
_STATUS_FIGURES = operator.itemgetter(
    step_kernels.STATUS_JOINT_ITERATIONS, step_kernels.STATUS_VELOCITY_ITERATIONS, step_kernels.STATUS_JOINT_ERROR,
    step_kernels.STATUS_VELOCITY_ERROR, step_kernels.STATUS_LINEAR_ITERATIONS,
)  # fmt: skip


class CheckpointError(ValueError):
    """A checkpoint that cannot be loaded into this simulator; the message names the file and the reason."""


class Simulator(Readout, Recording, ParallelSteps):
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
        contact_settings = dict(margin=contact_margin, solver=contact_solver, broad_phase=broad_phase,
                                sweeps=contact_sweeps)  # fmt: skip
        self._fingerprint = diagnose.fingerprint(model, contact_settings if model.colliders is not None else None)
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
        if self.redundant_rows:
            self._check_loops()
        self._check_finite(self.state, 0)
        self.accuracy = None if plan is None else accuracy_control.Controller(self, plan)
        """The step-size controller where `accuracy` was given (`accuracy.Controller`: its plan, horizon, step)."""

    # ---------------------------------------------------------------- options the scene decides
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
        values = self.drive_target.numpy()
        values[drive] = target
        self.drive_target.assign(values)

    def set_controls(self, values) -> None:
        """Set actuators' inputs as MuJoCo's `ctrl` does (`SceneBuilder.add_actuator`, `load_mjcf`): `values` is
        one number per actuator in order, or {name or index: value} for some of them (the others keep theirs).
        Each sets its motor's target to gain * clip(value, ctrl range) + bias, held until set again."""
        m = self.model
        names, h = m.actuator_name, m.host
        if isinstance(values, dict):
            items = list(values.items())
        else:
            arr = checks.numbers(values, "set_controls: values").reshape(-1)
            if len(arr) != len(names):
                raise ValueError(f"set_controls: {len(names)} actuators, got {len(arr)} values")
            items = list(enumerate(arr.tolist()))
        rows, controls = [], []
        for key, value in items:
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
        gain, bias, low, high = h.actuator_map[rows].T
        targets = self.drive_target.numpy()
        targets[h.actuator_drive[rows]] = gain * np.clip(controls, low, high) + bias
        self.drive_target.assign(targets)

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
        # CPU arrays' memory, read and written without a copy: the status rows, and as memoryviews (an element
        # read or written in half numpy's time) their summary row, the batch words and the spin
        status = None if cuda else self._status.numpy()
        self._views = None if cuda else (
            status, memoryview(status[-1]), memoryview(self._batch.numpy()), memoryview(self._spin_in.numpy())
        )  # fmt: skip
        # A step with rows is taken at order 2, as the parallel schedule takes it (ROWS_FALLBACK).
        self._fused_stages = (1.0,) if rows else self.scheme.stages
        fell_back = len(self._fused_stages) < len(self.scheme.stages)
        self._fused_order = (2, ROWS_FALLBACK) if fell_back else (self.order, "")  # the StepStats' order, fallback
        self._stages = wp.array(self._fused_stages, dtype=wp.float64, device=self.model.device)
        rows = [self._carry_rows[g * self.dt] for g in self._fused_stages]
        self._stage_carry = wp.array(rows, dtype=wp.int32, device=self.model.device)
        self._fused_by_h: dict[float, wp.Graph | Packed] = {}
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

    def _fused_launch(self, h: float) -> wp.Graph | Packed:
        """The fused kernel's launch for steps of h, recorded once per h: packed on a CPU (its arguments once, a
        call then costs ~0.3 us against a graph replay's ~1.7), captured as a graph on a GPU."""
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
            self._fused_by_h[h] = self._capture(launch) if self._views is None else Packed(launch)
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
        order, fallback = self._fused_order
        while done < n:
            self._update_forces()
            batch = self._steps_alike(min(n - done, self.FUSED_BATCH))
            status, summary = self._run_fused(batch, done + batch == n)  # the one read-back of the batch
            first = int(summary[columns.STATUS_CODE])  # the OK steps, which the kernel stops after
            if first:
                out += self._fused_stats(status, first, summary, order, fallback, combine)
            self._advance_clock(first)
            done += first
            if first < batch:
                out.append(self._handed_back(status[first], done + 1 == n))
                done += 1
            elif first:
                self._spin = summary[columns.STATUS_SPIN]
            if self.linear is not None:
                self.linear.check()  # and the redundant loop rows of the last factorization
        return done

    def _fused_step(self) -> StepStats:
        """One step (`step()`, the call a controller makes each tick): `_fused_steps`' work for n = 1 without its
        loop's bookkeeping (one launch of one step, whose state is handed out)."""
        self._update_forces()
        status, summary = self._run_fused(1, True)
        if summary[step_kernels.STATUS_CODE]:  # the step went OK
            order, fallback = self._fused_order
            stats = self._status_stats(summary, 1, order, fallback)
            self._advance_clock(1)
            self._spin = summary[step_kernels.STATUS_SPIN]
        else:
            stats = self._handed_back(status[0], True)
        if self.linear is not None:
            self.linear.check()  # and the redundant loop rows of the last factorization
        return stats

    def _handed_back(self, row: np.ndarray, hand_out: bool) -> StepStats:
        """The step whose status `row` stopped a fused launch: taken again by the parallel schedule where nothing
        of it was kept (SPLIT, RETRY), else (SINGULAR, VELOCITY) reported from the row. `hand_out`: its state is
        handed out (`defer_velocities`)."""
        columns = step_kernels
        code = int(row[columns.STATUS_CODE])
        self._spin = float(row[columns.STATUS_SPIN])
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
        """A StepStats of a status row (or of the summary row of `steps` steps)."""
        joint, velocity, joint_error, velocity_error, linear = _STATUS_FIGURES(row)
        return StepStats(
            int(joint), int(velocity), joint_error, velocity_error, True, int(linear), steps, order, fallback
        )

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

    def _run_fused(self, batch: int, hand_out: bool) -> tuple[np.ndarray, list[float]]:
        """Up to `batch` steps of dt by the fused kernel, from the spin of the last step: their status rows and
        the summary row's values (`warpimpulse/split.py` runs them on several threads instead). `hand_out`: the
        last step's state is handed out, so its velocities are corrected (`defer_velocities`)."""
        launch = self._fused_launch(self.dt)
        if self._views is None:
            self._batch.assign(np.array([batch, int(hand_out)], dtype=np.int32))
            self._spin_in.fill_(self._spin)
            wp.capture_launch(launch)
            status = self._status.numpy()
            return status, status[-1].tolist()
        status, summary, batch_view, spin_view = self._views
        batch_view[0], batch_view[1], spin_view[0] = batch, int(hand_out), self._spin
        launch.launch()
        return status, summary.tolist()

    def _velocity_failed(self, error: float, sweeps: int = 0) -> None:
        """A velocity correction that left more than the tolerance, under the iteration-limit policy (the
        message says what it left: it is one solve, or the contacts' few rounds, not an iteration limit; the
        iterative solver's `sweeps` are said)."""
        if not math.isfinite(error):
            self._max_error("velocity")
        self._may_iterate(self.max_iterations, error, "velocity", error, True, stopped=True, sweeps=sweeps)

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
        if self.accuracy is not None:  # n intervals of dt, in steps the controller sizes
            return self.accuracy.step(n)
        lean = n.__class__ is int and n == 1 and self.schedule == "fused" and not self._fallback  # a control tick
        if not lean and not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            raise ValueError(f"n must be an integer >= 1, got {n!r}")
        start = self.time
        try:
            stats = [self._fused_step()] if lean else self._steps(n, combine=n > 1)
        except SingularSystemError as err:  # a runaway load loses pivots too: name it rather than a joint
            note = self._runaway_note()
            if not note or not err.where:
                raise
            raise SingularSystemError(f"the system matrix is singular at {err.where}: {note}", err.where) from None
        for s in stats:
            if s.fallback and s.fallback not in self.fallbacks:
                self.fallbacks[s.fallback] = start
                if self.verbose:
                    print(f"warpimpulse: {self.fallback_note(s.fallback)}", file=sys.stderr)
        return stats[0] if len(stats) == 1 else combined(stats)

    def fallback_note(self, reason: str) -> str:
        """The sentence that says why steps were taken at order 2 (a `fallbacks` entry)."""
        return (f"order {self.order} was asked, but steps from t = {self.fallbacks[reason]:.6g} s on were taken at "
                f"order 2 because of {reason}")  # fmt: skip

    def _steps(self, n: int, combine: bool = False) -> list[StepStats]:
        """n steps' stats, one a step; with `combine`, a run of fused steps may be one StepStats of them all
        (`combined`'s figures, substeps the steps' count), for a caller that combines them anyway."""
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

    def _may_iterate(
        self, iterations: int, error: float, what: str, best: float, final: bool, stopped: bool = False,
        sweeps: int = 0,
    ) -> bool:  # fmt: skip
        """Whether the correction may take another iteration. On its limit, or when it diverges (the error
        grew 1000-fold over the best this step): False, and on the `final` try raise or warn naming the
        worst joints. `stopped`: a correction that is not an iteration to a limit stopped over its tolerance
        (the velocity correction's solve), said as such, with its `sweeps` where it took some."""
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
        msg = f"step {self.step_count + 1} (t = {self.time + self.dt:.6g} s): the {what} correction {failure}"
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
        m, st = self.model, self.state
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
            self.state.copy_from(m.state())
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
        self.fallbacks = {}
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
