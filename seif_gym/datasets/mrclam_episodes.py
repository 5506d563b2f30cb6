"""Deprecated alias of :mod:`seif_gym.datasets.mrclam.episodes` (removed in the next release)."""

import warnings
from typing import Any

from seif_gym.datasets.mrclam import episodes as _module
from seif_gym.datasets.mrclam.episodes import *  # noqa: F403  (the public names of the new module)

warnings.warn(
    "seif_gym.datasets.mrclam_episodes is deprecated: import seif_gym.datasets.mrclam.episodes",
    DeprecationWarning,
    stacklevel=2,
)


def __getattr__(name: str) -> Any:
    return getattr(_module, name)


if __name__ == "__main__":
    import sys

    sys.exit(_module.main())
