"""Where the full-data tests find the real datasets: the folder named by ``SEIF_GYM_DATA``.

Without it (or without the dataset in it) they are skipped, and the skip's
reason says what to set. The synthetic tests beside them write their own
small logs to ``tmp_path`` and always run. The data are never part of the
repository.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from seif_gym.datasets import DATA_ENV


def full_data(relative: str, what: str) -> tuple[Path, pytest.MarkDecorator]:
    """``(path, mark)``: ``$SEIF_GYM_DATA/relative`` and a skip mark for when it is not there."""
    root = os.environ.get(DATA_ENV, "").strip()
    if not root:
        reason = f"{what}: {DATA_ENV} is not set (set it to the folder holding {relative} to run the full-data tests)"
        return Path(relative), pytest.mark.skipif(True, reason=reason)
    path = Path(root) / relative
    return path, pytest.mark.skipif(not path.exists(), reason=f"{what} not found at {path} ({DATA_ENV}={root})")
