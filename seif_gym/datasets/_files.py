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
import struct
import sys
import zipfile
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from seif_gym._atomic import atomic_write

#: The environment variable naming the folder that holds every dataset (``victoria_park/``, ``mrclam/``).
DATA_ENV = "SEIF_GYM_DATA"

__all__ = [
    "DATA_ENV",
    "DataFormatError",
    "DataNotFoundError",
    "OutputPathError",
    "data_root",
    "load_npz",
    "output_file",
    "run_cli",
    "save_figure",
    "save_npz",
]


class DataNotFoundError(FileNotFoundError):
    """A dataset, or one of its files, is not where ``data=`` / ``--data`` or ``SEIF_GYM_DATA`` points."""


class DataFormatError(ValueError):
    """A data file is malformed; the message names the file and the line or the array."""


class OutputPathError(ValueError):
    """An output file cannot be written where asked (its folder is a file, or not writable)."""


def data_root() -> Path | None:
    """The folder named by ``SEIF_GYM_DATA`` (relative paths from the current directory), or None when unset."""
    value = os.environ.get(DATA_ENV, "").strip()
    return Path(value) if value else None


def not_found(what: str, where: str, how: str) -> DataNotFoundError:
    """The error of a dataset not found: what was looked for, where, and how to obtain it (one line)."""
    return DataNotFoundError(f"{what} not found: {where}. {how}")


#: What numpy and zipfile raise on a damaged archive: truncated, bytes flipped (in the data or the zip
#: directory: a bogus version, size or name), or not a zip at all.
NPZ_ERRORS: tuple[type[BaseException], ...] = (
    ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, struct.error, KeyError,
    IndexError, OverflowError,
)  # fmt: skip


def npz_problem(error: BaseException, archive: bool = True) -> str:
    """Why numpy could not read an archive (``archive``) or one of its arrays, without its advice on ``allow_pickle``."""
    text = str(error)
    if "Object arrays" in text:
        return "it holds Python objects (pickled), which are never loaded"
    if "pickle" in text and archive:  # neither zip nor .npy data: numpy takes it for a pickle
        return "neither a zip archive nor NumPy data (another format, or corrupt); pickles are never loaded"
    if isinstance(error, (zipfile.BadZipFile, EOFError, zlib.error, NotImplementedError, struct.error)):
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
    except NPZ_ERRORS as error:
        raise DataFormatError(f"{path}: not a readable .npz archive: {npz_problem(error, True)}") from None
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
            except NPZ_ERRORS as error:
                raise DataFormatError(f"{path}: array {name!r} cannot be read: {npz_problem(error, False)}") from None
    return arrays


def npz_path(path: str | os.PathLike[str]) -> Path:
    """``path``, with ``.npz`` appended when it has another suffix (where ``np.savez`` writes)."""
    path = Path(path)
    return path if path.suffix == ".npz" else path.with_name(path.name + ".npz")


def _not_a_folder(folder: Path) -> Path | None:
    """The first of ``folder`` and its ancestors that exists as something other than a folder, if any."""
    for candidate in (folder, *folder.parents):
        if candidate.exists():
            return None if candidate.is_dir() else candidate
    return None


def output_file(path: str | os.PathLike[str], option: str) -> Path:
    """``path`` as an output file whose folder exists (made here) and is writable, else :class:`OutputPathError`.

    ``option`` names the argument in the message (``--out``). Checked before a command's work starts.
    """
    target = Path(path)
    folder = target.parent
    blocker = _not_a_folder(folder)
    if blocker is not None:
        raise OutputPathError(f"{option} {target}: {blocker} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputPathError(
            f"{option} {target}: cannot make its folder {folder} ({error.strerror or error})"
        ) from None
    if target.is_dir():
        raise OutputPathError(f"{option} {target}: is a folder, expected a file name")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"{option} {target}: its folder {folder} is not writable")
    return target


def output_folder(path: str | os.PathLike[str], option: str) -> Path:
    """``path`` as an output folder that exists (made here) and is writable, else :class:`OutputPathError`."""
    folder = Path(path)
    blocker = _not_a_folder(folder)
    if blocker is not None:
        raise OutputPathError(f"{option} {folder}: {blocker} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputPathError(f"{option} {folder}: cannot make the folder ({error.strerror or error})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"{option} {folder}: the folder is not writable")
    return folder


def save_npz(path: str | os.PathLike[str], arrays: dict[str, Any]) -> Path:
    """``np.savez_compressed`` whole or not at all (:func:`seif_gym._atomic.atomic_write`); returns the file written.

    ``.npz`` is appended to ``path`` when missing, as numpy does.
    """
    target = npz_path(path)

    def write(temporary: Path) -> None:
        with open(temporary, "wb") as handle:
            np.savez_compressed(handle, **arrays)

    return atomic_write(target, write)


def save_figure(figure: Any, path: str | os.PathLike[str], **savefig: Any) -> Path:
    """``figure.savefig`` whole or not at all, in the format of ``path``'s suffix (PNG when it has none)."""
    target = Path(path)
    kind = target.suffix.lstrip(".").lower() or "png"
    return atomic_write(target, lambda temporary: figure.savefig(temporary, format=kind, **savefig))


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

    :class:`DataNotFoundError`, :class:`DataFormatError` and :class:`OutputPathError`
    are the user's to fix (a path, a file): they are printed as ``prog: error: message``, not as
    a traceback. Any other exception propagates.
    """
    try:
        return command()
    except (DataNotFoundError, DataFormatError, OutputPathError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
