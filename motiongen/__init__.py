"""motiongen: diffusion models for human motion in 3D scenes."""

from motiongen.errors import MotiongenError

__all__ = ["MotiongenError"]
__version__ = "0.1.0"
