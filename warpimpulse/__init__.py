"""warpimpulse: impulse-based articulated rigid bodies (Bender & Schmitt 2006) on NVIDIA Warp."""

from .builder import SceneBuilder, SceneError
from .joints import JOINT_TYPES
from .model import Model
from .shapes import Shape
from .simulator import SimulationError, Simulator, StepStats
from .solver import SingularSystemError
from .types import WORLD, ConstraintKind, Quat, Vec3

__version__ = "0.1.0"

__all__ = [
    "JOINT_TYPES",
    "ConstraintKind",
    "Model",
    "SceneBuilder",
    "SceneError",
    "Shape",
    "SimulationError",
    "Simulator",
    "SingularSystemError",
    "StepStats",
    "Quat",
    "Vec3",
    "WORLD",
    "__version__",
]
