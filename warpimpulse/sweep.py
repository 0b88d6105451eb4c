"""`warpimpulse sweep`: a grid or a random sample of parameters over scenes, run as batched worlds on Ray or on
a local process pool, into one table (CSV and JSON), with plots and a progress bar; a stopped sweep resumes.

Parameters (`PARAMETERS`): a point's *shared* ones (scene, dt, tolerance, duration, max_iterations) decide its
simulator; its *per-world* ones (mass_scale, spin, force) are values a batched world takes without rebuilding.
Points that share the first are run together, a chunk at a time, as the worlds of one batched Simulator
(`SceneBuilder.replicate`): each world's run is, bit for bit, that point's run alone, so the table does not
depend on how the points were chunked or where they ran, except for the run times.

Columns: the point's parameters; outcome ("ok", "stopped", "error") and error; steps taken; joint iterations
summed over the steps; the largest joint error after a step (m or rad); energy drift, the relative change of
kinetic plus potential energy from start to end (loads and the scenes' start torque do work, so it measures
the method only where nothing else does); run time, the chunk's wall time over its points (s).

Every finished point is appended at once to `points.jsonl` in the output folder; a sweep started again with
the same folder reads it and computes only the points missing. A point whose simulation fails is recorded with
its error (outcome "stopped"), one whose chunk could not run at all with that error (outcome "error"), and the
rest go on.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import checks

POINT_BYTES = 4000
"""About the memory a point takes while a sweep runs (its parameters, its key, its row, its table entry: 0.65 kB
for the first two, measured with tracemalloc over 20 000 points): a sweep too large for the machine is
refused before any point is made (`checks.affordable`)."""

# name: (default, kind, what), the per-world ones last.
PARAMETERS: dict[str, tuple[object, type, str]] = {
    "scene": ("tree31", str, "a built-in scene (warpimpulse.scenes.SCENES)"),
    "dt": (1.0 / 60.0, float, "step, s"),
    "tolerance": (1e-6, float, "joint tolerance, m or rad"),
    "duration": (1.0, float, "simulated time, s"),
    "max_iterations": (100, int, "joint-correction iterations before a step fails"),
    "mass_scale": (1.0, float, "every body's mass and inertia times this (per world)"),
    "spin": (0.0, float, "initial angular velocity of every body about world z, rad/s (per world)"),
    "force": (0.0, float, "constant world x force on the last body, N (per world)"),
}
PER_WORLD = ("mass_scale", "spin", "force")
POSITIVE = ("dt", "tolerance", "duration", "max_iterations", "mass_scale")
COLUMNS = ("point", *PARAMETERS, "outcome", "error", "steps", "joint_iterations", "max_joint_error",
           "energy_drift", "run_time_s")  # fmt: skip
TIMING = ("run_time_s",)  # the columns that vary from run to run


@dataclass(frozen=True)
class Point:
    index: int
    params: dict

    @property
    def key(self) -> str:
        """What identifies the point in a resumed sweep: its parameters, not its place."""
        return json.dumps(self.params, sort_keys=True)


# ---------------------------------------------------------------- the points
def _value(name: str, text) -> object:
    if name not in PARAMETERS:
        raise ValueError(f"unknown parameter {name!r}; expected one of {', '.join(PARAMETERS)}")
    kind = PARAMETERS[name][1]
    try:
        value = kind(text)
    except (TypeError, ValueError):
        raise ValueError(f"parameter {name}: {text!r} is not a {kind.__name__}") from None
    if kind is not str and not math.isfinite(value):
        raise ValueError(f"parameter {name}: {text!r} is not finite")
    if name in POSITIVE and not value > 0:
        raise ValueError(f"parameter {name}: must be positive, got {text!r}")
    if name == "scene":
        from .scenes import SCENES

        if value not in SCENES:
            raise ValueError(f"parameter scene: unknown scene {value!r}; expected one of {', '.join(sorted(SCENES))}")
    return value


def parse_param(text: str) -> tuple[str, list]:
    """`name=v1,v2,...` (a --param flag) as (name, values)."""
    name, sep, values = text.partition("=")
    if not sep or not values:
        raise ValueError(f"--param {text!r}: expected name=value1,value2,...")
    name = name.strip()
    return name, [_value(name, v.strip()) for v in values.split(",")]


def load_config(path: Path) -> dict:
    """A sweep file (TOML): `[params]` name = [values] (a grid); `[random]` samples = N, seed = S and
    `[random.ranges]` name = [low, high] for a random sample instead of the grid."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        raise ValueError(f"{path}: reading TOML needs Python 3.11 (tomllib); pass --param flags instead") from None
    try:
        data = tomllib.loads(Path(path).read_text())
    except OSError as err:
        raise ValueError(f"{path}: {err.strerror or err}") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{path}: not valid TOML ({err})") from None
    unknown = sorted(set(data) - {"params", "random"})
    if unknown:
        raise ValueError(f"{path}: unknown table(s) {unknown}; expected [params] and [random]")
    try:
        return _config(data)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None


