"""Deprecated alias of :mod:`seif_gym.harness`, the replay harness (removed in the next release).

``import seif_gym.evaluate`` and ``python -m seif_gym.evaluate`` still work
and warn (``DeprecationWarning``); use ``seif_gym.harness`` and
``python -m seif_gym.harness`` (whose ``--episodes-dir`` takes the folders
that ``--episodes`` took here).
"""

import sys
import warnings
from typing import Any

from seif_gym import harness as _harness
from seif_gym.harness import *  # noqa: F403  (the public names of the harness)
from seif_gym.harness import main

warnings.warn(
    "seif_gym.evaluate is deprecated: import seif_gym.harness (python -m seif_gym.harness)",
    DeprecationWarning,
    stacklevel=1 if __name__ == "__main__" else 2,
)


def __getattr__(name: str) -> Any:
    return getattr(_harness, name)


if __name__ == "__main__":
    sys.exit(main())
