"""warpimpulse: impulse-based articulated rigid bodies (Bender & Schmitt 2006) on NVIDIA Warp."""

from .builder import SceneBuilder, SceneError
from .joints import JOINT_TYPES, ConstraintKind
from .shapes import Shape

__version__ = "0.1.0"

__all__ = ["JOINT_TYPES", "ConstraintKind", "SceneBuilder", "SceneError", "Shape", "__version__"]
