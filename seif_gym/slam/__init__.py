"""The SLAM filter library of seif_gym, usable without the environment.

Filters (one interface, :class:`SlamFilter`): :class:`SEIF` (sparse extended
information filter), :class:`EIF` (exact extended information filter) and
:class:`EKF` (EKF SLAM). Models: :class:`VelocityMotionModel` and
:class:`RangeBearingSensor`.
"""

from seif_gym.slam.base import SlamFilter, UnknownLandmarkError
from seif_gym.slam.eif import EIF
from seif_gym.slam.ekf import EKF
from seif_gym.slam.models import MotionModel, RangeBearingSensor, VelocityMotionModel, wrap_angle
from seif_gym.slam.seif import SEIF

__all__ = [
    "EIF",
    "EKF",
    "MotionModel",
    "RangeBearingSensor",
    "SEIF",
    "SlamFilter",
    "UnknownLandmarkError",
    "VelocityMotionModel",
    "wrap_angle",
]
