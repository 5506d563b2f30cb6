"""The budget's clock in the observation: the fraction of the episode's steps left.

On the budget tasks (``SeifExploreBudget``, ``SeifExploreLoopBudget``,
``SeifExploreClusteredBudget``) the episode ends after a fixed number of
steps, and the final map error is what counts. The env's observation does not
say how many steps are left, so a policy cannot tell a first step from a last
one, and PPO, which bootstraps the value at a truncation, learns as if the
episode went on. Pardo et al. (ICML 2018, "Time limits in reinforcement
learning") show the remedy: put the time left into the observation and treat
the time limit as the end of the task.

:class:`TimeLeftObservation` does both for training (a single-env wrapper, an
``env_wrapper`` of a config). The time left is not part of the env: the
budget is part of the task's registration, and an agent can count its own
steps, so :class:`TimeLeftClock` computes the same entry on the agent's side
when a policy trained with it is evaluated on the plain env
(:class:`agents.sb3_agent.SB3Agent` and the validation callback use it).

>>> import gymnasium as gym
>>> import seif_gym
>>> from agents.time_feature import TimeLeftObservation
>>> env = TimeLeftObservation(gym.make("SeifExploreBudget-v2", max_episode_steps=2))
>>> observation, _ = env.reset(seed=0)
>>> float(observation["time_left"][0])
1.0
>>> observation, _, terminated, truncated, _ = env.step(env.action_space.sample())
>>> float(observation["time_left"][0]), terminated, truncated
(0.5, False, False)
>>> observation, _, terminated, truncated, _ = env.step(env.action_space.sample())
>>> float(observation["time_left"][0]), terminated, truncated
(0.0, True, False)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from agents.entries import holds_entry, with_entry
from seif_gym.validation import as_count

__all__ = ["TIME_LEFT", "TimeLeftClock", "TimeLeftObservation", "episode_limit", "uses_time_left"]

#: The observation key of the time left: ``(limit - steps taken) / limit``, in [0, 1], shape ``(1,)``.
TIME_LEFT = "time_left"


def uses_time_left(observation_space: Any) -> bool:
    """Whether ``observation_space`` (a policy's) holds the :data:`TIME_LEFT` entry."""
    return holds_entry(observation_space, TIME_LEFT)


def episode_limit(env: Any) -> int:
    """The time limit of ``env``'s registration (``env.spec.max_episode_steps``).

    Raises
    ------
    ValueError
        If ``env`` has no positive integer time limit.
    """
    spec = getattr(env, "spec", None)
    limit = getattr(spec, "max_episode_steps", None)
    if limit is None or isinstance(limit, bool) or not isinstance(limit, (int, np.integer)) or limit < 1:
        raise ValueError(f"env: the time left needs an env with a time limit (spec.max_episode_steps), got {limit!r}")
    return int(limit)


def _time_left(steps: np.ndarray, limit: int) -> np.ndarray:
    """``(limit - steps) / limit`` clipped to [0, 1], as ``float32`` of shape ``steps.shape + (1,)``."""
    return np.clip((limit - steps) / limit, 0.0, 1.0).astype(np.float32)[..., None]


class TimeLeftObservation(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Add :data:`TIME_LEFT` to the observation; the time limit ends the task (``terminated``).

    Parameters
    ----------
    env : gymnasium.Env
        An env with a ``Dict`` observation space and a time limit
        (``spec.max_episode_steps``, which ``gym.make`` sets from the
        registration or its ``max_episode_steps`` argument).

    Raises
    ------
    TypeError
        If the observation space is not a ``Dict``.
    ValueError
        If it already holds :data:`TIME_LEFT`, or the env has no time limit.

    Notes
    -----
    After ``t`` steps of an episode of at most ``T`` the entry is
    ``(T - t) / T``: 1 after the reset, 0 after the last step. A truncation
    at the limit is reported as ``terminated`` (and not ``truncated``), so
    that a learner does not bootstrap a value beyond the budget: with the time
    left in the observation the limit is part of the task (Pardo et al.,
    2018). A truncation before the limit (an outer wrapper's) stays a
    truncation.
    """

    def __init__(self, env: gym.Env) -> None:
        space = with_entry(env.observation_space, TIME_LEFT, gym.spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32))
        self.limit = episode_limit(env)
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.observation_space = space
        self._steps = 0

    def _observe(self, observation: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {**observation, TIME_LEFT: _time_left(np.asarray(self._steps), self.limit)}

    def reset(self, **kwargs: Any):
        observation, info = self.env.reset(**kwargs)
        self._steps = 0
        return self._observe(observation), info

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        if truncated and self._steps >= self.limit:
            terminated, truncated = True, False
        return self._observe(observation), reward, terminated, truncated, info


class TimeLeftClock:
    """The agent's side of :data:`TIME_LEFT`: counts each env's steps since its episode started.

    Parameters
    ----------
    limit : int
        The episode's time limit (:func:`episode_limit` of the env).

    Notes
    -----
    :meth:`observe` is called once per step with the observation the action
    is chosen on; ``episode_start`` (SB3's ``predict`` argument) or
    :meth:`reset` restart the count. The entry equals what
    :class:`TimeLeftObservation` gives the same observation.
    """

    def __init__(self, limit: int) -> None:
        self.limit = as_count(limit, "limit", minimum=1)
        self._steps = np.zeros(0, dtype=np.int64)

    def reset(self, index: int | None = None) -> None:
        """Env ``index`` (every env when ``None``) starts a new episode."""
        if index is None:
            self._steps = np.zeros(0, dtype=np.int64)
        elif 0 <= int(index) < self._steps.shape[0]:
            self._steps[int(index)] = 0

    def observe(self, observation: Mapping[str, np.ndarray], episode_start: Any = None) -> dict[str, np.ndarray]:
        """``observation`` with :data:`TIME_LEFT` added (single or batched), then one more step counted.

        Parameters
        ----------
        observation : mapping of str to ndarray
            One env's observation, or a batch (a leading axis on every entry).
        episode_start : array_like of bool, optional
            SB3's flags, one per env: a set flag restarts that env's count first.

        Returns
        -------
        dict
            ``observation`` with the entry (returned as it is if it already holds one).

        Raises
        ------
        ValueError
            If ``episode_start`` does not have one flag per env (the counts are left as they were).
        """
        if TIME_LEFT in observation:
            return dict(observation)
        # the env's pose entry is 1-D: a leading axis is the batch's
        pose = np.asarray(observation["pose"])
        batched = pose.ndim == 2
        n_envs = pose.shape[0] if batched else 1
        starts = None
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.shape[0] != n_envs:
                raise ValueError(f"episode_start must have {n_envs} entries, got shape {np.shape(episode_start)}")
        # checked before anything changes: a refused call leaves the counts as they were
        steps = self._steps if self._steps.shape[0] == n_envs else np.zeros(n_envs, dtype=np.int64)
        if starts is not None:
            steps[starts] = 0
        left = _time_left(steps, self.limit)
        self._steps = steps + 1
        return {**observation, TIME_LEFT: left if batched else left[0]}
