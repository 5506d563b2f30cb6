"""Deprecated alias of :mod:`seif_gym.datasets.mrclam.runner` (removed in the next release)."""

import warnings
from typing import Any

from seif_gym.datasets.mrclam import runner as _module
from seif_gym.datasets.mrclam.runner import *  # noqa: F403  (the public names of the new module)

warnings.warn(
    "seif_gym.datasets.mrclam_runner is deprecated: import seif_gym.datasets.mrclam.runner",
    DeprecationWarning,
    stacklevel=2,
)


def __getattr__(name: str) -> Any:
    return getattr(_module, name)


if __name__ == "__main__":
    import sys

    sys.exit(_module.main())
