"""The observation entries a policy computes on its own side, behind one interface.

Some policies were trained with entries that are not the env's, such as the
budget's clock (:mod:`agents.time_feature`, :data:`~agents.time_feature.TIME_LEFT`).
Training adds an entry with a wrapper (the config's ``env_wrapper``); on the
plain env the agent computes the same entry itself from what it observes. The
policy's observation space says which entries it needs: :func:`policy_memories`
builds the agent's side, :func:`policy_view` wraps an env the way training did
(for the spaces that ``VecNormalize`` and the leaderboard's fit check compare).

Each kind of entry is a :class:`PolicyEntry`; the product registers the clock,
and code outside the product (``research/``) registers its own with
:func:`register_policy_entry`.

>>> import gymnasium as gym
>>> import seif_gym
>>> from agents.time_feature import TIME_LEFT, TimeLeftObservation
>>> from agents.memories import policy_memories
>>> trained = TimeLeftObservation(gym.make("SeifExploreBudget-v2"))
>>> plain = gym.make("SeifExploreBudget-v2")
>>> memories = policy_memories(trained.observation_space, plain)
>>> observation, _ = plain.reset(seed=3)
>>> expected, _ = trained.reset(seed=3)
>>> bool((memories.observe(observation, episode_start=True)[TIME_LEFT] == expected[TIME_LEFT]).all())
True
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from agents.time_feature import TimeLeftClock, TimeLeftObservation, episode_limit, uses_time_left

__all__ = [
    "PolicyEntry",
    "PolicyMemories",
    "has_policy_entries",
    "needs_acting_env",
    "policy_entries",
    "policy_memories",
    "policy_view",
    "register_policy_entry",
]


class Memory(Protocol):
    """The agent's side of one entry: restarts with an episode, adds its entry to each observation."""

    def reset(self, index: int | None = None) -> None: ...

    def observe(self, observation: Mapping[str, np.ndarray], episode_start: Any = None) -> dict[str, np.ndarray]: ...


@dataclass(frozen=True)
class PolicyEntry:
    """One kind of entry a policy may compute itself.

    Attributes
    ----------
    name : str
        A unique name (the entry's key in the observation, by convention).
    holds : callable
        ``holds(observation_space) -> bool``: whether a policy's space has the entry.
    build : callable
        ``build(env) -> Memory``: the agent's side, from an env of the task.
    wrapper : callable
        ``wrapper(env) -> env``: the training wrapper that adds the entry.
    order : float
        Where the entry sits among the wrappers, innermost first (as in training).
    needs_acting_env : bool
        The memory reads the env the agent acts in (not only an env of the task).
    """

    name: str
    holds: Callable[[Any], bool]
    build: Callable[[Any], Memory]
    wrapper: Callable[[gym.Env], gym.Env]
    order: float = 0.0
    needs_acting_env: bool = False


_ENTRIES: dict[str, PolicyEntry] = {}


def register_policy_entry(entry: PolicyEntry) -> None:
    """Make ``entry`` known to :func:`policy_memories` and :func:`policy_view` (again: replaced).

    Raises
    ------
    TypeError
        If ``entry`` is not a :class:`PolicyEntry`.
    """
    if not isinstance(entry, PolicyEntry):
        raise TypeError(f"entry must be a PolicyEntry, got {type(entry).__name__}")
    _ENTRIES[entry.name] = entry


def policy_entries(observation_space: Any) -> list[PolicyEntry]:
    """The registered entries ``observation_space`` (a policy's) holds, innermost first."""
    return sorted((e for e in _ENTRIES.values() if e.holds(observation_space)), key=lambda e: e.order)


register_policy_entry(
    PolicyEntry("time_left", uses_time_left, lambda env: TimeLeftClock(episode_limit(env)), TimeLeftObservation)
)


class PolicyMemories:
    """The policy-side entries of one policy, applied innermost first.

    Parameters
    ----------
    memories : sequence of Memory
        Objects with ``reset(index=None)`` and ``observe(observation,
        episode_start=None)``; one may also have ``act(action)``, which turns
        the policy's action into the one the env executes.
    """

    def __init__(self, memories: list[Memory]) -> None:
        self.memories = list(memories)

    def reset(self, index: int | None = None) -> None:
        """Env ``index`` (every env when ``None``) starts a new episode."""
        for memory in self.memories:
            memory.reset(index)

    def observe(self, observation: Mapping[str, np.ndarray], episode_start: Any = None) -> dict[str, np.ndarray]:
        """``observation`` (single or batched) with every entry added; each memory then takes the step."""
        result = dict(observation)
        for memory in self.memories:
            result = memory.observe(result, episode_start)
        return result

    def act(self, action: Any) -> np.ndarray:
        """The action the env executes for the policy's ``action``: the first memory's ``act``, else ``action``."""
        for memory in self.memories:
            act = getattr(memory, "act", None)
            if act is not None:
                return np.asarray(act(action))
        return np.asarray(action)


def has_policy_entries(observation_space: Any) -> bool:
    """Whether ``observation_space`` (a policy's) holds an entry the agent computes itself."""
    return bool(policy_entries(observation_space))


def needs_acting_env(observation_space: Any) -> bool:
    """Whether one of the entries of ``observation_space`` (a policy's) reads the env the agent acts in."""
    return any(entry.needs_acting_env for entry in policy_entries(observation_space))


def policy_memories(observation_space: Any, env: Any) -> PolicyMemories | None:
    """The agent's side of the entries ``observation_space`` (a policy's) has beyond ``env``'s; ``None`` if none.

    Parameters
    ----------
    observation_space : gymnasium.spaces.Space
        The policy's observation space.
    env : gymnasium.Env
        An env of the task (its time limit and geometry are read, never its
        world); the env the agent acts in for an entry with ``needs_acting_env``.
    """
    memories = [entry.build(env) for entry in policy_entries(observation_space)]
    return PolicyMemories(memories) if memories else None


def policy_view(env: gym.Env, observation_space: Any) -> gym.Env:
    """``env`` wrapped with the training wrappers of the entries ``observation_space`` (a policy's) holds."""
    for entry in policy_entries(observation_space):
        if isinstance(env.observation_space, gym.spaces.Dict):
            env = entry.wrapper(env)
    return env