def _config(data: dict) -> dict:
    """`load_config`'s checks of a read TOML file: each message names the parameter, the caller the file."""
    params = {}
    for name, values in data.get("params", {}).items():
        values = values if isinstance(values, list) else [values]
        if not values:
            raise ValueError(f"params.{name} = []: no value to sweep")
        params[name] = [_value(name, v) for v in values]
    random = data.get("random", {})
    ranges = {}
    for name, bounds in random.get("ranges", {}).items():
        if not (isinstance(bounds, list) and len(bounds) == 2):
            raise ValueError(f"random.ranges.{name} must be [low, high]")
        if PARAMETERS.get(name, (None, float))[1] is str:
            raise ValueError(f"random.ranges.{name}: {name} is not a number; list its values in [params]")
        low, high = (float(_value(name, b)) for b in bounds)
        if low > high:
            raise ValueError(f"random.ranges.{name} = [{low:g}, {high:g}]: low is above high")
        ranges[name] = (low, high)
    samples = random.get("samples")
    if samples is not None and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
        raise ValueError(f"random.samples must be an integer >= 1, got {samples!r}")
    seed = random.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"random.seed must be an integer >= 0, got {seed!r}")
    if not params and not ranges:
        raise ValueError("nothing to sweep: no [params] values and no [random.ranges]")
    return {"params": params, "samples": samples, "seed": seed, "ranges": ranges}


def make_points(params: dict[str, list], samples: int | None = None, seed: int = 0,
                ranges: dict[str, tuple[float, float]] | None = None) -> list[Point]:  # fmt: skip
    """The grid of `params` (every combination, in the order given); or, with `samples`, that many random
    points: each listed parameter drawn from its values, each ranged one uniform in [low, high) (numpy's
    generator seeded with `seed`). Parameters not given take their defaults."""
    ranges = ranges or {}
    defaults = {name: spec[0] for name, spec in PARAMETERS.items()}
    if samples is None:
        if ranges:
            raise ValueError("ranges need a random sample (samples = N)")
        empty = [n for n, values in params.items() if not values]
        if empty:
            raise ValueError(f"parameter {empty[0]} has no value: nothing to sweep")
        count = math.prod(len(values) for values in params.values())
    elif isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    else:
        count = samples
    checks.affordable(count, POINT_BYTES, "the sweep", "point")
    if samples is None:
        names = list(params)
        chosen = [dict(zip(names, combo)) for combo in itertools.product(*(params[n] for n in names))]
    else:
        rng = np.random.default_rng(seed)
        chosen = []
        for _ in range(samples):
            point = {n: values[int(rng.integers(len(values)))] for n, values in params.items()}
            point.update({n: float(rng.uniform(lo, hi)) for n, (lo, hi) in ranges.items()})
            chosen.append(point)
    return [Point(i, {**defaults, **p}) for i, p in enumerate(chosen)]


def make_chunks(points: list[Point], workers: int, chunk_size: int = 16) -> list[list[Point]]:
    """Points that share their simulator (all but the per-world parameters), in chunks of at most
    `chunk_size`, and small enough that `workers` all get work."""
    groups: dict[tuple, list[Point]] = {}
    for p in points:
        groups.setdefault(tuple(v for n, v in p.params.items() if n not in PER_WORLD), []).append(p)
    chunks = []
    for group in groups.values():
        size = max(1, min(chunk_size, math.ceil(len(group) / max(workers, 1))))
        chunks += [group[i : i + size] for i in range(0, len(group), size)]
    return chunks


