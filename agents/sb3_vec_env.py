"""A Stable-Baselines3 ``VecEnv`` over a native Gymnasium ``VectorEnv`` (``gym.make_vec``).

Stable-Baselines3 2.x steps its own ``VecEnv`` type and has no adapter for a
Gymnasium ``VectorEnv``. :class:`NativeVecEnv` is that adapter: it drives the
vector env in ``SameStep`` autoreset mode (what SB3 expects: the step that
ends an episode already returns the next episode's first observation) and
turns its batched infos into SB3's list of per-env dicts, with
``infos[i]["terminal_observation"]`` and ``infos[i]["TimeLimit.truncated"]``;
each sub-env's latest reset info is in ``reset_infos[i]``, as SB3 keeps it.

>>> import seif_gym
>>> from agents.sb3_vec_env import NativeVecEnv
>>> venv = NativeVecEnv("SeifExplore-v2", num_envs=4, seed=0)
>>> obs = venv.reset()
>>> obs["belief_map"].shape
(4, 3, 40, 40)
>>> venv.close()
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from seif_gym.validation import as_count

__all__ = ["NativeVecEnv"]


class NativeVecEnv(VecEnv):
    """``gym.make_vec(env_id, num_envs, autoreset_mode="SameStep")`` behind SB3's ``VecEnv`` interface.

    Parameters
    ----------
    env_id : str
        A registered id (with a ``vector_entry_point``, the native vector env; otherwise Gymnasium's
        ``SyncVectorEnv``).
    num_envs : int
        Sub-envs.
    seed : int, optional
        The first :meth:`reset` seeds sub-env ``i`` with ``seed + i`` (as SB3's ``make_vec_env``).
    env_kwargs : dict, optional
        Keyword arguments of the env.

    Raises
    ------
    TypeError, ValueError
        If ``num_envs`` is not a positive int; ``gymnasium.error.Error`` for an unknown ``env_id``.
    """

    def __init__(self, env_id: str, num_envs: int, seed: int | None = None,
                 env_kwargs: dict[str, Any] | None = None) -> None:  # fmt: skip
        as_count(num_envs, "num_envs", minimum=1)
        self.venv = gym.make_vec(env_id, num_envs=int(num_envs), autoreset_mode=AutoresetMode.SAME_STEP,
                                 **(env_kwargs or {}))  # fmt: skip
        super().__init__(int(num_envs), self.venv.single_observation_space, self.venv.single_action_space)
        self._seed = seed
        self._actions: np.ndarray | None = None
        self.render_mode = getattr(self.venv, "render_mode", None)

    # -- VecEnv interface ---------------------------------------------------------------------------
    def reset(self) -> VecEnvObs:
        observations, infos = self.venv.reset(seed=self._seed)
        self._seed = None  # later resets continue each sub-env's own random stream
        self.reset_infos = self._split(infos)  # as DummyVecEnv: each sub-env's reset info
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        assert self._actions is not None, "step_async first"
        observations, rewards, terminated, truncated, infos = self.venv.step(self._actions)
        dones = terminated | truncated
        per_env = self._split(infos)
        if dones.any():
            # SB3's info of an ending step is that step's own (Gymnasium's SameStep keeps it in final_info,
            # with the next episode's reset info in its place)
            final = self._split(infos["final_info"])
            for i in np.flatnonzero(dones).tolist():
                self.reset_infos[i] = per_env[i]  # the next episode's reset info, as DummyVecEnv keeps it
                per_env[i] = final[i]
                per_env[i]["terminal_observation"] = infos["final_obs"][i]
        for i in range(self.num_envs):  # as SB3's DummyVecEnv: on every step
            per_env[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        return observations, rewards.astype(np.float32), dones, per_env

    def _split(self, infos: dict[str, Any]) -> list[dict[str, Any]]:
        """SB3's list of per-env dicts out of Gymnasium's batched infos (``_key`` masks honoured)."""
        per_env: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for key, value in infos.items():
            if key.startswith("_") or key in ("final_obs", "final_info"):
                continue
            mask = infos.get(f"_{key}")
            for i in range(self.num_envs):
                if mask is None or mask[i]:
                    per_env[i][key] = value[i]
        return per_env

    def close(self) -> None:
        self.venv.close()

    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        """Seed the next :meth:`reset` (sub-env ``i`` gets ``seed + i``)."""
        self._seed = seed
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def _sub_envs(self, indices: VecEnvIndices) -> list[Any]:
        envs = getattr(self.venv, "envs", None)
        if envs is None:
            raise AttributeError(f"{type(self.venv).__name__} does not expose its sub-envs")
        return [envs[i] for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(env.unwrapped, attr_name) for env in self._sub_envs(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise AttributeError("set_attr is not meaningful for a native vector env: its state lives in arrays")

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        return [getattr(env.unwrapped, method_name)(*method_args, **method_kwargs) for env in self._sub_envs(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        frame: Any = self.venv.render()  # sub-env 0's frame (an rgb array)
        return [np.asarray(frame) if frame is not None else None] + [None] * (self.num_envs - 1)
