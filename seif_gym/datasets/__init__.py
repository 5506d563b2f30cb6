"""Real-world datasets for the filters of :mod:`seif_gym.slam`.

* :mod:`seif_gym.datasets.victoria_park`: the ACFR Victoria Park car dataset
  (loader, and a runner: ``python -m seif_gym.datasets.victoria_park``).
* :mod:`seif_gym.datasets.mrclam`: the UTIAS MRCLAM multi-robot dataset
  (loader of the original text files, with Vicon ground truth and a surveyed map).

The data are not part of the package: every function takes the path of a
copy (``shared/data/victoria_park`` and ``shared/data/mrclam`` in this project).
"""

__all__ = ["mrclam", "victoria_park"]
