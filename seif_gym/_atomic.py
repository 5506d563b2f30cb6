"""Files written whole or not at all: the one home of the atomic writers every command uses.

A process killed at any moment leaves either the previous file or the new one, never a part of it
(a leftover ``.NAME.PID.tmp`` beside it at most, which :func:`remove_temporaries` clears). The
temporary file sits in the target's folder, so the final :func:`os.replace` stays on one file system.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_json", "atomic_write_text", "remove_temporaries"]


def atomic_write(path: str | os.PathLike, write: Callable[[Path], Any]) -> Path:
    """Write a file whole or not at all: ``write(temporary)`` fills a file beside ``path``, then it replaces ``path``.

    The temporary file (``.NAME.PID.tmp`` in the same folder) is flushed to disk before
    :func:`os.replace` puts it in place.

    Parameters
    ----------
    path : str or PathLike
        The file to write; its folder must exist.
    write : callable
        ``write(temporary: Path)`` writes the whole content to ``temporary``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    TypeError
        If ``path`` is not a path or ``write`` not callable.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a path, got {type(path).__name__}")
    if not callable(write):
        raise TypeError(f"write must be callable, got {type(write).__name__}")
    target = Path(path)
    temporary = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        write(temporary)
        with open(temporary, "rb") as handle:
            os.fsync(handle.fileno())
        os.replace(temporary, target)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return target


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole or not at all (:func:`atomic_write`)."""
    return atomic_write(path, lambda temporary: temporary.write_bytes(data))


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` whole or not at all (:func:`atomic_write`)."""
    return atomic_write(path, lambda temporary: temporary.write_text(text, encoding=encoding))


def atomic_write_json(path: str | os.PathLike, value: Any, **dumps: Any) -> Path:
    """Write ``json.dumps(value, **dumps)`` to ``path`` whole or not at all; a value JSON refuses raises before any file is touched."""
    return atomic_write_text(path, json.dumps(value, **dumps))


def remove_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Delete the temporary files :func:`atomic_write` left in ``folder`` and its subfolders when killed; those removed."""
    removed = []
    for temporary in Path(folder).rglob(".*.tmp"):
        if temporary.is_file():
            temporary.unlink()
            removed.append(temporary)
    return removed
