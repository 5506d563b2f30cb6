r"""An adversarial reward for ``SeifExplore``: drive where the SEIF does worse than the EKF.

:class:`SeifVsEkfReward` wraps a ``SeifExplore`` env and runs a *shadow* EKF
on exactly the data the env's own filter (the SEIF) gets: it is built at
``reset`` at the same start pose (``info["true_pose"]``, the pose the env's
filter starts from, with the same default initial covariance), processes the
reset's measurement, and then per step ``predict(info["executed_control"], dt)``
and ``update(*info["measurements"])``, the calls of the env and of
:func:`seif_gym.episodes.replay`. Its map error is the env's ``E_t`` (the same
function and ``d_cap``), so both errors are comparable bit for bit with
``replay(episode, "ekf").map_errors``.

Reward
------
With ``G_t = E_t^SEIF − E_t^EKF`` (the gap of the map errors after step ``t``;
``E`` is the env's map error, ``info["map_error"]`` for the SEIF)::

    r_t = (G_t − G_{t−1})  +  nees_weight · min(NEES_t, nees_cap) / 3

so with ``nees_weight = 0`` (the default) the undiscounted return of an
episode is ``G_T − G_0 = (E_T^SEIF − E_T^EKF) − (E_0^SEIF − E_0^EKF)``: the
final gap (``G_0`` is ~0: both filters have seen one scan). The env's
wall penalty is dropped (the reward is replaced, not added to). The optional
NEES term rewards overconfidence directly: ``NEES_t`` is the SEIF's pose NEES
with its *exact* marginal covariance (``filter.pose_covariance``, a sparse
solve per step), 1 per step on average for a consistent filter.
Divergence still ends the episode (the env terminates); a diverged SEIF has a
large ``E^SEIF``, so the adversary is paid for it.

Extra ``info`` keys: ``ekf_map_error`` (``E_t^EKF``), ``map_error_gap``
(``G_t``) and, with ``nees_weight > 0``, ``seif_pose_nees``.

Training: the policy still observes only the SEIF's belief; only the reward
changes. The shipped adversary ``ppo_adversary_v1``
(:data:`agents.loading.SHIPPED_POLICIES`) is the 200 k-step checkpoint of
this recipe, started from the shipped exploring policy (its use:
``docs/filters/robustness.md``)::

    python -m agents.train --algo ppo --env SeifExplore-v1 --init-from agents/policies/ppo.zip \
        --wrapper agents.adversary:SeifVsEkfReward --wrapper-kwargs '{"nees_weight": 0.01}' \
        --hyperparams learning_rate=1e-4 --timesteps 400000 --checkpoint-freq 100000 \
        --eval-freq 1000000 --out runs/adversary_v1 --seed 5

>>> import gymnasium as gym
>>> import seif_gym
>>> from agents.adversary import SeifVsEkfReward
>>> env = SeifVsEkfReward(gym.make("SeifExplore-v1", max_episode_steps=5))
>>> _, info = env.reset(seed=0)
>>> _, reward, _, _, info = env.step(env.action_space.sample())
>>> sorted(k for k in info if k in ("ekf_map_error", "map_error_gap"))
['ekf_map_error', 'map_error_gap']
"""

from __future__ import annotations

import math
from typing import Any, cast

import gymnasium as gym
import numpy as np

from seif_gym.envs.explore import SeifExploreEnv, map_error
from seif_gym.slam import SlamFilter, make_filter
from seif_gym.slam.models import wrap_angle

__all__ = ["SeifVsEkfReward"]


