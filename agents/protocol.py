"""The benchmark protocol's constants: seed splits and episode counts, in one place.

Training, selection, evaluation, the leaderboard and the showcase import them
from here (the protocol itself: the docs' Benchmark section).

==========  ==========================================  =====================================
split       seeds                                       used for
==========  ==========================================  =====================================
training    every seed below :data:`VALIDATION_SEED`    learning
validation  :data:`VALIDATION_SEED` onwards             choosing checkpoints, hyperparameters
held out    :data:`HELD_OUT_SEEDS`                      reporting only
==========  ==========================================  =====================================
"""

from __future__ import annotations

import gymnasium as gym

__all__ = [
    "DECLARED_HELD_OUT_EPISODES",
    "HELD_OUT_EPISODES",
    "HELD_OUT_SEED",
    "HELD_OUT_SEEDS",
    "LONG_TASK_DECLARED_HELD_OUT_EPISODES",
    "SHORT_TASK_HELD_OUT_EPISODES",
    "SHORT_TASK_STEPS",
    "VALIDATION_EPISODES",
    "VALIDATION_SEED",
    "declared_held_out_episodes",
    "held_out_episodes",
]

#: First held-out seed of the protocol (reporting only).
HELD_OUT_SEED = 1_000_000
#: First validation seed of the protocol (checkpoint and hyperparameter selection).
VALIDATION_SEED = 500_000
#: Episodes of each split: held-out ``HELD_OUT_SEED`` … ``+ 99`` (on the tasks longer than
#: :data:`SHORT_TASK_STEPS`), validation ``VALIDATION_SEED`` … ``+ 99``.
HELD_OUT_EPISODES = VALIDATION_EPISODES = 100
#: Tasks of at most this many steps (the budgets) are *short*: their held-out split is
#: :data:`SHORT_TASK_HELD_OUT_EPISODES` episodes.
SHORT_TASK_STEPS = 150
#: Held-out episodes of a short task: more than a long task's, because a short episode's paired
#: differences are wide relative to the leads they decide (docs/benchmark/protocol.md, "Statistics").
SHORT_TASK_HELD_OUT_EPISODES = 400
#: Held-out episodes an experiment may declare on a short task, beyond the leaderboard's
#: :data:`SHORT_TASK_HELD_OUT_EPISODES`, so that the paired rule can tell leads of 0.02–0.03 m
#: (docs/benchmark/protocol.md, "Statistics"); the count is fixed before the recipe trains.
#: The most any experiment may declare.
DECLARED_HELD_OUT_EPISODES = 1600
#: Held-out episodes an experiment may declare on a task longer than :data:`SHORT_TASK_STEPS`, to
#: resolve smaller leads than the leaderboard's 100 (docs/benchmark/protocol.md, "Statistics").
LONG_TASK_DECLARED_HELD_OUT_EPISODES = 400
#: Every held-out seed of the protocol (the most any task or declared experiment uses): nothing may be chosen on them.
HELD_OUT_SEEDS = range(
    HELD_OUT_SEED,
    HELD_OUT_SEED
    + max(
        HELD_OUT_EPISODES,
        SHORT_TASK_HELD_OUT_EPISODES,
        DECLARED_HELD_OUT_EPISODES,
        LONG_TASK_DECLARED_HELD_OUT_EPISODES,
    ),
)


def _is_short_task(env_id: str) -> bool:
    """Whether ``env_id`` is a short task (at most :data:`SHORT_TASK_STEPS` steps); checks the id."""
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be a str, got {type(env_id).__name__}")
    try:
        steps = gym.spec(env_id).max_episode_steps
    except gym.error.Error:
        raise ValueError(f"env_id: unknown env {env_id!r}") from None
    return steps is not None and steps <= SHORT_TASK_STEPS


def held_out_episodes(env_id: str) -> int:
    """The protocol's held-out episodes of ``env_id``: 400 on the short tasks (the budgets), 100 on the others.

    Raises
    ------
    TypeError
        If ``env_id`` is not a string.
    ValueError
        If ``env_id`` is not registered.
    """
    return SHORT_TASK_HELD_OUT_EPISODES if _is_short_task(env_id) else HELD_OUT_EPISODES


def declared_held_out_episodes(env_id: str) -> int:
    """The held-out episodes an experiment on ``env_id`` may declare before its recipe trains.

    1600 on the short tasks (:data:`DECLARED_HELD_OUT_EPISODES`), 400 on the others
    (:data:`LONG_TASK_DECLARED_HELD_OUT_EPISODES`): seeds ``HELD_OUT_SEED`` onwards, the
    leaderboard's among them. The leaderboard keeps :func:`held_out_episodes`.

    Raises
    ------
    TypeError, ValueError
        As :func:`held_out_episodes`.
    """
    return DECLARED_HELD_OUT_EPISODES if _is_short_task(env_id) else LONG_TASK_DECLARED_HELD_OUT_EPISODES
