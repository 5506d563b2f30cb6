"""What the dataset readers share: where the data lie, and how a bad file is reported.

The data are never part of the package. A reader takes the location from an
explicit ``data=`` argument (``--data PATH`` on a command line), else from the
folder named by the environment variable ``SEIF_GYM_DATA`` (holding
``victoria_park/`` and ``mrclam/``), else fails with :class:`DataNotFoundError`
saying how to obtain the data and where to put them. A file that is there but
malformed raises :class:`DataFormatError` naming the file and the line (text)
or the array (``.npz``).
"""

from __future__ import annotations

import os
import sys
import zipfile
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

#: The environment variable naming the folder that holds every dataset (``victoria_park/``, ``mrclam/``).
DATA_ENV = "SEIF_GYM_DATA"

__all__ = ["DATA_ENV", "DataFormatError", "DataNotFoundError", "data_root", "load_npz", "run_cli"]


class DataNotFoundError(FileNotFoundError):
    """A dataset, or one of its files, is not where ``data=`` / ``--data`` or ``SEIF_GYM_DATA`` points."""


class DataFormatError(ValueError):
    """A data file is malformed; the message names the file and the line or the array."""


def data_root() -> Path | None:
    """The folder named by ``SEIF_GYM_DATA`` (relative paths from the current directory), or None when unset."""
    value = os.environ.get(DATA_ENV, "").strip()
    return Path(value) if value else None


def not_found(what: str, where: str, how: str) -> DataNotFoundError:
    """The error of a dataset not found: what was looked for, where, and how to obtain it (one line)."""
    return DataNotFoundError(f"{what} not found: {where}. {how}")


def _reason(error: BaseException, archive: bool) -> str:
    """Why numpy could not read an archive (or one of its arrays), without numpy's advice on ``allow_pickle``."""
    text = str(error)
    if "Object arrays" in text:
        return "it holds Python objects (pickled), which are never loaded"
    if "pickle" in text and archive:  # neither zip nor .npy data: numpy takes it for a pickle
        return "neither a zip archive nor NumPy data (another format, or corrupt); pickles are never loaded"
    if isinstance(error, (zipfile.BadZipFile, EOFError, zlib.error)):
        return "corrupt or truncated"
    return f"corrupt, truncated or not NumPy data ({type(error).__name__})"


def load_npz(path: Path, required: Sequence[str], optional: Sequence[str] = ()) -> dict[str, NDArray]:
    """The arrays ``required`` (and those of ``optional`` present) of the ``.npz`` archive at ``path``.

    Read with ``allow_pickle=False``; every array is read in full here, so a
    corrupt member fails now, not later.

    Raises
    ------
    DataFormatError
        ``path`` is not a readable ``.npz`` archive (corrupt, truncated, a bare
        ``.npy``, pickled data), lacks an array of ``required``, or an array
        cannot be read; the message names ``path`` and the array.
    """
    try:
        archive = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as error:
        raise DataFormatError(f"{path}: not a readable .npz archive: {_reason(error, True)}") from None
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise DataFormatError(f"{path}: a single array (.npy), not a .npz archive of named arrays")
    arrays: dict[str, NDArray] = {}
    with archive:
        missing = [name for name in required if name not in archive.files]
        if missing:
            raise DataFormatError(f"{path} lacks the array(s) {missing}")
        for name in [*required, *(name for name in optional if name in archive.files)]:
            try:
                arrays[name] = archive[name]
            except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as error:
                raise DataFormatError(f"{path}: array {name!r} cannot be read: {_reason(error, False)}") from None
    return arrays


def check_vector(path: Path, name: str, array: NDArray, kind: str, length: int | None = None) -> None:
    """Check that ``array`` (``path``'s array ``name``) is 1-D, of ``kind`` and finite.

    ``kind`` is ``"int"`` (integers) or ``"float"`` (real numbers; integers
    accepted). ``length``, if given, is the length it must have.

    Raises
    ------
    DataFormatError
        Naming ``path`` and ``name``.
    """
    if array.ndim != 1:
        raise DataFormatError(f"{path}: array {name!r} has shape {array.shape}, expected one dimension")
    allowed = "iu" if kind == "int" else "iuf"
    if array.dtype.kind not in allowed:
        expected = "integers" if kind == "int" else "real numbers"
        raise DataFormatError(f"{path}: array {name!r} has dtype {array.dtype}, expected {expected}")
    if length is not None and len(array) != length:
        raise DataFormatError(f"{path}: array {name!r} has shape {array.shape}, expected ({length},)")
    if array.dtype.kind == "f":
        bad = np.flatnonzero(~np.isfinite(array))
        if len(bad):
            raise DataFormatError(f"{path}: array {name!r} has a non-finite value ({array[bad[0]]}) at index {bad[0]}")


def data_lines(path: Path) -> list[tuple[int, str]]:
    """``(line number, text)`` of the data lines of a text table: not blank, not a ``#`` comment."""
    found = []
    with open(path, encoding="utf-8", errors="replace") as file:
        for number, line in enumerate(file, start=1):
            text = line.split("#", 1)[0].strip()
            if text:
                found.append((number, text))
    return found


def run_cli(prog: str, command: Callable[[], int]) -> int:
    """Run a command-line ``command``; a data error becomes one line on stderr and exit status 2.

    :class:`DataNotFoundError` and :class:`DataFormatError` are the user's to
    fix (a path, a file): they are printed as ``prog: error: message``, not as
    a traceback. Any other exception propagates.
    """
    try:
        return command()
    except (DataNotFoundError, DataFormatError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
