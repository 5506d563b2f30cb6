"""What the command lines of :mod:`agents` share: argument types, the names of tasks and agents, their help.

One vocabulary for every command (``agents.evaluate``, ``agents.benchmark``,
``agents.showcase``, ``agents.robustness``, ``agents.train``):

- a *task* is a registered env id (``--env ID``; ``--tasks ID,...`` where a
  command runs several). A *family*, an id without its version
  (``SeifExploreLoop``), stands for its newest version (:func:`resolve_task`);
- a *layout* is the arrangement of the landmarks (the env's ``layout``
  keyword, :data:`seif_gym.world.LAYOUTS`);
- ``--episodes N`` is a count of episodes, ``--seed S`` the first seed;
- an *agent* is a baseline name, a shipped policy's name, the path of a saved
  model (``PATH.zip``) or ``rllib:CHECKPOINT``, any of them labelled
  ``LABEL=SPEC`` (:func:`agents.loading.load_agent`);
- ``--out DIR`` is the output folder, ``--resume DIR`` the folder of a killed
  run to continue (:func:`add_resume_argument`, :func:`resume_folder`).

Every command checks its input before any episode runs and before it writes
anything (:func:`usage_errors` turns each failed check into ``argparse``'s
usage error: exit status 2 and one line naming the option or the file):
counts and seeds by their types (:func:`positive_int`, :func:`non_negative_int`,
:func:`seed`), every agent and saved model opened (:func:`check_agents`),
the output folder writable (:func:`check_out`), the env made once with its
arguments (:func:`check_env`).

>>> import argparse
>>> parser = argparse.ArgumentParser()
>>> _ = parser.add_argument("--env-kwargs", type=json_object, default="{}")
>>> parser.parse_args(["--env-kwargs", '{"layout": "loop"}']).env_kwargs
{'layout': 'loop'}
>>> parser.parse_args([]).env_kwargs
{}
>>> resolve_task("SeifExploreLoop-v1"), resolve_task("SeifExploreMRCLAM"), resolve_task("SeifExplore", version=0)
('SeifExploreLoop-v1', 'SeifExploreMRCLAM-v1', 'SeifExplore-v0')
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import textwrap
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym

import seif_gym
from agents.baselines import BASELINES
from agents.loading import SHIPPED_POLICIES, agent_labels, check_agent_spec

__all__ = [
    "add_deprecated_alias",
    "add_resume_argument",
    "agents_help",
    "check_agents",
    "check_env",
    "check_out",
    "check_seeds",
    "json_object",
    "model_digests",
    "non_negative_int",
    "positive_int",
    "resume_folder",
    "seed",
    "usage_errors",
    "resolve_task",
    "resolve_tasks",
    "task",
    "task_families",
    "tasks_epilog",
    "tasks_help",
]


def json_object(text: str) -> dict[str, Any]:
    """An ``argparse`` type: ``text`` read as a JSON object (a usage error naming the option otherwise)."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"not valid JSON: {error}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return value


def task_families() -> dict[str, tuple[int, ...]]:
    """Every task family of :data:`seif_gym.VARIANTS` and its registered versions, in registration order.

    Returns
    -------
    dict
        Family (``SeifExploreLoop``) -> versions, ascending (``(0, 1, 2)``).
    """
    families: dict[str, list[int]] = {}
    for env_id in seif_gym.VARIANTS:
        family, _, version = env_id.rpartition("-v")
        families.setdefault(family, []).append(int(version))
    return {family: tuple(sorted(versions)) for family, versions in families.items()}


def resolve_task(env_id: str, version: int | None = None) -> str:
    """The registered env id that ``env_id`` names.

    Parameters
    ----------
    env_id : str
        A registered env id (returned as it is), or a family of :func:`task_families`.
    version : int, optional
        The version a family stands for; default its newest. Ignored for an env id.

    Returns
    -------
    str
        A registered env id.

    Raises
    ------
    TypeError
        If ``env_id`` is not a string.
    ValueError
        If ``env_id`` is neither registered nor a family, or the family has no ``version``.
    """
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be a str, got {type(env_id).__name__}")
    if env_id in gym.registry:
        return env_id
    families = task_families()
    if env_id not in families:
        raise ValueError(f"env_id: unknown env {env_id!r} (tasks: {tasks_help()})")
    versions = families[env_id]
    if version is None:
        return f"{env_id}-v{versions[-1]}"
    if version not in versions:
        raise ValueError(f"env_id: {env_id} has no version {version!r} (versions {', '.join(map(str, versions))})")
    return f"{env_id}-v{version}"


