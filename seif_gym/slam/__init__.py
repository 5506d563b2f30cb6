"""The SLAM filter library of seif_gym, usable without the environment.

Filters (one interface, :class:`SlamFilter`): :class:`SEIF` (sparse extended
information filter), :class:`EIF` (exact extended information filter),
:class:`EKF` (EKF SLAM) and :class:`ESEIF` (exactly sparse extended
information filter: bounded active set by relocalization, no overconfident
approximation) and :class:`ConservativeSEIF` (sparsification by certified
conservative cuts of the robot's links). Models: :class:`VelocityMotionModel` and
:class:`RangeBearingSensor`.
"""

from typing import Any

from numpy.typing import ArrayLike

from seif_gym.slam.association import AssociationAudit, Associator
from seif_gym.slam.base import InformationForm, SlamFilter, SparseInformationForm, UnknownLandmarkError
from seif_gym.slam.car_model import AckermannLaserModel
from seif_gym.slam.cseif import ConservativeSEIF
from seif_gym.slam.eif import EIF
from seif_gym.slam.ekf import EKF
from seif_gym.slam.eseif import ESEIF
from seif_gym.slam.models import MotionModel, RangeBearingSensor, VelocityMotionModel, wrap_angle
from seif_gym.slam.seif import SEIF

#: Filters by name, for ``make_filter`` and the env's ``filter=`` argument.
FILTERS: dict[str, type[SlamFilter]] = {"seif": SEIF, "eif": EIF, "ekf": EKF, "eseif": ESEIF, "cseif": ConservativeSEIF}


def make_filter(
    name: str,
    motion: MotionModel,
    sensor: RangeBearingSensor,
    initial_pose: ArrayLike,
    initial_pose_cov: ArrayLike | None = None,
    **options: Any,
) -> SlamFilter:
    """Build the filter called ``name`` (a key of :data:`FILTERS`)."""
    if not isinstance(name, str) or name not in FILTERS:
        raise ValueError(f"filter must be one of {tuple(FILTERS)}, got {name!r}")
    return FILTERS[name](motion, sensor, initial_pose, initial_pose_cov, **options)


__all__ = [
    "FILTERS",
    "make_filter",
    "AckermannLaserModel",
    "AssociationAudit",
    "Associator",
    "ConservativeSEIF",
    "EIF",
    "EKF",
    "ESEIF",
    "InformationForm",
    "MotionModel",
    "RangeBearingSensor",
    "SEIF",
    "SlamFilter",
    "SparseInformationForm",
    "UnknownLandmarkError",
    "VelocityMotionModel",
    "wrap_angle",
]
