"""Episodes as the sub-envs of one native vector env, the agent's forward passes batched over them.

:func:`run_batched_episodes` is the batched counterpart of :func:`~agents.evaluate.rollout.run_episode`:
sub-env ``e`` of a :class:`~seif_gym.envs.vector.SeifExploreVectorEnv` runs the episode of ``seeds[e]``
from ``reset(seed=seeds[e])``, and one ``predict`` call acts for every sub-env. Its rows equal
:func:`~agents.evaluate.rollout.run_episode`'s but for ``decision_time_ms``: the vector env equals
single envs bit for bit (``tests/env/test_vector_env.py``), the observation-only baselines act on each row
alone, and a saved policy runs inside :meth:`~agents.sb3_agent.SB3Agent.exact_batches`, where each
row's forward pass has the bits of that row alone. :func:`batch_refusal` says which agents cannot be
run so; :func:`batch_env` builds the vector env, or says why the configuration is not batched.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from agents.base import Agent
from agents.baselines import FrontierAgent, RevisitAgent
from agents.memories import needs_acting_env
from agents.sb3_agent import SB3Agent
from seif_gym.envs.vector import SeifExploreVectorEnv

__all__ = ["BATCHED_BASELINES", "batch_env", "batch_refusal", "batch_sizes", "run_batched_episodes"]

#: The baselines that act on a batch as on single envs: they read only the observation and the env's
#: geometry, and their memory is kept per batch row (``random``'s generator runs across episodes, and
#: ``info_gain`` plans with each env's filter, which the native vector env keeps in arrays).
BATCHED_BASELINES: tuple[type[Agent], ...] = (FrontierAgent, RevisitAgent)


def batch_refusal(agent: Agent) -> str | None:
    """Why ``agent`` cannot act on a batch of sub-envs with a serial run's rows; ``None`` when it can.

    Parameters
    ----------
    agent : Agent
        As :func:`agents.load_agent` builds it.

    Returns
    -------
    str or None
        A short reason (for a message), or ``None``: a saved SB3 model whose layers
        :meth:`~agents.sb3_agent.SB3Agent.exact_batches` runs row by row and whose own entries do not
        read the env it acts in, or one of :data:`BATCHED_BASELINES`.
    """
    if isinstance(agent, SB3Agent):
        if needs_acting_env(agent.model.observation_space):
            return "its own observation entries read the env it acts in"
        layers = agent.unbatchable_layers()
        if layers:
            return f"its layers {', '.join(layers)} are not batched row by row exactly"
        return None
    if type(agent) in BATCHED_BASELINES:
        return None
    if agent.carries_over_episodes:
        return "its state carries from one episode into the next"
    if agent.needs_filter:
        return "it plans with each env's filter, which the native vector env keeps in arrays"
    return f"a {type(agent).__name__} is not known to act on a batch as on single envs"


def batch_env(env_id: str, env_kwargs: Mapping[str, Any], num_envs: int) -> tuple[SeifExploreVectorEnv | None, str]:
    """The native vector env of ``num_envs`` sub-envs of ``env_id``, or ``None`` and why not.

    Parameters
    ----------
    env_id : str
        A registered env id.
    env_kwargs : mapping
        Keyword arguments of ``gym.make_vec`` (those of the single env, ``max_episode_steps`` included).
    num_envs : int
        Sub-envs.

    Returns
    -------
    env : SeifExploreVectorEnv or None
        A :class:`~seif_gym.envs.vector.SeifExploreVectorEnv` advanced by its compiled kernels; ``None``
        (the env closed) where ``gym.make_vec`` builds another vector env or the configuration runs
        as single envs (``backend == "sync"``: the ``-v0`` ids, the EKF and EIF filters, other data
        associations, ...).
    reason : str
        Why not (``""`` with an env).
    """
    env = gym.make_vec(env_id, num_envs=int(num_envs), **dict(env_kwargs))
    if not isinstance(env, SeifExploreVectorEnv):
        env.close()
        return None, f"{env_id} has no native vector env"
    backend = env.backend
    if backend == "compiled":
        return env, ""
    env.close()
    return None, f"the native vector env runs {env_id} with these settings as single envs (backend {backend!r})"


def batch_sizes(count: int, batch_size: int) -> list[int]:
    """``count`` episodes cut into the fewest batches of at most ``batch_size``, as even as can be.

    >>> batch_sizes(250, 100)
    [84, 83, 83]
    """
    batches = max(1, -(-int(count) // int(batch_size)))
    base, extra = divmod(int(count), batches)
    return [base + (1 if k < extra else 0) for k in range(batches) if base + (1 if k < extra else 0) > 0]


def run_batched_episodes(
    agent: Agent, env: SeifExploreVectorEnv, seeds: Sequence[int]
) -> list[tuple[dict[str, Any], list[float]]]:
    """The episodes of ``seeds``, sub-env ``e`` from ``env.reset(seed=seeds[e])``, deterministic actions.

    Each sub-env's row is what :func:`~agents.evaluate.rollout.run_episode` returns for its seed, with the
    same arithmetic per episode. Every step all sub-envs are stepped and ``agent.predict`` acts for all
    of them in one call (``episode_start`` set for all at the first, its ``state`` passed back); a
    sub-env whose episode has ended is ignored from then on (the env restarts it, the agent acts on
    it, neither is read) until every episode has ended.

    Parameters
    ----------
    agent : Agent
        An agent that acts on a batch as on single envs (:func:`batch_refusal` gives ``None``); a saved
        policy should run inside :meth:`~agents.sb3_agent.SB3Agent.exact_batches`. Its ``reset()``, if it
        has one, is called after the env's.
    env : SeifExploreVectorEnv
        A ``SeifExplore`` vector env of ``len(seeds)`` sub-envs (:func:`batch_env`).
    seeds : sequence of int
        Seeds of the sub-envs' ``reset``.

    Returns
    -------
    list of tuple
        Per seed, in order, ``(row, map_errors)`` as :func:`~agents.evaluate.rollout.run_episode` returns
        them; ``decision_time_ms`` is the mean over the episode's steps of a call's wall time divided by
        the sub-envs it acted for.

    Raises
    ------
    ValueError
        If ``seeds`` does not hold one seed per sub-env.
    """
    seeds = [int(seed) for seed in seeds]
    count = int(env.num_envs)
    if len(seeds) != count:
        raise ValueError(f"seeds must hold one seed per sub-env ({count}), got {len(seeds)}")
    observation, info = env.reset(seed=list(seeds))
    if hasattr(agent, "reset"):
        agent.reset()
    map_errors = [[float(info["map_error"][e])] for e in range(count)]
    squared = [[float(np.sum((info["true_pose"][e][:2] - info["pose_estimate"][e][:2]) ** 2))] for e in range(count)]
    total, thinking = [0.0] * count, [0.0] * count
    length, walls = [0] * count, [0] * count
    diverged = [False] * count
    rows: list[dict[str, Any] | None] = [None] * count
    running = list(range(count))
    state: Any = None
    start = np.ones(count, dtype=bool)
    while running:
        started = time.perf_counter()
        action, state = agent.predict(observation, state=state, episode_start=start, deterministic=True)
        share = (time.perf_counter() - started) / count
        start = np.zeros(count, dtype=bool)
        observation, reward, terminated, truncated, info = env.step(np.asarray(action).reshape(count, 2))
        still = []
        for e in running:
            thinking[e] += share
            total[e] += float(reward[e])
            length[e] += 1
            walls[e] += int(bool(info["wall_contact"][e]))
            diverged[e] = diverged[e] or bool(info["diverged"][e])
            map_errors[e].append(float(info["map_error"][e]))
            squared[e].append(float(np.sum((info["true_pose"][e][:2] - info["pose_estimate"][e][:2]) ** 2)))
            if not (terminated[e] or truncated[e]):
                still.append(e)
                continue
            rows[e] = {
                "seed": seeds[e],
                "final_map_error": map_errors[e][-1],
                "initial_map_error": map_errors[e][0],
                "pose_rmse": float(math.sqrt(np.mean(squared[e]))),
                "landmarks_mapped": int(info["landmarks_mapped"][e]),
                "landmarks_total": int(info["landmarks_total"][e]),
                "return": total[e],
                "length": length[e],
                "wall_contacts": walls[e],
                "diverged": int(diverged[e]),
                "decision_time_ms": 1e3 * thinking[e] / max(length[e], 1),
            }
        running = still
    return [(row, trace) for row, trace in zip(rows, map_errors) if row is not None]
