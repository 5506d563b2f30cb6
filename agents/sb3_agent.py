"""A saved Stable-Baselines3 or sb3-contrib model behind the :class:`~agents.base.Agent` interface."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agents.base import Agent
from agents.memories import PolicyMemories, has_policy_entries, needs_acting_env, policy_memories, policy_view

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

__all__ = ["SB3Agent", "sb3_algorithm"]


def sb3_algorithm(path: str | os.PathLike) -> type[BaseAlgorithm]:
    """The algorithm class that loads the SB3 model at ``path``: ``PPO``, ``RecurrentPPO`` or ``SAC``.

    Read from the policy class saved in the ``.zip`` (without loading the weights).

    Raises
    ------
    ValueError
        ``path`` is not a model of one of the three algorithms.
    """
    import zipfile

    from sb3_contrib import RecurrentPPO
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.save_util import json_to_data
    from stable_baselines3.sac.policies import SACPolicy

    try:
        with zipfile.ZipFile(path) as archive:
            policy = json_to_data(archive.read("data").decode()).get("policy_class")
    except (OSError, KeyError, zipfile.BadZipFile, ValueError) as error:
        raise ValueError(f"path: {str(path)!r} is not a saved SB3 model ({error})") from error
    # the recurrent policy is an actor-critic policy too: ask for it first
    for policy_base, algorithm in ((RecurrentActorCriticPolicy, RecurrentPPO), (SACPolicy, SAC),
                                   (ActorCriticPolicy, PPO)):  # fmt: skip
        if isinstance(policy, type) and issubclass(policy, policy_base):
            return algorithm
    raise ValueError(f"path: {str(path)!r} holds a {policy!r} policy, not one of PPO, RecurrentPPO or SAC")


class SB3Agent(Agent):
    """A saved Stable-Baselines3 model (PPO, RecurrentPPO or SAC) behind the :class:`~agents.base.Agent` interface.

    Parameters
    ----------
    path : str or Path
        The model's ``.zip``.
    env : gymnasium.Env, optional
        Used only to rebuild a ``VecNormalize`` (its spaces).
    env_factory : callable, optional
        Builds an env for ``VecNormalize.load`` when the model's
        normalisation statistics are found
        (:func:`agents.checkpoints.vecnormalize_path`: a checkpoint's
        ``PREFIX_vecnormalize_<N>_steps.pkl``, else ``vecnormalize.pkl``
        in the model's folder or rl-zoo3's ``<EnvId>/vecnormalize.pkl``); its
        observation normalisation (``obs_rms``) is then applied to every
        observation (statistics frozen).
    """

    name = "sb3"

    def __init__(self, path: str | os.PathLike, env: Any | None = None, env_factory: Any | None = None) -> None:
        super().__init__(env)
        self.path = Path(path)
        # the recurrent state runs through predict's ``state`` (run_episode passes it back each step)
        self.model = sb3_algorithm(self.path).load(self.path, device="cpu")
        #: a recurrent policy's state when the caller passes none (``predict(observation)`` alone)
        self.recurrent = hasattr(self.model.policy, "lstm_actor")
        self._recurrent_state: Any = None
        self.vecnormalize = None
        from agents.checkpoints import vecnormalize_path

        factory: Callable[[], Any] = env_factory if env_factory is not None else (lambda: env)
        # a policy trained with entries of its own (the budget's clock, the coverage memory) computes them itself
        space = self.model.observation_space
        self.memories: PolicyMemories | None = None
        if has_policy_entries(space):
            if env is None and needs_acting_env(space):
                raise ValueError(f"env: {self.path} computes an entry from the env it acts in: pass that env")
            if env is not None:
                self.memories = policy_memories(space, env)
            else:
                probe = factory()
                try:
                    self.memories = policy_memories(space, probe)
                finally:
                    if probe is not None:
                        probe.close()
            plain_factory = factory
            factory = lambda: policy_view(plain_factory(), space)  # noqa: E731  (the spaces VecNormalize checks)
        # the statistics saved with this very model (a checkpoint's own, never a later moment's)
        stats_path = vecnormalize_path(self.path)
        if stats_path is not None:
            from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

            self.vecnormalize = VecNormalize.load(str(stats_path), DummyVecEnv([factory]))
            self.vecnormalize.training = False
            self.vecnormalize.norm_reward = False

    def predict(
        self,
        observation: Mapping[str, np.ndarray],
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, Any]:
        """The model's ``predict`` after its own entries and the saved observation normalisation (if any)."""
        model_input: Any = (
            dict(observation) if self.memories is None else self.memories.observe(observation, episode_start)
        )
        if self.vecnormalize is not None:
            model_input = self.vecnormalize.normalize_obs(model_input)
        own_state = state is None and self.recurrent
        if own_state:  # no state passed: the agent carries the recurrent state itself, as SB3's caller would
            state = self._recurrent_state
            if episode_start is None:
                episode_start = self._episode_start(model_input)
        action, state = self.model.predict(
            model_input, state=state, episode_start=episode_start, deterministic=deterministic
        )
        if own_state:
            self._recurrent_state = state
        if self.memories is not None:
            action = self.memories.act(action)  # a residual's sum with the planner's action
        return np.asarray(action, dtype=np.float32), state

    def _act(self, observation: Mapping[str, np.ndarray], index: int) -> np.ndarray:
        """One unbatched observation (the model is stateless across envs)."""
        return self.predict(observation, deterministic=True)[0]

    def _episode_start(self, model_input: Any) -> np.ndarray:
        """``episode_start`` for a call without one: true for every env on the first call after a reset."""
        pose = np.asarray(model_input["pose"]) if isinstance(model_input, Mapping) else np.asarray(model_input)
        count = pose.shape[0] if pose.ndim == 2 else 1
        return np.full(count, self._recurrent_state is None)

    def reset(self, index: int | None = None) -> None:
        """Env ``index`` (every env when ``None``) starts a new episode; the policy's own entries restart with it.

        The recurrent state the agent carries itself (calls without ``state``) restarts for every env.
        """
        super().reset(index)
        self._recurrent_state = None
        if self.memories is not None:
            self.memories.reset(index)

    def __repr__(self) -> str:
        return f"SB3Agent({str(self.path)!r}, vecnormalize={self.vecnormalize is not None})"
