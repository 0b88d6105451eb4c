"""Batched worlds on every core: the worlds split into shares, one per thread, each share a Simulator of its
own (`Model.worlds`), stepped at once by the calling thread and a pool's (`pool.run_shared`). One world alone
is one tree cut at its root instead, a part of it per thread (`split.SplitSimulator`).

A Warp CPU launch runs on one thread but releases the GIL, so Python threads launching on disjoint arrays use
separate cores (docs/architecture.md, "Warp on a CPU"). Graph capture on a CPU is one record for the whole
process, though: a launch from any thread while another captures would be recorded instead of run. So the
threads run only what captures nothing: every substep size is recorded before they start
(`Simulator.prepare_substeps`), and the rare worlds that must take a step alone (`worlds.Batch.finish`, which
may build a one-world simulator) finish on the calling thread after the others.

Where a world alone runs on the fused schedule (`Simulator._pick_schedule`), each world is a share of its own, a
one-world Simulator, and `step(n)` takes its n steps in fused launches of up to 256 steps: a thread then spends
its time inside long launches that release the GIL, where a batched share (the parallel schedule: many short
launches and host decisions a step) holds the GIL between them and its threads wait on one another. Single
threaded, the fused one-world steps cost no more per world-step than a batch does (benchmarks/worlds.py). Where
the fused schedule is not available the shares are batched Simulators, one per thread.

A world's run does not depend on its share: every world gives, bit for bit, the run of that world alone.
"""

from __future__ import annotations

import functools
import os
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import warp as wp

from .launch import capture
from .model import Model
from .options import take as take_options
from .pool import run_shared
from .simulator import SimulationError, Simulator, StepStats
from .solver import SingularSystemError
from .split import SplitSimulator
from .steps import combined
from .worlds import WorldStats


