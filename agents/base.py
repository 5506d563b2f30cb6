"""The agent interface: Stable-Baselines3's ``predict`` over a per-env ``_act``.

Every agent of :mod:`agents` (the baselines, a saved SB3 model, an RLlib
checkpoint) is an :class:`Agent`, so they are used the same way.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

Observation = Mapping[str, np.ndarray]

__all__ = ["Agent", "Observation"]


# -- the interface ---------------------------------------------------------------------------------
class Agent(ABC):
    """Base class of the baselines: SB3's ``predict`` over per-env ``_act``.

    Subclasses implement :meth:`_act` for one (unbatched) observation and,
    if they keep memory, :meth:`_new_state`. :meth:`predict` accepts a single
    observation dict (arrays of the observation space's shapes) or a batched
    one (a leading ``n_envs`` axis, as a ``VecEnv`` returns), like an SB3
    model, and keeps one memory per env index.

    Parameters
    ----------
    env : gymnasium.Env or None
        The env the agent acts in. The baselines require it (they read the
        observation with its :class:`Geometry`); a trained model may not
        need it.
    """

    #: Name under which :func:`make_agent` builds the agent.
    name: ClassVar[str] = "agent"
    #: Whether the agent needs the env's filter (``env`` may not be ``None``).
    needs_filter: ClassVar[bool] = False
    #: Whether state carries from one episode into the next (beyond what ``reset`` clears), so that an
    #: episode's actions depend on the episodes before it: a harness must then run them in order.
    carries_over_episodes: ClassVar[bool] = False

    def __init__(self, env: Any | None = None) -> None:
        self.env = env
        self._states: dict[int, Any] = {}

    # -- for subclasses ----------------------------------------------------------------------------
    def _new_state(self) -> Any:
        """Fresh memory of one env at an episode start (``None``: memoryless)."""
        return None

    @abstractmethod
    def _act(self, observation: Observation, index: int) -> np.ndarray:
        """Action ``(2,)`` in ``[-1, 1]`` for the unbatched ``observation`` of env ``index``."""

    def _state(self, index: int) -> Any:
        if index not in self._states:
            self._states[index] = self._new_state()
        return self._states[index]

    # -- public ------------------------------------------------------------------------------------
    def reset(self, index: int | None = None) -> None:
        """Forget the memory of env ``index`` (all envs when ``None``): a new episode starts."""
        if index is None:
            self._states.clear()
        else:
            self._states.pop(int(index), None)

    def predict(
        self,
        observation: Observation,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, Any]:
        """Actions for ``observation``, with SB3's signature.

        Parameters
        ----------
        observation : dict of numpy.ndarray
            One observation of the env's ``Dict`` space, or a batch of them
            (every entry with a leading ``n_envs`` axis).
        state : Any, optional
            Returned unchanged (the recurrent state of SB3; the baselines
            keep their memory inside, per env index).
        episode_start : bool or array_like of bool, optional
            ``True`` for the envs whose episode has just started: their
            memory is reset first. Shape ``(n_envs,)`` for a batch.
        deterministic : bool, optional
            Ignored: ``random`` always samples (that is its point), the
            other baselines are deterministic.

        Returns
        -------
        action : numpy.ndarray of float32
            Shape ``(2,)`` for a single observation, ``(n_envs, 2)`` for a
            batch; values in ``[-1, 1]``.
        state : Any
            ``state``, unchanged.
        """
        if not isinstance(observation, Mapping) or "pose" not in observation:
            raise TypeError(f"observation must be the env's dict observation, got {type(observation).__name__}")
        pose = np.asarray(observation["pose"])
        if pose.ndim not in (1, 2) or pose.shape[-1] != 7:
            raise ValueError(f'observation["pose"] must have shape (7,) or (n_envs, 7), got {pose.shape}')
        batched = pose.ndim == 2
        count = pose.shape[0] if batched else 1
        if episode_start is not None:
            starts = np.broadcast_to(np.asarray(episode_start, dtype=bool).reshape(-1), (count,))
            for started in np.flatnonzero(starts):
                self.reset(int(started))
        actions = np.empty((count, 2), dtype=np.float32)
        for index in range(count):
            single = {
                key: np.asarray(value)[index] if batched else np.asarray(value) for key, value in observation.items()
            }
            actions[index] = np.clip(self._act(single, index), -1.0, 1.0)
        return (actions if batched else actions[0]), state

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"
