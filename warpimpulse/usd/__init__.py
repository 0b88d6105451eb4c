"""USD in, USD out: UsdPhysics scenes to SceneBuilders, simulated motion to time-sampled USD.

    scene = wi.usd.load_stage("robot.usda")            # reader.py: UsdPhysics -> SceneBuilder (+ prim paths)
    sim = wi.Simulator(scene.builder.finalize(), 1 / 240)
    wi.usd.record(sim, "out/robot.usdc", duration=5.0, fps=30, scene=scene)   # writer.py + warpimpulse.run
    anim = wi.usd.read_animation("out/robot.usdc")      # check.py: poses back from the time samples

Quaternions are (x, y, z, w) throughout; USD's `Gf.Quat*` constructors take the real part first.
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass
from typing import Any

from ..builder import SceneBuilder
from ..energy import EnergyWatch
from ..run import frame_count, frame_steps, record_frames, settings
from .check import Animation, read_animation, validate
from .reader import load_stage
from .scene import UnsupportedFeatureError, UsdScene, UsdSceneError, scene_from_builder
from .writer import INSTANCER_AUTO_BODIES, AnimationWriter, save_scene

__all__ = [
    "INSTANCER_AUTO_BODIES",
    "Animation",
    "AnimationWriter",
    "Recording",
    "UnsupportedFeatureError",
    "UsdScene",
    "UsdSceneError",
    "frame_steps",
    "load_stage",
    "read_animation",
    "record",
    "save_scene",
    "scene_from_builder",
    "validate",
]


@dataclass(frozen=True)
class Recording:
    """What `record` wrote: the file, its frames (frame f at t = f / fps s; time code f, or over a scene file
    start + f * rate / fps in the file's own rate), the simulator steps taken and the wall-clock seconds,
    output included."""

    path: str
    frames: int
    fps: float
    steps: int
    seconds: float


def record(
    sim: Any,
    path: str | os.PathLike,
    duration: float,
    fps: float = 30.0,
    scene: UsdScene | SceneBuilder | None = None,
    flatten: bool = False,
    instancer: bool | None = None,
    progress: bool | None = None,
) -> Recording:
    """Simulate `duration` seconds and write every 1/fps s as USD time samples, frame 0 being the state now.

    Args:
        sim: a `Simulator`; 1/fps must be a whole multiple of `sim.dt`.
        path: the output file (.usd, .usda or .usdc); its folder is created; an existing file is replaced.
        duration: simulated seconds; frames 0 .. round(duration * fps) are written.
        fps: frames per second (and time codes per second, unless `scene` is read from a file: the output then
            keeps that file's timeCodesPerSecond and startTimeCode, `AnimationWriter`).
        scene: the `UsdScene` from `load_stage` when the simulation was read from a file, so the output
            is a layer of `over`s on the input's prims; or the `SceneBuilder` the model was built from, to
            keep its shapes. By default the model's bodies, joints and forces are written as a whole
            UsdPhysics scene that reads back with `load_stage`, each body drawn as a sphere of its mean
            inertia (a model holds no shapes).
        flatten, instancer: as for `AnimationWriter`.
        progress: a progress bar on stderr (default: when stderr is a terminal).

    The simulator's settings are recorded in customLayerData (warpimpulse:dt, :tolerance, ...). If the
    simulation stops (SimulationError, FloatingPointError, Ctrl-C), the frames done so far are written,
    the file records the stop (warpimpulse:stoppedEarly), and the exception propagates. The energy gain over
    the run goes into the layer data too (warpimpulse:energyGain; `energy.EnergyWatch`), with a RuntimeWarning
    above 5% of the largest kinetic energy: the step is then too large for the motion. Why steps were taken at a
    lower order than asked goes there as well (warpimpulse:fallbacks; `Simulator.fallbacks`).
    """
    frame_steps(sim.dt, fps)  # a bad fps is refused before a file is touched
    frame_count(duration, fps)
    start_steps, start = sim.step_count, time.perf_counter()
    writer = AnimationWriter(
        path, sim.model if scene is None else scene, fps, settings(sim), flatten=flatten, instancer=instancer
    )
    energy = EnergyWatch(sim)
    with writer:
        frames = record_frames(sim, writer, duration, progress=progress, on_frame=energy.follow(writer.settings),
                               record=writer.settings)  # fmt: skip
    if energy.warning():
        warnings.warn(energy.warning(), RuntimeWarning, stacklevel=2)
    return Recording(writer.path, frames, writer.fps, sim.step_count - start_steps, time.perf_counter() - start)
