"""Real-world datasets for the filters of :mod:`seif_gym.slam`.

* :mod:`seif_gym.datasets.victoria_park`: the ACFR Victoria Park car dataset
  (loader, GPS ground truth, and a runner: ``python -m seif_gym.datasets.victoria_park``).
* :mod:`seif_gym.datasets.mrclam`: the UTIAS MRCLAM multi-robot dataset
  (loader of the original text files, calibration, episodes for the replay
  harness, and a runner: ``python -m seif_gym.datasets.mrclam``).

The data are not part of the package. Every reader takes the location from an
explicit ``data=`` argument (``--data PATH`` on a command line), else from the
folder named by the environment variable ``SEIF_GYM_DATA``, which holds::

    $SEIF_GYM_DATA/
        victoria_park/victoria_park.npz
        mrclam/MRCLAM_Dataset6/Barcodes.dat, Landmark_Groundtruth.dat, RobotN_*.dat

and otherwise raises :class:`DataNotFoundError` (a ``FileNotFoundError``)
saying how to obtain the data and where to put them. A malformed file raises
:class:`DataFormatError` (a ``ValueError``) naming the file and the line or
the array.
"""

from seif_gym.datasets._files import DATA_ENV, DataFormatError, DataNotFoundError, data_root

__all__ = ["DATA_ENV", "DataFormatError", "DataNotFoundError", "data_root", "mrclam", "victoria_park"]