# ---------------------------------------------------------------- one chunk (runs in a worker)
def run_chunk(points: list[Point]) -> list[dict]:
    """Simulate the points of one chunk as the worlds of one batched Simulator; a row per point."""
    import warnings

    from .options import StepOptions
    from .scenes import SCENES
    from .simulator import SimulationError, Simulator
    from .solver import SingularSystemError

    start = time.perf_counter()
    p0, count = points[0].params, len(points)
    # The velocities corrected every step, as a batch of worlds takes them, so that a point's row does not depend
    # on its chunk (one world alone would defer them, `StepOptions.defer_velocities`).
    sim = Simulator(SCENES[p0["scene"]]().replicate(count).finalize(), p0["dt"], tolerance=p0["tolerance"],
                    max_iterations=p0["max_iterations"], options=StepOptions(defer_velocities=False))  # fmt: skip
    n, host = sim.model.world_body_count, sim.model.host
    per = {name: np.array([p.params[name] for p in points], dtype=np.float64) for name in PER_WORLD}
    scale = per["mass_scale"]
    mass = host.body_mass.reshape(count, n) * scale[:, None]
    inertia = host.body_inertia.reshape(count, n, 3, 3) * scale[:, None, None, None]
    spin, force = np.zeros((count, n, 3)), np.zeros((count, n, 3))
    spin[:, :, 2] = per["spin"][:, None]
    force[:, -1, 0] = per["force"]
    if count == 1:  # a one-world model takes arrays without the world dimension (and raises where a batch stops)
        mass, inertia, spin, force = mass[0], inertia[0], spin[0], force[0]
    sim.set_masses(mass=mass, inertia=inertia)
    sim.set_state(angular_velocities=spin)
    sim.set_external_forces(force=force)
    e0 = np.atleast_1d(sim.energy())
    iterations, worst, taken = np.zeros(count, np.int64), np.zeros(count), np.zeros(count, np.int64)
    errors = [""] * count
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a stopped world is reported in its row
        for _ in range(int(round(p0["duration"] / p0["dt"]))):
            live = np.array([w not in sim.stopped for w in range(count)])
            try:
                stats = sim.step()
            except (SimulationError, SingularSystemError) as exc:  # a one-world chunk, or every world stopped
                for w in np.flatnonzero(live):
                    errors[w] = errors[w] or str(exc)
                break
            each = sim.world_stats
            iterations += each.joint_iterations if each is not None else stats.joint_iterations
            worst = np.maximum(worst, each.max_joint_error if each is not None else stats.max_joint_error)
            taken += live & np.array([w not in sim.stopped for w in range(count)])
    for w, why in sim.stopped.items():
        errors[w] = why.removeprefix(f"world {w}: ")
    # Name bodies and joints as in the scene, not by their place in this chunk.
    errors = [e.replace(f"world{w}/", "") for w, e in enumerate(errors)]
    e1 = np.atleast_1d(sim.energy())
    elapsed = (time.perf_counter() - start) / count
    return [
        {"point": p.index, **p.params, "outcome": "stopped" if errors[w] else "ok", "error": errors[w],
         "steps": int(taken[w]), "joint_iterations": int(iterations[w]), "max_joint_error": float(worst[w]),
         "energy_drift": None if errors[w] or e0[w] == 0.0 else float((e1[w] - e0[w]) / abs(e0[w])),
         "run_time_s": elapsed}
        for w, p in enumerate(points)
    ]  # fmt: skip


def error_rows(points: list[Point], error: BaseException) -> list[dict]:
    """The rows of a chunk that could not run: each point with the error."""
    return [{"point": p.index, **p.params, "outcome": "error", "error": f"{type(error).__name__}: {error}",
             "steps": 0, "joint_iterations": 0, "max_joint_error": None, "energy_drift": None, "run_time_s": None}
            for p in points]  # fmt: skip


