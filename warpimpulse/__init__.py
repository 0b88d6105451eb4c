"""warpimpulse: impulse-based articulated rigid bodies (Bender & Schmitt 2006) on NVIDIA Warp.

`import warpimpulse as wi` gives the builder and simulator; `wi.scenes` (built-in scenes), `wi.usd` (USD in
and out), `wi.run` (the frame loop) and `wi.sweep` (parameter sweeps) are imported on first use, so that
`import warpimpulse` stays fast.
"""

import importlib

from .builder import SceneBuilder, SceneError
from .files import WriteError
from .joints import JOINT_TYPES
from .mjcf import load_mjcf
from .model import Model
from .options import StepOptions
from .shapes import Shape
from .simulator import CheckpointError, SimulationError, Simulator, StepStats
from .solver import SingularSystemError
from .threads import ThreadedSimulator
from .types import WORLD, ConstraintKind, Quat, Vec3
from .urdf import UrdfError, load_urdf
from .verbosity import quiet_by_default
from .worlds import WorldStats

quiet_by_default()  # no Warp banner or module-load lines unless asked (Simulator(verbose=True), --verbose)

__version__ = "0.1.0"

__all__ = [
    "JOINT_TYPES",
    "CheckpointError",
    "ConstraintKind",
    "Model",
    "SceneBuilder",
    "SceneError",
    "Shape",
    "SimulationError",
    "Simulator",
    "SingularSystemError",
    "StepOptions",
    "StepStats",
    "ThreadedSimulator",
    "UrdfError",
    "WorldStats",
    "Quat",
    "Vec3",
    "WORLD",
    "WriteError",
    "__version__",
    "load_mjcf",
    "load_urdf",
    "run",
    "scenes",
    "sweep",
    "usd",
]

_LAZY = ("run", "scenes", "sweep", "usd")


def __getattr__(name: str):
    """The submodules in `_LAZY`, imported on first access (PEP 562)."""
    if name in _LAZY:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
