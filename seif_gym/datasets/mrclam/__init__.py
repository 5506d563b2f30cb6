"""The UTIAS MRCLAM dataset (Leung et al., IJRR 2011): loader, calibration, episodes and runner.

* :mod:`~seif_gym.datasets.mrclam.loader` (re-exported here): :func:`load`,
  :func:`load_all` read the original text files of one dataset folder.
* :mod:`~seif_gym.datasets.mrclam.calibration`: the robots' command
  correction, motion and sensor noise from the Vicon ground truth
  (:data:`~seif_gym.datasets.mrclam.calibration.DATASET6` is the shipped
  calibration of Dataset 6).
* :mod:`~seif_gym.datasets.mrclam.episodes`: logs as
  :class:`~seif_gym.episodes.Episode` objects for the replay harness.
* :mod:`~seif_gym.datasets.mrclam.runner`: a filter over the logs, scored
  against Vicon and the survey.
* ``python -m seif_gym.datasets.mrclam [calibrate | episodes] ...``: the
  command line (:mod:`seif_gym.datasets.mrclam.__main__`).

The data are found through ``data=`` (``--data``) or ``SEIF_GYM_DATA``
(:func:`locate`); ``docs/data/mrclam.md`` says where to obtain them.
"""

from seif_gym.datasets.mrclam.loader import (
    BARCODES_FILE,
    DEFAULT_DATASET,
    LANDMARKS_FILE,
    ROBOTS,
    GroundTruth,
    Landmarks,
    Measurements,
    MrclamLog,
    Odometry,
    load,
    load_all,
    locate,
)

__all__ = [
    "BARCODES_FILE", "DEFAULT_DATASET", "LANDMARKS_FILE", "ROBOTS", "GroundTruth", "Landmarks", "Measurements",
    "MrclamLog", "Odometry", "load", "load_all", "locate",
]  # fmt: skip
