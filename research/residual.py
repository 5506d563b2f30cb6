"""A residual on the ``info_gain`` planner: the policy corrects the planner's action.

Residual policy learning (Silver et al., 2018, "Residual policy learning";
Johannink et al., ICRA 2019, "Residual reinforcement learning for robot
control") starts a learner from a controller that already works: the action
executed is the controller's plus the policy's, so a policy whose output is
zero *is* the controller, and reinforcement learning only has to find the
corrections that pay. Here the controller is the ``info_gain`` planner
(:class:`agents.baselines.InfoGainAgent`, the strongest baseline on the large
world), which plans with the env's filter, that is with the belief the
observation shows and never the truth.

The policy sees the planner's action as the observation entry
:data:`PLANNER_ACTION`; its own action ``r`` is the residual, and the env
executes ``clip(planner_action + r, -1, 1)``. Training adds both with
:class:`PlannerResidualAction` (an ``env_wrapper`` of a config, outermost);
on the plain env :class:`PlannerResidual` does the same on the agent's side
(:func:`agents.memories.policy_memories`, used by
:class:`agents.evaluate.SB3Agent` and the validation callback), with the env
the agent acts in (the planner reads its filter).

>>> import gymnasium as gym
>>> import numpy as np
>>> import seif_gym
>>> from agents.baselines import make_agent
>>> from research.residual import PLANNER_ACTION, PlannerResidualAction
>>> env = PlannerResidualAction(gym.make("SeifExplore-v2"))
>>> planner_env = gym.make("SeifExplore-v2")
>>> planner = make_agent("info_gain", planner_env)
>>> observation, _ = env.reset(seed=4)
>>> expected, _ = planner_env.reset(seed=4)
>>> for _ in range(3):  # a zero residual is the planner, bit for bit
...     action, _ = planner.predict(expected)
...     same = bool((observation[PLANNER_ACTION] == action).all())
...     observation, *_ = env.step(np.zeros(2, dtype=np.float32))
...     expected, *_ = planner_env.step(action)
>>> same, bool((observation["pose"] == expected["pose"]).all())
(True, True)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from agents.baselines import InfoGainAgent
from agents.entries import holds_entry, with_entry
from agents.memories import PolicyEntry, register_policy_entry

__all__ = ["PLANNER_ACTION", "PlannerResidual", "PlannerResidualAction", "uses_planner_action"]

#: The observation key of the planner's action: ``info_gain``'s ``(v, ω)`` action in ``[-1, 1]``, shape ``(2,)``.
PLANNER_ACTION = "planner_action"


def uses_planner_action(observation_space: Any) -> bool:
    """Whether ``observation_space`` (a policy's) holds the :data:`PLANNER_ACTION` entry."""
    return holds_entry(observation_space, PLANNER_ACTION)


class PlannerResidual:
    """The agent's side of the residual: the planner's action in, the executed action out.

    Parameters
    ----------
    env : gymnasium.Env, sequence of them, or a ``DummyVecEnv``
        The env(s) the policy acts in (env ``i`` serves batch row ``i``): the
        planner plans with their filter, so a probe of the task will not do.

    Notes
    -----
    Per step, :meth:`observe` (with the observation the action is chosen
    on) adds the planner's action ``a_p`` and :meth:`act` turns the policy's
    residual ``r`` into the executed ``clip(a_p + r, -1, 1)``, which the
    planner is told (its bump check compares the motion with the speed
    commanded).
    """

    def __init__(self, env: Any) -> None:
        self.planner = InfoGainAgent(env)
        self._plan: np.ndarray | None = None

    def reset(self, index: int | None = None) -> None:
        """Env ``index`` (every env when ``None``) starts a new episode."""
        self.planner.reset(index)
        self._plan = None

    def observe(self, observation: Mapping[str, np.ndarray], episode_start: Any = None) -> dict[str, np.ndarray]:
        """``observation`` (single or batched) with :data:`PLANNER_ACTION` added: the planner's action for it."""
        if PLANNER_ACTION in observation:  # a wrapped env's (its wrapper plans): act sums with that plan
            self._plan = np.asarray(observation[PLANNER_ACTION], dtype=np.float32).copy()
            return dict(observation)
        plan, _ = self.planner.predict(observation, episode_start=episode_start, deterministic=True)
        self._plan = np.asarray(plan, dtype=np.float32)
        return {**observation, PLANNER_ACTION: self._plan.copy()}

    def act(self, residual: Any) -> np.ndarray:
        """The executed action ``clip(planner_action + residual, -1, 1)`` (float32, the residual's shape).

        Raises
        ------
        RuntimeError
            Before :meth:`observe` has seen the step's observation.
        ValueError
            If ``residual``'s shape is not the planner action's.
        """
        if self._plan is None:
            raise RuntimeError("residual: observe the step's observation before acting on it")
        residual = np.asarray(residual, dtype=np.float32)
        if residual.shape != self._plan.shape:
            raise ValueError(f"residual must have the planner action's shape {self._plan.shape}, got {residual.shape}")
        executed = np.clip(self._plan + residual, -1.0, 1.0).astype(np.float32)
        for index, action in enumerate(executed.reshape(-1, 2)):
            self.planner.executed(action, index)
        self._plan = None  # one action per observation
        return executed


class PlannerResidualAction(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Add :data:`PLANNER_ACTION` to the observation and execute ``clip(planner_action + action, -1, 1)``.

    Parameters
    ----------
    env : gymnasium.Env
        A ``SeifExplore`` env with a ``Dict`` observation space (wrapped or
        not); the planner plans with its filter. Put this wrapper outermost,
        so that the policy's action is the residual.
    """

    def __init__(self, env: gym.Env) -> None:
        space = with_entry(
            env.observation_space, PLANNER_ACTION, gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        )
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.observation_space = space
        self.residual = PlannerResidual(env)

    def reset(self, **kwargs: Any):
        observation, info = self.env.reset(**kwargs)
        self.residual.reset()
        return self.residual.observe(observation, episode_start=True), info

    def step(self, action):
        executed = self.residual.act(action)
        observation, reward, terminated, truncated, info = self.env.step(executed)
        return self.residual.observe(observation), reward, terminated, truncated, info


# last, as in training (outermost): the planner sees the observation the inner entries made
register_policy_entry(
    PolicyEntry(
        PLANNER_ACTION, uses_planner_action, PlannerResidual, PlannerResidualAction, order=2.0, needs_acting_env=True
    )  # fmt: skip
)
