"""A run's finished work kept as it finishes, and the manifest that marks a run folder finished.

The long commands (``agents.evaluate``, ``agents.benchmark``, ``agents.robustness``) cut their work into
*units* (an agent's run of seeds, an agent × layout's episodes: the tasks of
:meth:`agents.parallel.Executor.map`). A :class:`RunJournal` keeps each finished unit's result in the
run folder as it arrives (``OUT/.journal/units/<hash>.json``, written whole or not at all by
:mod:`seif_gym._atomic`), beside the run's configuration (``OUT/.journal/config.json``). A run killed at
any moment and started again with ``--resume OUT`` and the same configuration runs only the units
that are not in the journal, and its outputs equal those of a run that was never interrupted.

A run's outputs are written whole or not at all, and ``manifest.json`` last (:func:`write_manifest`:
every file's SHA-256, the command, the configuration and the version). So a folder holds a finished
run exactly when it holds a manifest (:func:`read_manifest`); a reader of run folders
(``--stored-run``, :func:`agents.evaluate.read_run`) refuses the others.

>>> import tempfile
>>> from pathlib import Path
>>> folder = Path(tempfile.mkdtemp())
>>> journal = RunJournal.start(folder, "demo", {"episodes": 2})
>>> journal.record({"agent": "frontier", "seeds": [0, 1]}, [[0.5, 1.25], None])
>>> RunJournal.start(folder, "demo", {"episodes": 2}, resume=True).units()
[({'agent': 'frontier', 'seeds': [0, 1]}, [[0.5, 1.25], None])]
>>> RunJournal.start(folder, "demo", {"episodes": 3}, resume=True)  # doctest: +ELLIPSIS
Traceback (most recent call last):
    ...
agents.evaluate.journal.ResumeError: --resume: ... was run with another configuration (episodes: 2 there, 3 here)
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import seif_gym
from seif_gym._atomic import atomic_write_json, remove_temporaries

__all__ = [
    "JOURNAL",
    "MANIFEST",
    "ResumeError",
    "RunFinished",
    "RunJournal",
    "UnfinishedRunError",
    "file_digest",
    "journal_for_command_line",
    "finished_with",
    "forget_manifest",
    "read_manifest",
    "verify_manifest",
    "write_manifest",
]

#: The journal's folder inside a run folder.
JOURNAL = ".journal"
#: The file in the journal that names the process writing it (``{"host": ..., "pid": ...}``).
OWNER = "owner.json"
#: The file written last into a finished run folder.
MANIFEST = "manifest.json"
#: Version of the journal's and the manifest's format.
FORMAT_VERSION = 1


class ResumeError(ValueError):
    """``--resume`` cannot continue the folder it names: no run there, or a run of another configuration."""


class RunFinished(Exception):
    """``--resume`` of a run that finished: nothing to do (the message says where its outputs are)."""


class UnfinishedRunError(ValueError):
    """A run folder without its manifest: the run was killed before its end (or is still running)."""


# -- values in JSON, numpy's included, exactly ---------------------------------------------------------
def _encode(value: Any) -> Any:
    """``value`` as JSON-able data from which :func:`_decode` rebuilds it bit for bit (tuples become lists)."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biufU":
            raise TypeError(f"cannot keep an array of dtype {value.dtype} in a journal")
        return {"__ndarray__": value.dtype.str, "shape": list(value.shape), "data": value.ravel().tolist()}
    if isinstance(value, np.generic):
        return {"__numpy__": value.dtype.str, "value": value.item()}
    if isinstance(value, Mapping):
        if not all(isinstance(key, str) for key in value):
            raise TypeError("cannot keep a mapping with keys other than str in a journal")
        return {key: _encode(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode(item) for item in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"cannot keep a {type(value).__name__} in a journal")


def _decode(value: Any) -> Any:
    if isinstance(value, dict):
        if "__ndarray__" in value:
            return np.asarray(value["data"], dtype=np.dtype(value["__ndarray__"])).reshape(value["shape"])
        if "__numpy__" in value:
            return np.dtype(value["__numpy__"]).type(value["value"])
        return {key: _decode(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_decode(item) for item in value]
    return value


def _canonical(value: Any) -> Any:
    """``value`` as JSON gives it back (tuples as lists, paths as str), for comparing configurations."""
    return json.loads(json.dumps(value, default=str))


def _differences(found: Mapping[str, Any], expected: Mapping[str, Any]) -> list[str]:
    """``key: A there, B here`` for every key whose values differ."""
    out = []
    for key in sorted(set(found) | set(expected)):
        if found.get(key) != expected.get(key):
            out.append(f"{key}: {_short(found.get(key))} there, {_short(expected.get(key))} here")
    return out


def _short(value: Any, width: int = 60) -> str:
    text = json.dumps(value, default=str)
    return text if len(text) <= width else text[: width - 3] + "..."


# -- the journal -----------------------------------------------------------------------------------------
class RunJournal:
    """The finished units of one run, kept in ``folder/.journal`` as they finish.

    Build it with :meth:`start`. Each unit is named by a key (a JSON-able mapping: what the unit
    computes) and holds a result of JSON data, numpy arrays and scalars (:meth:`record`); a unit
    written again replaces itself.

    Parameters
    ----------
    folder : Path
        The run folder.
    command : str
        The command whose run this is (``agents.evaluate``).
    config : mapping
        What the outputs depend on (not how they are computed: not the executor).
    """

    def __init__(self, folder: Path, command: str, config: Mapping[str, Any]) -> None:
        self.folder = Path(folder)
        self.command = str(command)
        self.config = _canonical(dict(config))
        #: Units of an unfinished earlier run that a new run (:meth:`start` without ``resume``) forgot.
        self.discarded = 0

    @property
    def path(self) -> Path:
        """``folder/.journal``."""
        return self.folder / JOURNAL

    @classmethod
    def start(cls, folder: str | os.PathLike, command: str, config: Mapping[str, Any], *,
              resume: bool = False) -> RunJournal:  # fmt: skip
        """The journal of a run in ``folder``: a new one, or (``resume``) the one a killed run left there.

        A new run forgets what ``folder`` held of an earlier run of the command (its journal, its
        manifest: the folder reads as unfinished until the new run writes its own) and records
        ``config``. A resumed one keeps the units of the journal, whose configuration must equal
        ``config``, and clears the temporary files a kill left (:func:`seif_gym._atomic.remove_temporaries`).

        Parameters
        ----------
        folder : str or PathLike
            The run folder (created if missing).
        command, config
            As :class:`RunJournal` takes them.
        resume : bool
            Continue the run of ``folder``.

        Returns
        -------
        RunJournal

        Raises
        ------
        ResumeError
            With ``resume``: ``folder`` holds no run of ``command``, or one of another configuration.
        RunFinished
            With ``resume``: the run of ``folder`` finished (its manifest is there).

        Notes
        -----
        A run still going on in ``folder`` (its process, on this machine, alive) is refused with a
        :class:`ResumeError` either way: two runs never write one folder.
        """
        journal = cls(Path(folder), command, config)
        journal._check_not_running()
        if resume:
            journal._check_resumable()
            remove_temporaries(journal.folder)
            (journal.path / "units").mkdir(parents=True, exist_ok=True)
        else:
            journal.folder.mkdir(parents=True, exist_ok=True)
            forget_manifest(journal.folder)
            if journal.path.exists():
                journal.discarded = len(list((journal.path / "units").glob("*.json")))
                shutil.rmtree(journal.path)
            (journal.path / "units").mkdir(parents=True)
            atomic_write_json(journal.path / "config.json", journal._header(), indent=2, sort_keys=True)
        atomic_write_json(journal.path / OWNER, {"host": socket.gethostname(), "pid": os.getpid()})
        return journal

    def _check_not_running(self) -> None:
        """Refuse a folder whose journal belongs to a process of this machine that is still alive."""
        try:
            owner = json.loads((self.path / OWNER).read_text())
            host, pid = owner["host"], int(owner["pid"])
        except (OSError, ValueError, KeyError, TypeError):
            return  # no run there, or one that never got so far
        if host != socket.gethostname() or pid == os.getpid():
            return
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return  # killed: its journal is free
        except PermissionError:
            pass  # alive, another user's
        raise ResumeError(f"--out: {self.folder} is being written by a run still going on (process {pid}); "
                          "wait for it or end it first")  # fmt: skip

    def _header(self) -> dict[str, Any]:
        return {"format_version": FORMAT_VERSION, "command": self.command, "seif_gym": seif_gym.__version__,
                "config": self.config}  # fmt: skip

    def _check_resumable(self) -> None:
        folder = self.folder
        manifest = folder / MANIFEST
        if manifest.is_file():
            header = _read_json(manifest, ResumeError)
            self._check_same(header, manifest)
            raise RunFinished(f"{folder} holds a finished run of {self.command} ({manifest.name} is there): "
                              "nothing to resume")  # fmt: skip
        config_path = self.path / "config.json"
        if not config_path.is_file():
            raise ResumeError(f"--resume: {folder} holds no run of {self.command} to resume (no {JOURNAL}/config.json)")
        self._check_same(_read_json(config_path, ResumeError), config_path)

    def _check_same(self, header: Any, path: Path) -> None:
        if not isinstance(header, dict) or header.get("command") != self.command:
            found = header.get("command") if isinstance(header, dict) else None
            raise ResumeError(f"--resume: {path} is of a run of {found!r}, not of {self.command}")
        if header.get("seif_gym") != seif_gym.__version__:
            raise ResumeError(f"--resume: {self.folder} was run by seif_gym {header.get('seif_gym')}, "
                              f"this is {seif_gym.__version__}: start it afresh")  # fmt: skip
        found = header.get("config")
        if found != self.config:
            changed = _differences(found if isinstance(found, dict) else {}, self.config)
            raise ResumeError(f"--resume: {self.folder} was run with another configuration ({'; '.join(changed)})")

    @staticmethod
    def _name(key: Mapping[str, Any]) -> str:
        text = json.dumps(_canonical(dict(key)), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:32] + ".json"

    def record(self, key: Mapping[str, Any], result: Any) -> None:
        """Keep ``result``, the finished unit ``key``'s, whole or not at all.

        Raises
        ------
        TypeError
            If ``result`` holds something other than JSON data, numpy arrays of numbers or strings
            and numpy scalars.
        """
        content = {"key": _canonical(dict(key)), "result": _encode(result)}
        atomic_write_json(self.path / "units" / self._name(key), content, allow_nan=True)

    def units(self) -> list[tuple[dict[str, Any], Any]]:
        """Every unit kept, ``(key, result)``, in the order of their keys' names."""
        out = []
        for path in sorted((self.path / "units").glob("*.json")):
            content = _read_json(path, ValueError)
            out.append((content["key"], _decode(content["result"])))
        return out

    def finish(self) -> None:
        """Delete the journal: the run's outputs and manifest are written (call after :func:`write_manifest`)."""
        shutil.rmtree(self.path, ignore_errors=True)


def _read_json(path: Path, error: type[Exception]) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as problem:
        raise error(f"{path} does not read as JSON ({problem})") from problem


# -- the manifest ------------------------------------------------------------------------------------------
def file_digest(path: str | os.PathLike) -> str:
    """The SHA-256 of the file at ``path``, in hexadecimal."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def finished_with(folder: str | os.PathLike, command: str, config: Mapping[str, Any]) -> bool:
    """Whether ``folder`` holds a finished run of ``command`` with ``config`` (its manifest says so), by this version."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        return False
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return (isinstance(manifest, dict) and manifest.get("command") == command
            and manifest.get("seif_gym") == seif_gym.__version__
            and manifest.get("config") == _canonical(dict(config)))  # fmt: skip


def forget_manifest(folder: str | os.PathLike) -> None:
    """Delete ``folder``'s manifest, before a run writes anything there: the folder reads as unfinished."""
    (Path(folder) / MANIFEST).unlink(missing_ok=True)


def write_manifest(folder: str | os.PathLike, files: Sequence[str | os.PathLike], command: str,
                   config: Mapping[str, Any]) -> Path:  # fmt: skip
    """Write ``folder/manifest.json``, last: ``files`` (paths inside ``folder``) with their SHA-256.

    Parameters
    ----------
    folder : str or PathLike
        The run folder.
    files : sequence of path
        The run's outputs, written and complete.
    command : str
        The command that wrote them.
    config : mapping
        The run's configuration (JSON data).

    Returns
    -------
    Path
        The manifest.

    Raises
    ------
    ValueError
        If a file is not inside ``folder`` or ``config`` holds a number JSON refuses (``nan``).
    FileNotFoundError
        If a file does not exist.
    """
    root = Path(folder)
    listed: dict[str, str] = {}
    for file in files:
        path = Path(file)
        path = path if path.exists() else root / path
        try:
            name = path.resolve().relative_to(root.resolve()).as_posix()
        except ValueError:
            raise ValueError(f"files: {path} is not inside {root}") from None
        listed[name] = file_digest(path)
    content = {"format_version": FORMAT_VERSION, "command": str(command), "seif_gym": seif_gym.__version__,
               "config": _canonical(dict(config)), "files": dict(sorted(listed.items()))}  # fmt: skip
    return atomic_write_json(root / MANIFEST, content, indent=2, sort_keys=True, allow_nan=False)


def read_manifest(folder: str | os.PathLike, name: str = "folder") -> dict[str, Any]:
    """The manifest of the finished run in ``folder``.

    Parameters
    ----------
    folder : str or PathLike
        A run folder.
    name : str
        What the folder is to the caller, the start of the error message.

    Raises
    ------
    UnfinishedRunError
        If ``folder`` holds no manifest (a run killed before its end, still running, or written before
        seif_gym wrote manifests), or one that does not read or lists a file that is not there.
    """
    path = Path(folder) / MANIFEST
    if not path.is_file():
        running = " (its .journal is there: finish it with --resume)" if (Path(folder) / JOURNAL).is_dir() else ""
        raise UnfinishedRunError(f"{name}: {folder} is not a finished run: no {MANIFEST}, which a run writes "
                                 f"last{running}")  # fmt: skip
    try:
        manifest = json.loads(path.read_text())
        files = dict(manifest["files"])
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as error:
        raise UnfinishedRunError(f"{name}: {path} is not a manifest of seif_gym ({error})") from error
    missing = [file for file in files if not (Path(folder) / file).is_file()]
    if missing:
        raise UnfinishedRunError(f"{name}: {folder} lacks {', '.join(missing)}, which its {MANIFEST} lists")
    return dict(manifest)


def verify_manifest(folder: str | os.PathLike, name: str = "folder") -> dict[str, Any]:
    """:func:`read_manifest`, and every listed file's SHA-256 checked.

    Raises
    ------
    UnfinishedRunError
        As :func:`read_manifest`.
    ValueError
        If a file changed since the manifest was written (its SHA-256 differs).
    """
    manifest = read_manifest(folder, name)
    changed = [file for file, digest in manifest["files"].items() if file_digest(Path(folder) / file) != digest]
    if changed:
        raise ValueError(f"{name}: {', '.join(changed)} in {folder} changed after its {MANIFEST} was written")
    return manifest


def journal_for_command_line(parser: Any, folder: str | os.PathLike, command: str, config: Mapping[str, Any],
                             resume: bool) -> RunJournal | None:  # fmt: skip
    """:meth:`RunJournal.start` for a command's ``main``: ``None`` (after printing why) for a finished run.

    A ``--resume`` that names no run of this configuration is a usage error: ``parser`` exits with
    status 2 and one line.
    """
    try:
        return RunJournal.start(folder, command, config, resume=resume)
    except RunFinished as finished:
        print(finished)
        return None
    except ResumeError as error:
        parser.exit(2, f"{parser.prog}: error: {error}\n")
        raise  # pragma: no cover - parser.exit exits
