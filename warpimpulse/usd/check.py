"""Reading exported files back: the body poses of every time sample (`read_animation`) and UsdValidation
errors (`validate`). The tests and `warpimpulse preview` see an output the way another USD reader would."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..transforms import quat_rotate
from .reader import decompose, load_stage
from .scene import INSTANCER_PATH, MODE_KEY, UsdScene, open_stage, pxr


@dataclass
class Animation:
    """Frames read back from an exported file: centres of mass (F, N, 3) in metres and orientations
    (F, N, 4) as (x, y, z, w), both in the stage's world frame, whose vertical is `up_axis`. `fps` is the
    file's timeCodesPerSecond; its startTimeCode is t = 0."""

    time_codes: np.ndarray
    body_paths: list[str]
    positions: np.ndarray
    orientations: np.ndarray
    fps: float
    up_axis: str = "Z"
    start_time_code: float = 0.0

    @property
    def seconds(self) -> np.ndarray:
        """The simulated time of each frame, s."""
        return (self.time_codes - self.start_time_code) / self.fps


def read_animation(path: str | os.PathLike, scene: UsdScene | None = None) -> Animation:
    """Read the body poses of every time sample of an exported file (per-body prims or instancer)."""
    _, _, _, Usd, UsdGeom, *_ = pxr()
    path = os.fspath(path)
    stage = open_stage(path)
    layer = stage.GetRootLayer()
    fps = float(layer.timeCodesPerSecond)
    start = float(layer.startTimeCode)
    up = str(UsdGeom.GetStageUpAxis(stage))
    mode = layer.customLayerData.get(MODE_KEY, "")
    if mode == "instancer":
        inst = UsdGeom.PointInstancer(stage.GetPrimAtPath(INSTANCER_PATH))
        times = np.array(inst.GetPositionsAttr().GetTimeSamples(), dtype=np.float64)
        pos = np.array([np.array(inst.GetPositionsAttr().Get(t), dtype=np.float64) for t in times])
        ori = np.array([np.array(inst.GetOrientationsAttr().Get(t), dtype=np.float64) for t in times])
        n = pos.shape[1] if len(times) else 0
        return Animation(times, [f"{INSTANCER_PATH}[{i}]" for i in range(n)], pos, ori, fps, up, start)
    if scene is None:
        with warnings.catch_warnings():  # the run that wrote the file gave them (and its customLayerData has them)
            warnings.simplefilter("ignore")
            scene = load_stage(path, ignore_unsupported=True)
    prims = [stage.GetPrimAtPath(p) for p in scene.body_paths]
    # The frames are the moving bodies' samples: a static body keeps its prim as the input authors it (animated
    # or not).
    moving = [p for p, b in zip(prims, scene.builder.bodies) if not b.static] or prims
    times = sorted({t for p in moving for t in UsdGeom.Xformable(p).GetTimeSamples()})
    pos = np.zeros((len(times), len(prims), 3))
    ori = np.zeros((len(times), len(prims), 4))
    for k, t in enumerate(times):
        cache = UsdGeom.XformCache(Usd.TimeCode(t))
        for i, prim in enumerate(prims):
            fr = decompose(cache.GetLocalToWorldTransform(prim), str(prim.GetPath()))
            pos[k, i] = (fr.t + quat_rotate(fr.q, scene.com_offsets[i])) * scene.meters_per_unit
            ori[k, i] = fr.q
    return Animation(np.array(times, dtype=np.float64), list(scene.body_paths), pos, ori, fps, up, start)


def validate(path_or_stage: Any) -> list[str]:
    """UsdValidation errors (not warnings) on a file or stage, as strings; empty when it is clean."""
    from pxr import UsdValidation

    stage = open_stage(os.fspath(path_or_stage)) if isinstance(path_or_stage, (str, os.PathLike)) else path_or_stage
    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    errors = ctx.Validate(stage)
    return [
        f"{e.GetName()}: {e.GetMessage()}" for e in errors if e.GetType() == UsdValidation.ValidationErrorType.Error
    ]
