"""Driving a simulation frame by frame into a writer, with a progress bar: the loop behind both
`warpimpulse simulate` and `warpimpulse.usd.record`.

Frame f holds the state at t = f / fps; between frames the simulator takes whole steps of dt, so 1/fps must
be a whole multiple of dt (`frame_steps`). Nothing here knows USD: the writer is anything with `fps` and
`write_frame`.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np


class FrameWriter(Protocol):
    """Where frames go (e.g. `warpimpulse.usd.AnimationWriter`)."""

    fps: float

    def write_frame(self, frame: int, positions: np.ndarray, orientations: np.ndarray) -> None:
        """Frame `frame` (t = frame / fps): centres of mass (N, 3) in metres and orientations (N, 4) as
        (x, y, z, w), world frame. The writer decides its time code (`AnimationWriter.time_code`)."""


def frame_steps(dt: float, fps: float) -> int:
    """Steps of `dt` per frame. Raises ValueError unless 1/fps is a whole multiple of dt (to 1e-9)."""
    ratio = 1.0 / (fps * dt)
    steps = round(ratio)
    if steps < 1 or abs(ratio - steps) > 1e-9 * max(ratio, 1.0):
        raise ValueError(
            f"1/fps = {1.0 / fps:.9g} s is not a whole multiple of dt = {dt:.9g} s ({ratio:.6g} steps a frame); "
            f"choose dt = 1/(fps*k), e.g. dt = {1.0 / (fps * max(1, math.ceil(ratio))):.9g}"
        )
    return steps


def frame_count(duration: float, fps: float) -> int:
    """The frames after frame 0 in `duration` seconds: round(duration * fps). Raises ValueError when that is
    0, which would write the start state and simulate nothing."""
    frames = int(round(duration * fps))
    if frames < 1:
        raise ValueError(
            f"fps {fps:g}: a frame lasts {1.0 / fps:.6g} s, longer than the duration {duration:g} s, so no step "
            "would be simulated; raise fps or the duration"
        )
    return frames


def settings(sim: Any) -> dict[str, Any]:
    """The simulator settings an output file records (customLayerData warpimpulse:*), so a run can be
    repeated from its file."""
    notes = {"scheduleNote": getattr(sim, "schedule_note", ""), "splitNote": getattr(sim, "split_note", ""),
             "damperNote": sim.damper_note() if hasattr(sim, "damper_note") else ""}  # fmt: skip
    return {
        "dt": sim.dt,
        "schedule": getattr(sim, "schedule", ""),  # the fused step (a CPU's, one kernel) or the parallel stages
        **{key: note for key, note in notes.items() if note},  # why the schedule or threads asked for are not used,
        # which dampers were taken implicitly
        "tolerance": sim.tolerance,
        "velocity_tolerance": sim.velocity_tolerance,
        "solver": sim.solver_name,
        "max_iterations": sim.max_iterations,
        "max_rotation": sim.max_rotation or 0.0,  # 0: whole steps
        "order": sim.order,  # in time: 2 the paper's step, 4 and 6 its compositions
        "composition": sim.scheme.name,
        "newton": sim.newton,  # the first joint iteration's Newton step
        "carry": sim.carry,  # the first joint iteration's carried right-hand side
        "defer_velocities": sim.defer_velocities,  # velocities corrected only where a frame is handed out
        "reuse_factor": sim.reuse_factor,  # K's factor kept across steps where it serves
        "split_forces": sim.split_forces,  # elements of the poses alone as half kicks about each step
        **({"accuracy": sim.accuracy.plan.accuracy} if sim.accuracy is not None else {}),  # m: dt is the largest step
    }


def record_frames(
    sim: Any,
    writer: FrameWriter,
    duration: float,
    dt: float | None = None,
    progress: bool | None = None,
    on_frame: Callable[[int], None] | None = None,
    record: dict | None = None,
) -> int:
    """Step `sim` and write frames 0 .. round(duration * fps) inclusive (frame f holds t = f / fps).

    `sim` needs `step(n)` (n steps: one fused launch a frame), `positions()` and `orientations()` (and `dt`
    unless given). A progress bar is drawn on stderr when it is a terminal (or `progress=True`). Returns the
    number of frames written; call it inside `with writer:` so that an error or Ctrl-C still leaves a valid
    file. A non-finite state raises FloatingPointError naming the frame. `on_frame(f)` runs after frame f is
    written (the energy watch of `energy.EnergyWatch.follow`). `record` (a writer's settings, which go into the
    layer data, even of a partial file) gets the sentences of `sim.fallbacks` so far under "fallbacks": why
    steps were taken at a lower order than asked.
    """
    dt = float(dt if dt is not None else sim.dt)
    steps = frame_steps(dt, writer.fps)
    frames = frame_count(duration, writer.fps)
    show = sys.stderr.isatty() if progress is None else progress
    start = time.perf_counter()
    for f in range(frames + 1):
        if f > 0:
            sim.step(steps)
            if record is not None and getattr(sim, "fallbacks", None):
                record["fallbacks"] = [sim.fallback_note(reason) for reason in sim.fallbacks]
        x, q = sim.positions().reshape(-1, 3), sim.orientations().reshape(-1, 4)  # batched worlds: all of them
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(q))):
            raise FloatingPointError(f"the simulation diverged (non-finite state) before frame {f}")
        writer.write_frame(f, x, q)
        if on_frame is not None:
            on_frame(f)
        if show:
            done = (f + 1) / (frames + 1)
            bar = "#" * int(30 * done)
            rate = (f + 1) / max(time.perf_counter() - start, 1e-9)
            print(f"\r[{bar:<30}] {f}/{frames} frames  {rate:6.1f} fps", end="", file=sys.stderr, flush=True)
    if show:
        print(file=sys.stderr)
    return frames + 1