class ThreadedSimulator:
    """Steps the worlds of a batched Model (`SceneBuilder.replicate`) on `threads` threads (default: one per
    core, at most one per world). Accessors, setters and stats are those of a batched Simulator: per world with
    `world=`, or with a leading world dimension. A Model of one world is stepped by a `SplitSimulator`: its
    tree cut at the root, a part per thread (`split_note` says why where it runs on one thread); its step fails
    as a Simulator's does. `fused_shares` says whether each world is a one-world fused share (see the module
    docstring) or the worlds are batched shares, one per thread."""

    def __init__(self, model: Model, dt: float, threads: int | None = None, **settings) -> None:
        """Args: model, dt and `settings` as for `Simulator`; threads: how many (>= 1)."""
        threads = os.cpu_count() or 1 if threads is None else threads
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError(f"threads must be an integer >= 1, got {threads!r}")
        self.model = model
        self.split_note = ""
        self.fused_shares = False
        if model.world_count == 1:
            split = SplitSimulator(model, dt, threads=threads, **settings)
            self.threads, self.split_note, self.parts = split.threads, split.split_note, [split]
            self.starts = np.zeros(1, dtype=int)
        else:
            if settings.get("accuracy") is not None:
                raise ValueError(f"accuracy: batched worlds ({model.world_count}) step together at one dt; give dt")
            self.threads = min(threads, model.world_count)
            # One-world shares correct every step's velocities, as batched worlds do (`Simulator.defer_velocities`),
            # so that however the worlds are shared the run is the batched run.
            options = take_options(settings, "ThreadedSimulator")
            if options.defer_velocities is None:
                options = options.replace(defer_velocities=False)
            settings["options"] = options
            first = Simulator(model.worlds(0, 1), dt, **settings)
            self.fused_shares = first.schedule == "fused"
            if self.fused_shares:
                bounds = np.arange(model.world_count + 1)
                rest = [Simulator(model.worlds(w, w + 1), dt, **settings) for w in range(1, model.world_count)]
                self.parts = [first, *rest]
            else:
                bounds = np.linspace(0, model.world_count, self.threads + 1).round().astype(int)
                self.parts = [Simulator(model.worlds(a, b), dt, **settings) for a, b in zip(bounds[:-1], bounds[1:])]
            self.starts = bounds[:-1]
        for part in self.parts:
            part.prepare_substeps()
        self.dt = self.parts[0].dt
        self._last: list[StepStats] | None = None
        self._stopped: dict[int, str] = {}  # worlds of one-world shares that stopped
        # per one-world share: its state at the start of a call and before a step replayed (`_share_steps`)
        self._snapshots = [
            (_Snapshot(part), _Snapshot(part)) if part.batch is None and model.world_count > 1 else None
            for part in self.parts
        ]
        self._pool = ThreadPoolExecutor(max(1, self.threads - 1), thread_name_prefix="warpimpulse")

    def close(self) -> None:
        self._pool.shutdown()
        for part in self.parts:
            if isinstance(part, SplitSimulator):
                part.close()

    def __enter__(self) -> ThreadedSimulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def time(self) -> float:
        return self.parts[0].time

    @property
    def step_count(self) -> int:
        return self.parts[0].step_count

    # ---------------------------------------------------------------- the step
    def _share_steps(self, index: int, n: int) -> list[StepStats | None] | None:
        """What runs on a thread: a batched share's batched part of one step (n = 1), or a one-world share's n
        steps, each world's StepStats (None for a step it had stopped before). A world whose step fails stops at
        its state at the start of that step, as in a batch, and its clock goes on."""
        part = self.parts[index]
        if part.batch is not None:
            part.batch.step_batched()
            return None
        world = int(self.starts[index])
        if world in self._stopped:
            return self._idle(part, [], n)
        start, before = self._snapshots[index]
        start.take(part)
        try:
            return part._steps(n)
        except (SimulationError, SingularSystemError):
            start.restore(part)
        out: list[StepStats | None] = []  # again a step at a time, to stop at the start of the failing one
        for _ in range(n):
            before.take(part)
            try:
                out += part._steps(1)
            except (SimulationError, SingularSystemError) as exc:
                before.restore(part)
                self._stopped[world] = f"world {world}: {exc}"
                return self._idle(part, [*out, StepStats(0, 0, 0.0, 0.0, False)], n)
        return out  # not reached: the same steps fail again (a step depends on its start only)

    @staticmethod
    def _idle(part: Simulator, out: list, n: int) -> list:
        """A stopped world's steps: its clock goes on, its state stays."""
        part.step_count += n - len(out)
        part.time = part.step_count * part.dt
        return out + [None] * (n - len(out))

    def step(self, n: int = 1) -> StepStats:
        """n steps of dt for every world; the StepStats over all worlds, combined over the steps as
        `Simulator.step` does (each world's figures of the last step in `world_stats`). One-world shares take
        the n steps in long fused launches; batched shares step together n times."""
        if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            raise ValueError(f"n must be an integer >= 1, got {n!r}")
        if self.model.world_count == 1:  # one tree on its threads: its Simulator's step, failures and all
            self._last = [self.parts[0].step(n)]
            return self._last[0]
        if self.fused_shares:
            steps = self._fused_step(n)
        else:
            steps = [self._batched_step() for _ in range(n)]
        return steps[0] if n == 1 else combined(steps)

    def _fused_step(self, n: int) -> list[StepStats]:
        """n steps of the one-world shares, each world's on whichever thread takes it."""
        known = set(self._stopped)
        tasks = [functools.partial(self._share_steps, i, n) for i in range(len(self.parts))]
        per_world = run_shared(self._pool, self.threads - 1, tasks)  # this thread takes shares too
        self._warn_stopped(known)
        zero = StepStats(0, 0, 0.0, 0.0, True)
        self._last = [steps[-1] or StepStats(0, 0, 0.0, 0.0, False) for steps in per_world]
        out = [self._over_worlds([s or zero for s in step], [s is not None for s in step]) for step in zip(*per_world)]
        self._check_all_stopped()
        return out

    def _batched_step(self) -> StepStats:
        """One step of the batched shares: their batched parts on the threads, then each share's rest."""
        known = set(self._stopped)
        tasks = [functools.partial(self._share_steps, i, 1) for i in range(len(self.parts))]
        results = run_shared(self._pool, self.threads - 1, tasks)
        self._warn_stopped(known)
        failed = StepStats(0, 0, 0.0, 0.0, False)
        self._last = [part.batch.finish() if r is None else r[0] or failed for part, r in zip(self.parts, results)]
        self._check_all_stopped()
        return self._over_worlds(self._last, [r is None or r[0] is not None for r in results])

    def _warn_stopped(self, known: set[int]) -> None:
        for w in sorted(set(self._stopped) - known):
            warnings.warn(f"{self._stopped[w]}; the world stops, the others go on", RuntimeWarning, stacklevel=4)

    def _check_all_stopped(self) -> None:
        if len(self.stopped) == self.model.world_count:
            raise SimulationError(f"every one of the {self.model.world_count} worlds has stopped")

    @staticmethod
    def _over_worlds(stats: list[StepStats], live: list[bool]) -> StepStats:
        """One step's StepStats over the shares: the most iterations, the largest errors; converged where every
        share that stepped converged (a world stopped before the step does not count, as in a batch)."""
        return StepStats(
            max(s.joint_iterations for s in stats), max(s.velocity_iterations for s in stats),
            max(s.max_joint_error for s in stats), max(s.max_velocity_error for s in stats),
            all(s.converged for s, on in zip(stats, live) if on), max(s.linear_iterations for s in stats),
            max(s.substeps for s in stats),
        )  # fmt: skip

    def simulate(self, duration: float) -> list[StepStats]:
        """Whole steps covering `duration` seconds, their StepStats over all worlds."""
        steps = int(round(duration / self.dt))
        if not steps:
            return []
        if not self.fused_shares:
            return [self.step() for _ in range(steps)]
        chunk = Simulator.FUSED_BATCH  # a launch's steps; each world's stats are kept only for a chunk
        return [s for start in range(0, steps, chunk) for s in self._fused_step(min(chunk, steps - start))]

    @property
    def world_stats(self) -> WorldStats | None:
        """Each world's figures of the last step, over all shares (None before the first step)."""
        if self._last is None:
            return None
        each = []
        for part, last in zip(self.parts, self._last):
            if part.batch is not None:
                each.append(part.world_stats)
            else:
                one = WorldStats.zeros(1)
                one.set(0, last)
                each.append(one)
        return WorldStats(*(np.concatenate([getattr(e, f) for e in each]) for f in WorldStats.__dataclass_fields__))

    @property
    def stopped(self) -> dict[int, str]:
        """Worlds that stopped, by index in the whole model, with why."""
        out = dict(self._stopped)
        for start, part in zip(self.starts, self.parts):
            out.update({int(start) + w: why for w, why in part.stopped.items()})
        return out

    # ---------------------------------------------------------------- per world
    def _part(self, world: int) -> tuple[Simulator, int | None]:
        """The share of `world` and its index there (None for a one-world share)."""
        if isinstance(world, (bool, np.bool_)) or not isinstance(world, (int, np.integer)):
            raise ValueError(f"a world index is expected, got {world!r}")
        if not 0 <= world < self.model.world_count:
            raise ValueError(f"world {world} does not exist ({self.model.world_count} worlds)")
        i = int(np.searchsorted(self.starts, world, side="right")) - 1
        part = self.parts[i]
        return part, (int(world - self.starts[i]) if part.batch is not None else None)

    def _gather(self, name: str, world: int | None, *args):
        """A per-world accessor of the shares: one world's, or all of them with a leading world dimension."""
        if world is not None:
            part, local = self._part(world)
            return getattr(part, name)(*args, world=local)
        parts = [np.asarray(getattr(part, name)(*args)) for part in self.parts]
        return np.concatenate([p if part.batch is not None else p[None] for p, part in zip(parts, self.parts)])

    def positions(self, world: int | None = None) -> np.ndarray:
        return self._gather("positions", world)

    def orientations(self, world: int | None = None) -> np.ndarray:
        return self._gather("orientations", world)

    def linear_velocities(self, world: int | None = None) -> np.ndarray:
        return self._gather("linear_velocities", world)

    def angular_velocities(self, world: int | None = None) -> np.ndarray:
        return self._gather("angular_velocities", world)

    def energy(self, world: int | None = None):
        return self._gather("energy", world)

    def _scatter(self, name: str, world: int | None, **values) -> None:
        """A per-world setter of the shares: one world's values, or all (leading world dimension) split."""
        if world is not None:
            part, local = self._part(world)
            getattr(part, name)(**values, world=local)
            return
        bounds = [*self.starts, self.model.world_count]
        for i, part in enumerate(self.parts):
            share = {k: None if v is None else np.asarray(v)[bounds[i] : bounds[i + 1]] for k, v in values.items()}
            if part.batch is None:
                share = {k: None if v is None else v[0] for k, v in share.items()}
            getattr(part, name)(**share)

    def set_external_forces(self, force=None, torque=None, world: int | None = None) -> None:
        self._scatter("set_external_forces", world, force=force, torque=torque)

    def set_masses(self, mass=None, inertia=None, world: int | None = None) -> None:
        self._scatter("set_masses", world, mass=mass, inertia=inertia)

    def set_state(self, positions=None, orientations=None, linear_velocities=None, angular_velocities=None,
                  world: int | None = None) -> None:  # fmt: skip
        self._scatter("set_state", world, positions=positions, orientations=orientations,
                      linear_velocities=linear_velocities, angular_velocities=angular_velocities)  # fmt: skip