class SeifVsEkfReward(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Replace the reward by the growth of the SEIF's map error over a shadow EKF's on the same data.

    Parameters
    ----------
    env : gymnasium.Env
        An env whose ``unwrapped`` is a ``SeifExploreEnv`` (``gym.make``'s
        wrappers may sit in between).
    nees_weight : float, default 0
        Weight of the per-step term ``min(NEES_t, nees_cap) / 3`` of the SEIF's
        pose NEES (exact marginal covariance).
    nees_cap : float, default 100
        Cap of ``NEES_t`` in that term (one divergent step should not dominate).
    reference : str, default "ekf"
        The shadow filter (a name of ``seif_gym.slam.FILTERS``; "eif" gives the
        same estimates).

    Raises
    ------
    TypeError
        If ``env.unwrapped`` is not a ``SeifExploreEnv``.
    ValueError
        If ``nees_weight`` is negative or not finite, or ``nees_cap`` is not positive.
    """

    def __init__(self, env: gym.Env, nees_weight: float = 0.0, nees_cap: float = 100.0, reference: str = "ekf") -> None:
        gym.utils.RecordConstructorArgs.__init__(self, nees_weight=nees_weight, nees_cap=nees_cap, reference=reference)
        gym.Wrapper.__init__(self, env)
        if not isinstance(env.unwrapped, SeifExploreEnv):
            raise TypeError(f"SeifVsEkfReward needs a SeifExploreEnv inside, got {type(env.unwrapped).__name__}")
        nees_weight, nees_cap = float(nees_weight), float(nees_cap)
        if not (math.isfinite(nees_weight) and nees_weight >= 0):
            raise ValueError(f"nees_weight must be a finite number >= 0, got {nees_weight}")
        if not nees_cap > 0:
            raise ValueError(f"nees_cap must be positive, got {nees_cap}")
        self.nees_weight = nees_weight
        self.nees_cap = nees_cap
        self.reference = reference
        self.shadow: SlamFilter | None = None  # the shadow filter of the current episode
        self.gap = math.nan  # G_t

    # -- helpers ----------------------------------------------------------------------------------
    def _base(self) -> SeifExploreEnv:
        return cast(SeifExploreEnv, self.env.unwrapped)  # checked by the constructor

    def _shadow_error(self) -> float:
        base, shadow = self._base(), self.shadow
        if shadow is None or base.world is None:
            raise RuntimeError("call reset() first")
        return map_error(
            np.asarray(shadow.landmarks),
            base.world.landmarks,
            np.asarray(shadow.landmark_ids),
            base.reward_config.d_cap,
        )

    @staticmethod
    def _measurements(info: dict[str, Any]):
        ranges, bearings, ids = info["measurements"]
        return (
            np.asarray(ranges, dtype=np.float64),
            np.asarray(bearings, dtype=np.float64),
            np.asarray(ids, dtype=np.int64),
        )

    def _seif_nees(self, info: dict[str, Any]) -> float:
        filt = self._base().filter
        if filt is None:
            raise RuntimeError("call reset() first")
        error = np.asarray(info["true_pose"], dtype=np.float64) - np.asarray(filt.pose, dtype=np.float64)
        error[2] = wrap_angle(float(error[2]))
        try:
            value = float(error @ np.linalg.solve(np.asarray(filt.pose_covariance), error))
        except np.linalg.LinAlgError:
            return math.inf
        return value if value >= 0 else math.inf

    def _annotate(self, info: dict[str, Any], ekf_error: float) -> dict[str, Any]:
        info = dict(info)
        info["ekf_map_error"] = ekf_error
        info["map_error_gap"] = self.gap
        return info

    # -- gymnasium API ----------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        observation, info = self.env.reset(seed=seed, options=options)
        base = self._base()
        # the env's filter starts at the true start pose with the default covariance (as replay does)
        self.shadow = make_filter(
            self.reference, base.motion, base.sensor, np.asarray(info["true_pose"], dtype=np.float64)
        )
        self.shadow.update(*self._measurements(info))
        ekf_error = self._shadow_error()
        self.gap = float(info["map_error"]) - ekf_error
        return observation, self._annotate(info, ekf_error)

    def step(self, action):
        if self.shadow is None:
            raise RuntimeError("call reset() before step()")
        observation, _, terminated, truncated, info = self.env.step(action)
        base = self._base()
        self.shadow.predict(np.asarray(info["executed_control"], dtype=np.float64), base.robot_config.dt)
        self.shadow.update(*self._measurements(info))
        ekf_error = self._shadow_error()
        gap = float(info["map_error"]) - ekf_error
        reward = gap - self.gap
        self.gap = gap
        info = self._annotate(info, ekf_error)
        if self.nees_weight > 0:
            nees = self._seif_nees(info)
            info["seif_pose_nees"] = nees
            reward += self.nees_weight * min(nees, self.nees_cap) / 3.0
        return observation, float(reward), terminated, truncated, info