# ---------------------------------------------------------------- where chunks run
def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def on_pool(chunks: list[list[Point]], workers: int) -> Iterator[list[dict]]:
    """Each chunk on a local process pool (spawned workers, so Warp starts fresh in each), as they finish."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(run_chunk, chunk): chunk for chunk in chunks}
        for future in as_completed(futures):
            try:
                yield future.result()
            except Exception as exc:  # recorded in the rows; the rest go on
                yield error_rows(futures[future], exc)


def on_ray(chunks: list[list[Point]], workers: int, address: str | None) -> Iterator[list[dict]]:
    """Each chunk a Ray task, on a local cluster of `workers` CPUs (`ray.init()`) or on the running one at
    `address` (HOST:PORT, where warpimpulse must be installed too), as they finish."""
    import ray

    if not ray.is_initialized():
        if address is None:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    task = ray.remote(num_cpus=1)(run_chunk)
    pending = {task.remote(chunk): chunk for chunk in chunks}
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        for ref in done:
            chunk = pending.pop(ref)
            try:
                yield ray.get(ref)
            except Exception as exc:  # recorded in the rows; the rest go on
                yield error_rows(chunk, getattr(exc, "cause", None) or exc)


# ---------------------------------------------------------------- the sweep
@dataclass
class Result:
    rows: list[dict]  # every point of the sweep, in order
    computed: list[int]  # the points this run computed (the others were done before)
    backend: str  # "ray" or "pool"


def _read_done(path: Path) -> dict[str, dict]:
    done = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:  # a line cut short by a stop: that point is computed again
                continue
            done[row["key"]] = row
    return done


def run(points: list[Point], out: Path, workers: int | None = None, backend: str = "auto",
        address: str | None = None, chunk_size: int = 16,
        progress: Callable[[int, int, int], None] | None = None) -> Result:  # fmt: skip
    """Run the points not yet in `out`/points.jsonl, appending each row as it comes, then write `out`/sweep.csv
    and sweep.json with every point. backend: "ray", "pool" or "auto" (Ray when it is installed)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log = out / "points.jsonl"
    done = _read_done(log)
    todo = [p for p in points if p.key not in done]
    workers = workers or os.cpu_count() or 1
    if backend == "auto":
        backend = "ray" if ray_available() else "pool"
    chunks = make_chunks(todo, workers, chunk_size)
    source: Iterable[list[dict]] = []
    if chunks:
        source = on_ray(chunks, workers, address) if backend == "ray" else on_pool(chunks, workers)
    computed, failed = [], 0
    if progress:
        progress(0, len(todo), 0)
    with log.open("a") as f:
        if log.stat().st_size and not log.read_bytes().endswith(b"\n"):
            f.write("\n")  # after a line cut short by a stop
        for rows in source:
            for row in rows:
                key = points[row["point"]].key
                done[key] = {"key": key, **row}
                f.write(json.dumps(done[key]) + "\n")
                computed.append(row["point"])
                failed += row["outcome"] != "ok"
            f.flush()
            if progress:
                progress(len(computed), len(todo), failed)
    table = [{**{c: done[p.key].get(c) for c in COLUMNS}, "point": p.index} for p in points]
    write_table(table, out)
    return Result(table, sorted(computed), backend)


def failures(rows: list[dict], most: int = 5) -> list[str]:
    """A line for each distinct reason points failed ("error": the chunk did not run; "stopped": the simulation
    stopped), with how many and which points, the `most` commonest; the table holds every point's."""
    reasons: dict[tuple[str, str], list[int]] = {}
    for row in rows:
        if row["outcome"] != "ok":
            reasons.setdefault((row["outcome"], row["error"] or "no reason recorded"), []).append(row["point"])
    ranked = sorted(reasons.items(), key=lambda item: -len(item[1]))
    lines = []
    for (outcome, why), points in ranked[:most]:
        listed = ", ".join(str(p) for p in points[:5]) + (", ..." if len(points) > 5 else "")
        lines.append(f"{outcome} in {len(points)} point{'s' if len(points) > 1 else ''} ({listed}): {why}")
    if len(ranked) > most:
        lines.append(f"and {len(ranked) - most} other reasons: see the table's error column")
    return lines


def write_table(rows: list[dict], out: Path) -> None:
    with (out / "sweep.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    (out / "sweep.json").write_text(json.dumps(rows, indent=1) + "\n")


def progress_bar(done: int, total: int, failed: int) -> None:
    """On stderr: [####    ] done/total points, failed."""
    bar = "#" * int(30 * done / max(total, 1))
    tail = f", {failed} failed" if failed else ""
    print(f"\r[{bar:<30}] {done}/{total} points{tail}", end="\n" if done == total else "", file=sys.stderr, flush=True)


def plot(rows: list[dict], path: Path) -> bool:
    """Run time, iterations and energy drift against each parameter that varies; False without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    varying = [n for n in PARAMETERS if PARAMETERS[n][1] is not str and len({r[n] for r in rows}) > 1][:4]
    varying = varying or ["point"]
    metrics = ("run_time_s", "joint_iterations", "energy_drift")
    fig, axes = plt.subplots(len(metrics), len(varying), figsize=(3.2 * len(varying), 7.5), squeeze=False)
    for j, name in enumerate(varying):
        for i, metric in enumerate(metrics):
            ax = axes[i][j]
            for outcome, color in (("ok", "tab:blue"), ("stopped", "tab:red"), ("error", "black")):
                pts = [(r[name], r[metric]) for r in rows if r["outcome"] == outcome and r[metric] is not None]
                if pts:
                    ax.scatter(*zip(*pts), s=12, color=color, label=outcome)
            ax.set_xlabel(name)
            ax.set_ylabel(metric)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True
