"""``python -m seif_gym.datasets.mrclam [calibrate | episodes] ...``: the MRCLAM command line.

* ``calibrate ...``: :func:`seif_gym.datasets.mrclam.calibration.main`
  (command correction, motion and sensor noise from the ground truth, to a JSON file);
* ``episodes ...``: :func:`seif_gym.datasets.mrclam.episodes.main`
  (the logs as episodes for ``python -m seif_gym.harness``);
* anything else: the runner, :func:`seif_gym.datasets.mrclam.runner.main`.

Each finds the data through ``--data DIR``, else ``$SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6``.
Exit status 0, or 2 for bad arguments and for data not found or malformed
(one line on stderr naming the file, no traceback).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from seif_gym.datasets.mrclam import calibration, episodes, runner

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Route ``argv`` (default ``sys.argv[1:]``) to a subcommand; returns the exit status."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] == "calibrate":
        return calibration.main(args[1:])
    if args and args[0] == "episodes":
        return episodes.main(args[1:])
    return runner.main(args)


if __name__ == "__main__":
    sys.exit(main())