def resolve_tasks(names: Sequence[str], version: int | None = None) -> list[str]:
    """:func:`resolve_task` of every name, each env id once, in the order given.

    Raises
    ------
    TypeError, ValueError
        As :func:`resolve_task`.
    """
    resolved: list[str] = []
    for name in names:
        env_id = resolve_task(name, version)
        if env_id not in resolved:
            resolved.append(env_id)
    return resolved


def task(text: str) -> str:
    """An ``argparse`` type: :func:`resolve_task` of ``text`` (a usage error naming the option otherwise)."""
    try:
        return resolve_task(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def tasks_help() -> str:
    """The registered tasks in a line: each family with its versions (``SeifExplore-v0/v1/v2, ...``)."""
    return ", ".join(
        f"{family}-" + "/".join(f"v{version}" for version in versions) for family, versions in task_families().items()
    )


def tasks_epilog(option: str = "--env") -> str:
    """The registered tasks as a block of an ``argparse`` epilog, headed by the ``option`` that takes them."""
    return f"tasks ({option}; a family alone stands for its newest version):\n" + _wrap(tasks_help(), "  ")


def _wrap(text: str, first: str, indent: int | None = None) -> str:
    """``text`` in lines of at most 100 characters, the first after ``first``, the others indented alike."""
    rest = " " * (len(first) if indent is None else indent)
    return textwrap.fill(text, 100, initial_indent=first, subsequent_indent=rest, break_on_hyphens=False)


def agents_help(paths: bool = True) -> str:
    """The agent specs a command takes, as lines for an ``argparse`` epilog.

    Parameters
    ----------
    paths : bool
        Whether saved models (``PATH.zip``) and ``rllib:CHECKPOINT`` are listed too.
    """
    lines = [
        "agents (comma-separated; any of them LABEL=SPEC to name it in the outputs):",
        _wrap(", ".join(BASELINES), "  baselines          "),
        _wrap(", ".join(SHIPPED_POLICIES), "  shipped policies   "),
    ]
    if paths:
        lines += [
            "  PATH.zip           a saved Stable-Baselines3 / sb3-contrib model (PPO, RecurrentPPO, SAC)",
            "  rllib:CHECKPOINT   an RLlib checkpoint of python -m agents.rllib_train (the ray extra)",
        ]
    return "\n".join(lines)


class _DeprecatedAlias(argparse.Action):
    """Stores like the option it stands for, with a ``FutureWarning`` naming the new spelling."""

    def __init__(self, *args: Any, new: str, **kwargs: Any) -> None:
        self.new = new
        super().__init__(*args, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:  # fmt: skip
        # FutureWarning, not DeprecationWarning: Python shows it to the command's user by default
        warnings.warn(f"{option_string} is deprecated: use {self.new}", FutureWarning, stacklevel=2)
        setattr(namespace, self.dest, values)


def add_deprecated_alias(parser: argparse.ArgumentParser, old: str, new: str, **kwargs: Any) -> None:
    """Add ``old`` as a hidden, deprecated spelling of the option ``new`` of ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        Already holds ``new``.
    old, new : str
        The option strings (``--seeds``, ``--episodes``).
    **kwargs
        Passed to ``add_argument`` (``type=``, ``metavar=``); ``dest`` is ``new``'s.

    Raises
    ------
    ValueError
        If ``parser`` has no option ``new``.
    """
    actions = [action for action in parser._actions if new in action.option_strings]
    if not actions:
        raise ValueError(f"new: the parser has no option {new!r}")
    parser.add_argument(old, dest=actions[0].dest, action=_DeprecatedAlias, new=new, help=argparse.SUPPRESS, **kwargs)


# -- early checks: every input answered before any work starts ---------------------------------------------
def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None


def positive_int(text: str) -> int:
    """An ``argparse`` type: a positive integer (a count of episodes, steps, threads)."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """An ``argparse`` type: an integer of at least 0 (resamples of a bootstrap)."""
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {value}")
    return value


#: The largest seed: ``env.reset(seed=s)`` seeds numpy's generators, which take seeds below 2**63 here.
MAX_SEED = 2**63 - 1


def seed(text: str) -> int:
    """An ``argparse`` type: a seed of ``env.reset`` (an integer in ``0 … 2**63 − 1``)."""
    value = _integer(text)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"a seed is an integer from 0 to 2**63 - 1, got {value}")
    return value


def check_seeds(first: int, episodes: int, option: str = "--seed") -> list[int]:
    """The seeds ``first … first + episodes − 1``, all of them seeds (:func:`seed`).

    Raises
    ------
    ValueError
        If the last one passes :data:`MAX_SEED` (or ``first`` is negative, ``episodes`` not positive).
    """
    if first < 0 or episodes < 1 or first + episodes - 1 > MAX_SEED:
        raise ValueError(f"{option}: the seeds {first}..{first + episodes - 1} are not all in 0..2**63 - 1")
    return list(range(first, first + episodes))


def check_out(path: str | os.PathLike, option: str = "--out") -> Path:
    """``path`` as a folder a command can write into, without creating it (nothing is written).

    Parameters
    ----------
    path : str or PathLike
        The output folder: an existing folder, or a path whose nearest existing parent is a folder.
    option : str
        The option that named it, the start of the message.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        If ``path`` is a file, lies under a file, or its nearest existing folder is not writable.
    """
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{option}: {folder} is a file, not a folder")
    existing = folder
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        raise ValueError(f"{option}: {folder} lies under {existing}, which is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{option}: {existing} is not writable")
    return folder


def check_agents(specs: Sequence[str], option: str = "--agents") -> list[tuple[str, str]]:
    """The ``(label, target)`` of every agent spec, each checked and every saved model opened.

    Raises
    ------
    ValueError
        If a spec is empty or unknown, or a saved model is not a whole one
        (:func:`agents.loading.check_model_file`: the message names the file), prefixed by ``option``.
    FileNotFoundError
        If a saved model or checkpoint does not exist.
    """
    if not specs:
        raise ValueError(f"{option}: give at least one agent")
    try:
        labelled = agent_labels(list(specs))
        for _, target in labelled:
            check_agent_spec(target, open_model=True)
    except ValueError as error:
        raise ValueError(f"{option}: {error}") from None
    except FileNotFoundError as error:
        raise FileNotFoundError(f"{option}: {error}") from None
    return labelled


def check_env(env_id: str, env_kwargs: Mapping[str, Any] | None = None, option: str = "--env-kwargs",
              **fixed: Any) -> None:  # fmt: skip
    """Make ``env_id`` once with ``env_kwargs`` (and ``fixed``) and close it: its refusals before any work.

    Raises
    ------
    ValueError
        What ``gym.make`` raised (a ``ValueError`` or ``TypeError`` of the env), prefixed by ``option``.
    """
    try:
        env = gym.make(env_id, **{**dict(env_kwargs or {}), **fixed})
    except (ValueError, TypeError) as error:
        raise ValueError(f"{option}: {error}") from None
    env.close()


def model_digests(labelled: Sequence[tuple[str, str]]) -> dict[str, str]:
    """The SHA-256 of every saved model among ``(label, target)`` pairs, by label: part of a run's configuration.

    A run resumed with a model file that changed since is refused, as one with other arguments.
    """
    from agents.evaluate.journal import file_digest

    digests = {}
    for label, target in labelled:
        if target in SHIPPED_POLICIES:
            digests[label] = file_digest(SHIPPED_POLICIES[target].path)
        elif target.endswith(".zip"):
            digests[label] = file_digest(target)
    return digests


def add_resume_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--resume OUT``: continue the killed run of the folder ``OUT`` (:func:`resume_folder`)."""
    parser.add_argument("--resume", default=None, metavar="OUT",
                        help="continue the run that was killed in the folder OUT, with the same arguments: the work "
                        "it finished is not done again, and the outputs are those of a run left alone "
                        "(OUT is the output folder)")  # fmt: skip


def resume_folder(args: argparse.Namespace, default_out: str) -> tuple[Path, bool]:
    """The output folder of parsed arguments with ``--out`` and ``--resume``, and whether to resume.

    ``--resume OUT`` writes to ``OUT``; an ``--out`` beside it must name the same folder.

    Parameters
    ----------
    args : argparse.Namespace
        Has ``out`` (``None`` when not given) and ``resume``.
    default_out : str
        The folder without either.

    Raises
    ------
    ValueError
        If ``--out`` and ``--resume`` name different folders, or ``--resume``'s folder does not exist.
    """
    if args.resume is None:
        return check_out(default_out if args.out is None else args.out), False
    folder = Path(args.resume)
    if args.out is not None and Path(args.out).resolve() != folder.resolve():
        raise ValueError(f"--resume: {folder} is the output folder; --out {args.out} names another")
    if not folder.is_dir():
        raise ValueError(f"--resume: {folder} is not a folder (the --out of the run to continue)")
    return check_out(folder, "--resume"), True


@contextlib.contextmanager
def usage_errors(parser: argparse.ArgumentParser) -> Iterator[None]:
    """Inside the block, a ``ValueError``, ``TypeError``, ``FileNotFoundError`` or ``OSError`` is a usage error.

    The exception's message on one line of stderr, after the command's name (as ``parser.error`` writes
    it, without the usage: the line says what is wrong), and exit status 2; no traceback.
    """
    try:
        yield
    except (ValueError, TypeError, OSError) as error:
        parser.exit(2, f"{parser.prog}: error: {' '.join(str(error).split())}\n")
