"""`warpimpulse preview OUT.usdc -o preview.png`: a picture of a written run without a USD viewer.

The bodies are drawn as points at their centres of mass, read from the file's time samples (body prims or
the PointInstancer), and each joint as a segment between the centres of mass of its two bodies (or from its
world anchor); the stage's up axis is drawn vertical. A .png shows a few frames side by side, a .gif plays
the run. matplotlib comes from the `preview` extra: `pip install "warpimpulse[preview]"`.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

from .builder import WORLD
from .usd import Animation, UsdSceneError, load_stage, read_animation

INSTALL = 'warpimpulse preview needs matplotlib: pip install "warpimpulse[preview]" (or pip install matplotlib)'
# Stage axes -> drawing axes (x, y, z up), keeping the frame right-handed.
_AXES = {"Z": ([0, 1, 2], [1.0, 1.0, 1.0]), "Y": ([0, 2, 1], [1.0, -1.0, 1.0]), "X": ([1, 2, 0], [1.0, 1.0, 1.0])}


def read(path: Path) -> tuple[Animation, np.ndarray, np.ndarray]:
    """The run's frames, joint segments as body index pairs (J, 2), and world anchors (J, 3) where a
    joint's parent is the world (index -1 in the pairs). An instancer file has no joints."""
    try:
        with warnings.catch_warnings():  # unsupported features are dropped quietly: this only draws
            warnings.simplefilter("ignore")
            scene = load_stage(path, ignore_unsupported=True)
    except UsdSceneError:
        scene = None  # a PointInstancer output holds no rigid bodies; read_animation reads it alone
    anim = read_animation(path, scene)
    joints = scene.builder.joints if scene is not None else []
    pairs = np.array([(j.parent if j.parent != WORLD else -1, j.child) for j in joints], dtype=np.int64)
    anchors = np.array([j.anchor for j in joints], dtype=np.float64)
    return anim, pairs.reshape(-1, 2), anchors.reshape(-1, 3)


def _segments(x: np.ndarray, pairs: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """(J, 2, 3) end points of the joint segments in one frame."""
    start = np.where(pairs[:, :1] >= 0, x[np.maximum(pairs[:, 0], 0)], anchors)
    return np.stack([start, x[pairs[:, 1]]], axis=1)


def draw(anim: Animation, pairs: np.ndarray, anchors: np.ndarray, out: Path, panels: int, gif_frames: int) -> int:
    """Write the picture; returns the number of frames drawn."""
    from matplotlib.animation import FuncAnimation, PillowWriter
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    order, sign = _AXES[anim.up_axis]
    pos = anim.positions[..., order] * sign
    anchors = anchors[:, order] * sign
    if len(pos) == 0:
        raise ValueError(f"{out}: the file holds no time samples to draw")
    everything = np.concatenate([pos.reshape(-1, 3), anchors])
    lo, hi = everything.min(axis=0), everything.max(axis=0)
    centre, half = 0.5 * (lo + hi), 0.5 * max(float((hi - lo).max()), 1e-3) * 1.05
    size = float(np.clip(2000.0 / max(pos.shape[1], 1), 1.0, 30.0))

    def paint(ax, k: int) -> None:
        ax.cla()
        x = pos[k]
        if len(pairs):
            ax.add_collection3d(Line3DCollection(_segments(x, pairs, anchors), colors="0.45", linewidths=1.0))
        ax.scatter(x[:, 0], x[:, 1], x[:, 2], s=size, c="tab:blue", depthshade=False)
        for axis, set_lim in enumerate((ax.set_xlim, ax.set_ylim, ax.set_zlim)):
            set_lim(centre[axis] - half, centre[axis] + half)
        ax.set_box_aspect((1.0, 1.0, 1.0))
        ax.set_title(f"t = {anim.seconds[k]:.3g} s", fontsize=9)
        ax.tick_params(labelsize=6)

    count = len(pos)
    if out.suffix.lower() == ".gif":
        shown = np.unique(np.linspace(0, count - 1, min(gif_frames, count)).round().astype(int))
        fig = Figure(figsize=(5, 5))
        ax = fig.add_subplot(projection="3d")
        seconds = anim.seconds[shown[-1]] - anim.seconds[shown[0]]
        rate = max(1.0, (len(shown) - 1) / seconds) if seconds > 0 else 1.0  # plays in real time where it can
        FuncAnimation(fig, lambda k: paint(ax, int(k)), frames=shown).save(str(out), writer=PillowWriter(fps=rate))
        return len(shown)
    shown = np.unique(np.linspace(0, count - 1, min(panels, count)).round().astype(int))
    fig = Figure(figsize=(3.2 * len(shown), 3.4))
    for n, k in enumerate(shown):
        paint(fig.add_subplot(1, len(shown), n + 1, projection="3d"), int(k))
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return len(shown)


def main(path: Path, out: Path | None, panels: int = 4, gif_frames: int = 60) -> int:
    """The `preview` command: exit 0, or 2 (one line on stderr) without matplotlib or for a bad path."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print(f"warpimpulse: error: {INSTALL}", file=sys.stderr)
        return 2
    out = out or path.with_suffix(".png")
    if out.suffix.lower() not in (".png", ".gif"):
        raise ValueError(f"{out}: the picture must end in .png or .gif")
    if out.exists():
        print(f"warpimpulse: overwriting {out}", file=sys.stderr)
    anim, pairs, anchors = read(path)
    drawn = draw(anim, pairs, anchors, out, panels, gif_frames)
    print(f"wrote {out}: {len(anim.body_paths)} bodies at {drawn} of {len(anim.time_codes)} frames")
    return 0
