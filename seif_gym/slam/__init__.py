"""The SLAM filter library of seif_gym, usable without the environment."""

from seif_gym.slam.base import SlamFilter, UnknownLandmarkError
from seif_gym.slam.models import MotionModel, RangeBearingSensor, VelocityMotionModel, wrap_angle

__all__ = [
    "MotionModel",
    "RangeBearingSensor",
    "SlamFilter",
    "UnknownLandmarkError",
    "VelocityMotionModel",
    "wrap_angle",
]