class _Snapshot:
    """What a one-world Simulator carries from step to step, to go back to: its state, drive integrals, carried
    right-hand sides (`Simulator.carry`, of every step size: `prepare_substeps` made them), clock, spin and
    pending fallback. The copies are captured graphs, made before the threads start (a copy each way costs a few
    us per world; a world of 31 bodies takes about 18 us a step)."""

    def __init__(self, sim: Simulator) -> None:
        self.state, integral = sim.model.state(), wp.clone(sim.drive_integral)
        pairs = [
            (getattr(self.state, name), getattr(sim._state, name)) for name in ("body_x", "body_q", "body_v", "body_w")
        ]
        if integral.size:
            pairs.append((integral, sim.drive_integral))
        pairs += [(wp.clone(c), c) for arrays in sim._carries().values() for c in arrays]
        self._take = capture(sim.model.device, *(functools.partial(wp.copy, a, b) for a, b in pairs))
        self._back = capture(sim.model.device, *(functools.partial(wp.copy, b, a) for a, b in pairs))
        self.clock = (sim.time, sim.step_count, sim._spin, sim._fallback, sim._handout)

    def take(self, sim: Simulator) -> None:
        wp.capture_launch(self._take)
        self.clock = (sim.time, sim.step_count, sim._spin, sim._fallback, sim._handout)

    def restore(self, sim: Simulator) -> None:
        wp.capture_launch(self._back)
        sim.time, sim.step_count, sim._spin, sim._fallback, sim._handout = self.clock
        sim._active_forces = None
        sim._update_frames()
