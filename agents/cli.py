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
  ``LABEL=SPEC`` (:func:`agents.loading.load_agent`).

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
import json
import textwrap
import warnings
from collections.abc import Sequence
from typing import Any

import gymnasium as gym

import seif_gym
from agents.baselines import BASELINES
from agents.loading import SHIPPED_POLICIES

__all__ = [
    "add_deprecated_alias",
    "agents_help",
    "json_object",
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
