"""Batched worlds on every core: the worlds split into shares, one per thread, each share a Simulator of its
own (`Model.worlds`), stepped at once by the calling thread and a pool's (`pool.run_shared`). One world alone
is one tree cut at its root instead, a part of it per thread (`split.SplitSimulator`).

A Warp CPU launch runs on one thread but releases the GIL, so Python threads launching on disjoint arrays use
separate cores (docs/architecture.md, "Warp on a CPU"). Graph capture on a CPU is one record for the whole
process, though: a launch from any thread while another captures would be recorded instead of run. So the
threads run only what captures nothing: every substep size is recorded before they start
(`Simulator.prepare_substeps`), and the rare worlds that must take a step alone (`worlds.Batch.finish`, which
may build a one-world simulator) finish on the calling thread after the others.

A world's run does not depend on its share: every world gives, bit for bit, the run of that world alone.
"""

from __future__ import annotations

import functools
import os
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .model import Model
from .pool import run_shared
from .simulator import SimulationError, Simulator, StepStats
from .split import SplitSimulator
from .worlds import WorldStats


class ThreadedSimulator:
    """Steps the worlds of a batched Model (`SceneBuilder.replicate`) on `threads` threads (default: one per
    core, at most one per world). Accessors, setters and stats are those of a batched Simulator: per world with
    `world=`, or with a leading world dimension. A Model of one world is stepped by a `SplitSimulator`: its
    tree cut at the root, a part per thread (`split_note` says why where it runs on one thread); its step fails
    as a Simulator's does."""

    def __init__(self, model: Model, dt: float, threads: int | None = None, **settings) -> None:
        """Args: model, dt and `settings` as for `Simulator`; threads: how many (>= 1)."""
        threads = os.cpu_count() or 1 if threads is None else threads
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError(f"threads must be an integer >= 1, got {threads!r}")
        self.model = model
        self.split_note = ""
        if model.world_count == 1:
            split = SplitSimulator(model, dt, threads=threads, **settings)
            self.threads, self.split_note, self.parts = split.threads, split.split_note, [split]
            self.starts = np.zeros(1, dtype=int)
        else:
            self.threads = min(threads, model.world_count)
            bounds = np.linspace(0, model.world_count, self.threads + 1).round().astype(int)
            self.starts = bounds[:-1]
            self.parts = [Simulator(model.worlds(a, b), dt, **settings) for a, b in zip(bounds[:-1], bounds[1:])]
        for part in self.parts:
            part.prepare_substeps()
        self.dt = self.parts[0].dt
        self._last: list[StepStats] | None = None
        self._starts_of_step = [
            part.model.state() if part.batch is None and model.world_count > 1 else None for part in self.parts
        ]
        self._stopped: dict[int, str] = {}  # worlds of one-world shares that stopped
        self._pool = ThreadPoolExecutor(max(1, len(self.parts) - 1), thread_name_prefix="warpimpulse")

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
    def _batched(self, index: int) -> StepStats | None:
        """What runs on a thread: a share's batched part of the step, or a one-world share's whole step."""
        part = self.parts[index]
        if part.batch is not None:
            part.batch.step_batched()
            return None
        if self.starts[index] in self._stopped:
            part.step_count += 1
            part.time = part.step_count * part.dt
            return StepStats(0, 0, 0.0, 0.0, False)
        start = self._starts_of_step[index]
        start.copy_from(part.state)
        try:
            return part.step()
        except SimulationError as exc:
            part.state.copy_from(start)  # a stopped world stays at its last good state, as in a batch
            self._stopped[int(self.starts[index])] = f"world {self.starts[index]}: {exc}"
            part.step_count += 1
            part.time = part.step_count * part.dt
            return StepStats(0, 0, 0.0, 0.0, False)

    def step(self) -> StepStats:
        """One step of dt for every world; the StepStats over all worlds (per world in `world_stats`)."""
        if self.model.world_count == 1:  # one tree on its threads: its Simulator's step, failures and all
            self._last = [self.parts[0].step()]
            return self._last[0]
        known = set(self._stopped)
        tasks = [functools.partial(self._batched, i) for i in range(len(self.parts))]
        results = run_shared(self._pool, len(self.parts) - 1, tasks)  # this thread takes shares too
        for w in sorted(set(self._stopped) - known):
            warnings.warn(f"{self._stopped[w]}; the world stops, the others go on", RuntimeWarning, stacklevel=2)
        stats = [part.batch.finish() if part.batch is not None else r for part, r in zip(self.parts, results)]
        self._last = stats
        if len(self.stopped) == self.model.world_count:
            raise SimulationError(f"every one of the {self.model.world_count} worlds has stopped")
        return StepStats(
            max(s.joint_iterations for s in stats), max(s.velocity_iterations for s in stats),
            max(s.max_joint_error for s in stats), max(s.max_velocity_error for s in stats),
            all(s.converged for s in stats), max(s.linear_iterations for s in stats), max(s.substeps for s in stats),
        )  # fmt: skip

    def simulate(self, duration: float) -> list[StepStats]:
        return [self.step() for _ in range(int(round(duration / self.dt)))]

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
