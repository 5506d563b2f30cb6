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

import copy
import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from agents.base import Agent
from agents.baselines import FrontierAgent, InfoGainAgent, RandomAgent, RevisitAgent
from agents.memories import needs_acting_env
from agents.sb3_agent import SB3Agent
from seif_gym.envs.vector import SeifExploreVectorEnv

__all__ = ["BATCHED_BASELINES", "batch_env", "batch_refusal", "batch_sizes", "run_batched_episodes"]

#: The baselines that act on a batch as on single envs: they read the observation and the env's geometry,
#: and their memory is kept per batch row; ``info_gain`` plans row ``e`` with a copy of sub-env ``e``'s
#: filter (:meth:`InfoGainAgent.bind`); ``random``'s one generator, which runs across the episodes in
#: order, is drawn ahead (:func:`run_batched_episodes`).
BATCHED_BASELINES: tuple[type[Agent], ...] = (FrontierAgent, RevisitAgent, InfoGainAgent, RandomAgent)


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
        return "it plans with each env's filter and cannot be given a vector env's"
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
) -> list[tuple[dict[str, Any], list[float], float, int]]:
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
        Per seed, in order, ``(row, map_errors, planning_seconds, plans)``: the row and trace as
        :func:`~agents.evaluate.rollout.run_episode` returns them (``decision_time_ms`` the mean over
        the episode's steps of a call's wall time divided by the sub-envs it acted for), and the wall
        time and number of the plans made for the episode by an agent that plans and times it
        (``info_gain``; ``0.0, 0`` for others).

    Raises
    ------
    ValueError
        If ``seeds`` does not hold one seed per sub-env.
    """
    seeds = [int(seed) for seed in seeds]
    count = int(env.num_envs)
    if len(seeds) != count:
        raise ValueError(f"seeds must hold one seed per sub-env ({count}), got {len(seeds)}")
    if type(agent) is RandomAgent:
        return _random_episodes(agent, env, seeds)
    observation, info = env.reset(seed=list(seeds))
    planner = agent if isinstance(agent, InfoGainAgent) else None
    if planner is not None:
        kept_envs = planner.envs
        planner.bind(env)  # row e plans with sub-env e's filter
    first_plan = len(planner.planning_times) if planner is not None else 0
    try:
        rows, map_errors, plans_at_end = _batched_rollout(agent, env, seeds, observation, info)
    finally:
        if planner is not None:
            planner.envs = kept_envs
    planning = [0.0] * count
    plans = [0] * count
    if planner is not None:
        made = zip(planner.planning_times[first_plan:], planner.planning_rows[first_plan:])
        for number, (seconds, row) in enumerate(made, start=first_plan):
            if number < plans_at_end[row]:  # a finished sub-env's row is acted on until all have finished
                planning[row] += seconds
                plans[row] += 1
    return [(row, trace, planning[e], plans[e]) for e, (row, trace) in enumerate(zip(rows, map_errors))]


class _DrawnAhead:
    """``random``'s actions for a batch: row ``e`` at step ``t`` takes draw ``offsets[e] + t`` of ``draws``.

    What :func:`_batched_rollout` calls of an agent (``predict``). A row past the draws (its speculated
    episode ran longer than the draws cover) takes the last one; :func:`_random_episodes` never keeps
    such a row.
    """

    def __init__(self, draws: np.ndarray, offsets: np.ndarray) -> None:
        self.draws, self.offsets, self.step = draws, offsets, 0

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]:  # fmt: skip
        rows = np.minimum(self.offsets + self.step, len(self.draws) - 1)
        self.step += 1
        actions = np.empty((len(rows), 2), dtype=np.float32)
        actions[:] = np.clip(self.draws[rows], -1.0, 1.0)  # RandomAgent.predict's clip and float32
        return actions, state


def _random_episodes(agent: RandomAgent, env: SeifExploreVectorEnv,
                     seeds: list[int]) -> list[tuple[dict[str, Any], list[float], float, int]]:  # fmt: skip
    """:func:`run_batched_episodes` of ``random``: the rows its one generator gives the episodes in order.

    Serially, episode ``k`` takes the draws after those of the episodes before it: 2 uniforms a step,
    ``2 L_j`` for an episode of ``L_j`` steps. Its actions do not depend on the observations, so the
    draws are made ahead (from a copy of the generator: ``uniform`` fills an array with the values
    one call at a time would give) and each episode is offset by the lengths before it, speculated
    to be the time limit ``T``. An episode that ends before ``T`` (a diverged filter) makes the
    offsets of the later ones wrong: those are run again with the lengths now known, until every
    row's offset is exact (each pass fixes at least one more row). At the end the agent's generator
    is advanced past the draws the episodes took, as a serial run leaves it.
    """
    count = len(seeds)
    limit = env.max_episode_steps
    if limit is None:
        raise ValueError("random's episodes are batched under a time limit: make the vector env with max_episode_steps")
    draws = copy.deepcopy(agent.rng).uniform(-1.0, 1.0, (count * limit, 2))
    done: list[tuple[dict[str, Any], list[float], float, int]] = []
    used = 0  # draws taken by the episodes in `done`
    while len(done) < count:
        pending = seeds[len(done) :]
        padded = pending + [pending[-1]] * (count - len(pending))  # the vector env's other rows: not read
        offsets = used + limit * np.arange(count, dtype=np.int64)
        observation, info = env.reset(seed=list[int | None](padded))
        rows, traces, _ = _batched_rollout(_DrawnAhead(draws, offsets), env, padded, observation, info)
        for row, trace in zip(rows[: len(pending)], traces):
            done.append((row, trace, 0.0, 0))
            used += int(row["length"])
            if row["length"] != limit:  # the next rows' offsets assumed `limit` steps here
                break
    agent.rng.uniform(-1.0, 1.0, (used, 2))  # the generator where a serial run leaves it
    return done


def _batched_rollout(agent: Agent | _DrawnAhead, env: SeifExploreVectorEnv, seeds: list[int], observation: dict[str, Any],
                     info: dict[str, Any]) -> tuple[list[dict[str, Any]], list[list[float]], list[int]]:  # fmt: skip
    """:func:`run_batched_episodes`' loop from the reset's ``observation`` and ``info``.

    Returns the rows, the map-error traces and, per row, how many plans the agent had made
    (``len(agent.planning_times)``) when its episode ended.
    """
    count = len(seeds)
    if hasattr(agent, "reset"):
        agent.reset()
    map_errors = [[float(info["map_error"][e])] for e in range(count)]
    squared = [[float(np.sum((info["true_pose"][e][:2] - info["pose_estimate"][e][:2]) ** 2))] for e in range(count)]
    total, thinking = [0.0] * count, [0.0] * count
    length, walls = [0] * count, [0] * count
    diverged = [False] * count
    rows: list[dict[str, Any] | None] = [None] * count
    plans_at_end = [0] * count
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
            plans_at_end[e] = len(getattr(agent, "planning_times", ()))
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
    assert all(row is not None for row in rows)  # the loop ends when every episode has
    return rows, map_errors, plans_at_end  # type: ignore[return-value]
