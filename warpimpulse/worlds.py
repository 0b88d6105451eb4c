"""Batched worlds: the step of a Model of many independent copies (`SceneBuilder.replicate`), every launch
covering all of them, each world converging and failing on its own.

How one step goes (`Batch.step`):
- every world that has not stopped starts from its own spin, which sets its substeps (2**k, as for one world);
  the worlds of the most common k are stepped together, the rest alone;
- in the joint correction a world that holds its joints is masked (`kernels/worlds.mask_worlds`): its impulses
  are zero, so its prediction repeats bit for bit and it takes no more iterations while others go on;
- a world whose correction fails (iteration limit, divergence, NaN, a body turning too far, a velocity
  correction that stops short) drops out of the batch and is frozen at the start of the step;
- the drives' PID integrals advance with the accepted states of the batch; a world that leaves it gets back its
  integral of the start of the step;
- each world that was not finished in the batch takes the step alone, from its state (and drive integrals and
  targets) at the start, on a
  one-world Simulator of the same settings: the halving, splitting, raising and warning of one world, exactly.
  A world whose step fails there stops (frozen at its last good state, `Batch.stopped` gives the message by
  world index) and the others go on; only when every world has stopped does `step` raise.
So a batched run gives each world the trajectory that a Simulator of that world alone gives, bit for bit
(tests/test_worlds.py).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import warp as wp

from .kernels import carry as carry_kernels
from .kernels import loop as loop_kernels
from .kernels import step as step_kernels
from .model import State
from .solver import SingularSystemError
from .steps import SimulationError, StepStats


@dataclass
class WorldStats:
    """Per-world figures of the last step, each an array over worlds (a stopped world's stay at zero)."""

    joint_iterations: np.ndarray
    velocity_iterations: np.ndarray
    max_joint_error: np.ndarray
    max_velocity_error: np.ndarray
    converged: np.ndarray
    linear_iterations: np.ndarray
    substeps: np.ndarray
    alone: np.ndarray  # True where the world took the step alone (a hard step, a failure or a stop)

    @classmethod
    def zeros(cls, count: int) -> WorldStats:
        i, f = np.zeros(count, np.int64), np.zeros(count)
        return cls(i.copy(), i.copy(), f.copy(), f.copy(), np.ones(count, bool), i.copy(), i.copy(),
                   np.zeros(count, bool))  # fmt: skip

    def set(self, world: int, stats) -> None:
        """Put one world's StepStats (of a step taken alone)."""
        for name in ("joint_iterations", "velocity_iterations", "max_joint_error", "max_velocity_error",
                     "converged", "linear_iterations", "substeps"):  # fmt: skip
            getattr(self, name)[world] = getattr(stats, name)


class Batch:
    """The per-world side of a Simulator whose model has several worlds (`Simulator.batch`)."""

    def __init__(self, sim) -> None:
        m = sim.model
        self.sim = sim
        self.count = m.world_count
        self.bodies = m.world_body_count
        self.spin = np.zeros(self.count)  # rad/s: each world's largest |w| of its last prediction
        self.stopped: dict[int, str] = {}  # world -> why it stopped
        self.stats = WorldStats.zeros(self.count)
        self._t0: State = m.state()
        self._integral0 = np.zeros(m.drive_count)  # the drives' PID integrals at the start of the step
        self._drives = m.drive_count // self.count  # per world, world-major like the bodies
        self._solos: dict[int, object] = {}
        # The correction loop decided on the device, per world (`kernels/loop.py`): each world's record (the
        # columns of `loop_state`) and whether it is still in the batch; one graph a step size (`device_loop`).
        self.world_loop = wp.zeros((self.count, loop_kernels.LOOP_WIDTH), dtype=wp.float64, device=m.device)
        self.world_batch = wp.zeros(self.count, dtype=wp.int32, device=m.device)
        self._loops_by_h: dict[float, wp.Graph] = {}
        # The worlds that keep the c their step measured (`Simulator.carry`), and the launch that keeps it, a step size
        self.world_take = wp.zeros(self.count, dtype=wp.int32, device=m.device)
        self._commits: dict[float, wp.Launch] = {}

    # ---------------------------------------------------------------- per-world reductions
    def world_max(self) -> np.ndarray:
        """Each world's largest constraint error just measured (NaN where any is NaN)."""
        return self.sim.errors.numpy().reshape(self.count, -1).max(axis=1)

    def measure(self, state: State) -> np.ndarray:
        """Each world's (NaN/Inf bodies, largest |w|) of `state`; sets the spin."""
        self.sim.world_summary.zero_()
        self.sim._world_checks[id(state)].launch()
        return self._read_summary(np.ones(self.count, bool))

    def _read_summary(self, worlds: np.ndarray) -> np.ndarray:
        summary = self.sim.world_summary.numpy()
        self.spin[worlds] = summary[worlds, 1]
        return summary

    def _restore(self, target: State, worlds: np.ndarray) -> None:
        """Rows of `worlds` in `target` back to the start of the step."""
        n = self.bodies
        for w in np.flatnonzero(worlds).tolist():
            for name in ("body_x", "body_q", "body_v", "body_w"):
                wp.copy(getattr(target, name), getattr(self._t0, name), w * n, w * n, n)

    def _drive_rows(self, world: int) -> slice:
        return slice(world * self._drives, (world + 1) * self._drives)

    def _restore_integrals(self, worlds: np.ndarray) -> None:
        """The drives' integrals of `worlds` back to the start of the step (the batch integrated them)."""
        if self._drives:
            integral = self.sim.drive_integral.numpy()
            for w in np.flatnonzero(worlds).tolist():
                integral[self._drive_rows(w)] = self._integral0[self._drive_rows(w)]
            self.sim.drive_integral.assign(integral)

    def reset(self) -> None:
        self.stopped.clear()
        self.stats = WorldStats.zeros(self.count)

    def forget(self, worlds) -> None:
        """Drop the one-world simulators of `worlds` (their masses changed)."""
        for w in worlds:
            self._solos.pop(int(w), None)

    # ---------------------------------------------------------------- the step
    def step(self):
        """One step of dt for every world that has not stopped (see the module docstring); returns the
        StepStats over all worlds (the most iterations, the largest errors) and leaves per-world ones in
        `stats`."""
        self.step_batched()
        return self.finish()

    def step_batched(self) -> None:
        """The batched part of a step: every world that can, together. It captures nothing, so threads may run
        it for disjoint batches at once once their step sizes are recorded (`Simulator.prepare_substeps`)."""
        sim = self.sim
        sim._update_forces()
        self._t0.copy_from(sim.state)
        if self._drives:
            self._integral0 = sim.drive_integral.numpy().copy()
        self._spin0 = self.spin.copy()  # a world stepped alone starts from its spin of the start
        self._live = live = np.array([w not in self.stopped for w in range(self.count)])
        if not live.any():
            raise SimulationError(f"every one of the {self.count} worlds has stopped: {self.stopped[0]}")
        depths = np.array([sim._depth_of(s) for s in self.spin])
        depth = int(np.bincount(depths[live]).argmax())
        self._batch = batch = live & (depths == depth)
        self._stats = WorldStats.zeros(self.count)
        for _ in range(2**depth):
            self._advance(sim.dt / 2**depth, depth, batch, self._stats)
        sim._use_step_size(sim.dt)

    def finish(self):
        """The rest of the step: the worlds not finished in the batch, each alone (this may build a one-world
        simulator, so a thread must not run it while others step); then the time and the stats."""
        sim, batch, live, stats = self.sim, self._batch, self._live, self._stats
        alone = live & ~batch
        if (~batch).any():
            self._restore(sim.state, ~batch)  # frozen: the alone ones start there, the stopped ones stay
            self._restore_integrals(~batch)
            for w in np.flatnonzero(alone).tolist():
                self._step_alone(w, stats)
            sim._update_frames()
        stats.alone = alone
        stats.converged &= np.array([w not in self.stopped for w in range(self.count)])
        sim.step_count += 1
        sim.time = sim.step_count * sim.dt
        self.stats = stats
        return StepStats(
            int(stats.joint_iterations.max()), int(stats.velocity_iterations.max()),
            float(stats.max_joint_error.max()), float(stats.max_velocity_error.max()),
            bool(stats.converged[live].all()), int(stats.linear_iterations.max()), int(stats.substeps.max()),
        )  # fmt: skip

    def device_loop(self) -> wp.Graph:
        """The joint-correction loop of every world of the batch at the simulator's current step size, as one
        graph decided on the device (captured once per step size; `Simulator.prepare_substeps` captures them
        ahead for threads): predict and measure, then, while any world of the batch goes on, iterate the worlds
        that do (`world_active` masks the others' right-hand sides); a world that fails leaves the batch."""
        sim = self.sim
        if sim._h not in self._loops_by_h:
            first, first_iteration, iteration = sim._loop_work
            self._loops_by_h[sim._h] = sim._capture_loop(
                first, iteration, ((sim.errors, sim.model.constraint_world),), sim.tolerance, sim.max_iterations,
                first_iteration=first_iteration, loop_state_out=self.world_loop, loop_batch_out=self.world_batch,
                loop_active_out=sim.world_active,
            )  # fmt: skip
        return self._loops_by_h[sim._h]

    def _advance(self, h: float, depth: int, batch: np.ndarray, stats: WorldStats) -> None:
        """One substep of h for the worlds of `batch`; a world that fails leaves `batch` (frozen at the start
        of the step, to be stepped alone)."""
        sim = self.sim
        sim._use_step_size(h)
        final = depth >= sim.max_substep_depth
        self.world_batch.assign(batch.astype(np.int32))
        wp.capture_launch(self.device_loop())
        record = self.world_loop.numpy()
        err = record[:, loop_kernels.LOOP_LAST].copy()
        iterations = record[:, loop_kernels.LOOP_ITERATIONS].astype(np.int64)
        batch &= self.world_batch.numpy() != 0
        summary = self._read_summary(batch)  # of the last prediction of each world
        batch &= summary[:, 0] == 0
        if not final and sim.max_rotation is not None:
            batch &= ~(self.spin * h / sim.max_rotation > 1.0)  # turned too far: halve it, alone
        if (~batch).any():
            self._restore(sim.pred, ~batch)  # the accepted state of a frozen world is its start
        wp.capture_launch(sim._accept_graph)
        sim._integrate_drives.launch()  # every world's; `finish` puts back those of the worlds that leave
        sim.linear.check()
        sim._velocity_errors.launch()
        verr = self.world_max()
        fix = np.zeros(len(batch), dtype=np.int64)  # the solves of each world's velocity correction
        for _ in range(step_kernels.VELOCITY_SOLVES):  # one exact solve, one more on its round-off
            short = batch & ~(verr <= sim.velocity_tolerance)
            if not short.any():
                break
            sim.world_active.assign(short.astype(np.int32))
            wp.capture_launch(sim._velocity_fix)
            verr = self.world_max()
            fix += short
        batch &= verr <= sim.velocity_tolerance  # a correction stopped short: alone, where it is reported
        stats.joint_iterations[batch] += iterations[batch]
        stats.velocity_iterations[batch] += fix[batch]
        stats.max_joint_error[batch] = np.maximum(stats.max_joint_error[batch], err[batch])
        stats.max_velocity_error[batch] = verr[batch]
        solves = iterations + fix + sim._newton_solves(iterations)
        stats.linear_iterations[batch] += solves[batch]
        stats.substeps[batch] += 1
        if sim.carry:  # the worlds kept whose first solve ran keep the c it measured (`Simulator.carry`)
            if h not in self._commits:
                c, c_next, *past = sim._carry_arrays((h, 0))
                self._commits[h] = sim._record(carry_kernels.carry_commit, sim.model.constraint_count,
                                               world_take=self.world_take, carry_next=c_next, carry_out=c,
                                               **{f"past{k + 1}_out": p for k, p in enumerate(past)})  # fmt: skip
            self.world_take.assign((batch & (iterations > 0)).astype(np.int32))
            self._commits[h].launch()

    # ---------------------------------------------------------------- a world alone
    def _solo(self, world: int):
        """A one-world Simulator of this world (its current masses) with the batch's settings, made once."""
        if world not in self._solos:
            sim = self.sim
            self._solos[world] = type(sim)(
                sim.model.worlds(world, world + 1), sim.dt, tolerance=sim.tolerance,
                velocity_tolerance=sim.velocity_tolerance, solver=sim.solver_name, max_iterations=sim.max_iterations,
                on_max_iterations=sim.on_max_iterations, order=sim.order, options=sim.options.replace(
                    formulation=sim.linear.pattern.formulation if sim.linear is not None else "auto",
                    newton=sim.newton, carry=sim.carry, defer_velocities=sim.defer_velocities),
            )  # fmt: skip
        return self._solos[world]

    def _step_alone(self, world: int, stats: WorldStats) -> None:
        """Take this step for `world` on its own simulator, from its state at the start of the step; a
        failure stops the world (and warns), not the batch."""
        sim, n = self.sim, self.bodies
        solo = self._solo(world)
        for name in ("body_x", "body_q", "body_v", "body_w"):
            wp.copy(getattr(solo.state, name), getattr(self._t0, name), 0, world * n, n)
        rows = slice(world * n, (world + 1) * n)
        solo.set_external_forces(sim._user_force[rows], sim._user_torque[rows])
        drives = self._drive_rows(world)
        if self._drives:
            solo.drive_target.assign(sim.drive_target.numpy()[drives])
            solo._follow_elements()
            solo.drive_integral.assign(self._integral0[drives])
        solo.time, solo.step_count = sim.time, sim.step_count
        solo._update_frames()
        solo._spin = self._spin0[world]
        nc = sim.model.world_constraint_count
        for key, arrays in sim._carries().items():  # the world's c and past of every step size (`Simulator.carry`)
            for mine, theirs in zip(solo._carries_of(key), arrays):
                wp.copy(mine, theirs, 0, world * nc, nc)
        try:
            result = solo.step()
        except (SimulationError, SingularSystemError) as exc:
            self.stopped[world] = f"world {world}: {exc}"
            warnings.warn(f"{self.stopped[world]}; the world stops, the others go on", RuntimeWarning, stacklevel=4)
            stats.converged[world] = False
            return
        for name in ("body_x", "body_q", "body_v", "body_w"):
            wp.copy(getattr(sim.state, name), getattr(solo.state, name), world * n, 0, n)
        for key, arrays in solo._carries().items():
            for theirs, mine in zip(sim._carries_of(key), arrays):
                wp.copy(theirs, mine, world * nc, 0, nc)
        if self._drives:
            wp.copy(sim.drive_integral, solo.drive_integral, drives.start, 0, self._drives)
        self.spin[world] = solo._spin
        stats.set(world, result)
