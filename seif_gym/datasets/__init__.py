"""Real-world datasets for the filters of :mod:`seif_gym.slam`.

* :mod:`seif_gym.datasets.victoria_park`: the ACFR Victoria Park car dataset
  (loader, and a runner: ``python -m seif_gym.datasets.victoria_park``).

The data are not part of the package: every function takes the path of a
copy (``shared/data/victoria_park`` in this project).
"""

__all__ = ["victoria_park"]
