"""The observation entries a policy computes on its own side, in one place.

Some policies were trained with entries that are not the env's: the
budget's clock (:mod:`agents.time_feature`, :data:`~agents.time_feature.TIME_LEFT`),
the memory of the swept arena (:mod:`agents.coverage_memory`,
:data:`~agents.coverage_memory.UNSWEPT`) and the planner's action of a
residual policy (:mod:`agents.residual`, :data:`~agents.residual.PLANNER_ACTION`).
Training adds them with a wrapper (the config's ``env_wrapper``); on the plain
env the agent computes the same entries itself from what it observes, and
:meth:`PolicyMemories.act` turns a residual policy's action into the one the
env executes. The policy's observation space says
which it needs: :func:`policy_memories` builds the agent's side,
:func:`policy_view` wraps an env the way training did (for the spaces that
``VecNormalize`` and the leaderboard's fit check compare).

>>> import gymnasium as gym
>>> import seif_gym
>>> from agents.coverage_memory import UNSWEPT, CoverageMemoryObservation
>>> from agents.memories import policy_memories
>>> trained = CoverageMemoryObservation(gym.make("SeifExploreLarge-v2"))
>>> plain = gym.make("SeifExploreLarge-v2")
>>> memories = policy_memories(trained.observation_space, plain)
>>> observation, _ = plain.reset(seed=3)
>>> expected, _ = trained.reset(seed=3)
>>> bool((memories.observe(observation, episode_start=True)[UNSWEPT] == expected[UNSWEPT]).all())
True
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from agents.baselines import Geometry
from agents.coverage_memory import CoverageMemory, CoverageMemoryObservation, uses_coverage_memory
from agents.residual import PlannerResidual, PlannerResidualAction, uses_planner_action
from agents.time_feature import TimeLeftClock, TimeLeftObservation, episode_limit, uses_time_left

__all__ = ["PolicyMemories", "has_policy_entries", "policy_memories", "policy_view"]


class _Memory(Protocol):
    def reset(self, index: int | None = None) -> None: ...

    def observe(self, observation: Mapping[str, np.ndarray], episode_start: Any = None) -> dict[str, np.ndarray]: ...


class PolicyMemories:
    """The policy-side entries of one policy (each entry's value does not depend on the order).

    Parameters
    ----------
    memories : sequence
        Objects with ``reset(index=None)`` and ``observe(observation,
        episode_start=None)`` (:class:`~agents.time_feature.TimeLeftClock`,
        :class:`~agents.coverage_memory.CoverageMemory`).
    """

    def __init__(self, memories: list[_Memory]) -> None:
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
        """The action the env executes for the policy's ``action`` (a residual's sum; else ``action``)."""
        for memory in self.memories:
            if isinstance(memory, PlannerResidual):
                return memory.act(action)
        return np.asarray(action)


#: Each policy-side entry: whether a policy's space holds it, the agent's side built from an env of
#: the task, and the training wrapper that adds it. The memory checks everything the clock checks
#: (and the pose) before it changes, so with it first a refused observation changes neither.
_ENTRIES: tuple[tuple[Callable[[Any], bool], Callable[[Any], _Memory], Callable[[gym.Env], gym.Env]], ...] = (
    (uses_coverage_memory, lambda env: CoverageMemory(Geometry.from_env(env)), CoverageMemoryObservation),
    (uses_time_left, lambda env: TimeLeftClock(episode_limit(env)), TimeLeftObservation),
    # last, as in training (outermost): the planner sees the observation the inner entries made
    (uses_planner_action, PlannerResidual, PlannerResidualAction),
)


def has_policy_entries(observation_space: Any) -> bool:
    """Whether ``observation_space`` (a policy's) holds an entry the agent computes itself."""
    return any(holds(observation_space) for holds, _, _ in _ENTRIES)


def policy_memories(observation_space: Any, env: Any) -> PolicyMemories | None:
    """The agent's side of the entries ``observation_space`` (a policy's) has beyond ``env``'s; ``None`` if none.

    Parameters
    ----------
    observation_space : gymnasium.spaces.Space
        The policy's observation space.
    env : gymnasium.Env
        An env of the task (its time limit and geometry are read, never its
        world); for a residual on the planner (:mod:`agents.residual`) the
        env the agent acts in, whose filter the planner plans with.
    """
    memories = [build(env) for holds, build, _ in _ENTRIES if holds(observation_space)]
    return PolicyMemories(memories) if memories else None


def policy_view(env: gym.Env, observation_space: Any) -> gym.Env:
    """``env`` wrapped with the training wrappers of the entries ``observation_space`` (a policy's) holds."""
    for holds, _, wrapper in _ENTRIES:
        if holds(observation_space) and isinstance(env.observation_space, gym.spaces.Dict):
            env = wrapper(env)
    return env
