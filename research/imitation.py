"""Kickstarting PPO from a baseline: behaviour cloning with DAgger, then reinforcement learning.

On the large world PPO from scratch never learns to cover 40 m, while the
``info_gain`` planner does; on the other tasks a policy that starts where the
best baseline is has only to improve on it. Kickstarting (Schmitt et al.,
2018, "Kickstarting deep reinforcement learning") starts the learner from the
teacher: here the policy network is first fitted to the teacher's actions
(behaviour cloning), on the teacher's own episodes and then, DAgger-style
(Ross et al., AISTATS 2011), on episodes the learner drives while the
teacher labels every state it visits, so that the clone learns to recover
from its own mistakes. PPO then trains from there (``python -m
research.kickstart``).

What is fitted, on the observations exactly as the training envs give them
(the config's ``env_wrapper`` applied):

* the actor, by maximum likelihood of the teacher's action under the policy's
  Gaussian (its mean *and* its log standard deviation);
* the critic, by regression on the discounted return of the normalised
  training reward, with the reward statistics (``VecNormalize.ret_rms``)
  computed from the same episodes, so that PPO's first advantages are not
  those of an untrained critic.

The teacher acts in a copy of the env it labels (``info_gain`` plans with
that env's filter); it sees every step whoever drives, so its memory
(visited cells, the arc it is holding) follows the episode.

>>> from research.imitation import discounted_returns
>>> discounted_returns([1.0, 1.0, 1.0], [False, False, True], gamma=0.5).tolist()
[1.75, 1.5, 1.0]
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import ArrayLike

from agents.baselines import BASELINES, Agent, make_agent
from research.oracle import CoverageOracle
from seif_gym.validation import as_count

__all__ = [
    "TEACHERS",
    "Demonstrations",
    "behaviour_clone",
    "collect_demonstrations",
    "discounted_returns",
    "kickstart",
    "make_teacher",
    "round_seeds",
    "running_returns",
]


@dataclass
class Demonstrations:
    """States visited, the teacher's action in each, and the episodes' rewards.

    Attributes
    ----------
    observations : dict of str to ndarray
        Each observation entry stacked over the steps (``(n, ...)``).
    actions : ndarray, shape (n, 2)
        The teacher's action in each state (the label).
    rewards : ndarray, shape (n,)
        The reward of the step taken from each state (of the action driven,
        which is the teacher's on its own episodes).
    dones : ndarray of bool, shape (n,)
        Whether the step from this state ended its episode.
    """

    observations: dict[str, np.ndarray]
    actions: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray

    def __len__(self) -> int:
        return int(self.actions.shape[0])

    @staticmethod
    def concatenate(parts: Sequence[Demonstrations]) -> Demonstrations:
        """The steps of ``parts``, one after another."""
        if not parts:
            raise ValueError("parts must hold at least one Demonstrations")
        keys = parts[0].observations.keys()
        return Demonstrations(
            observations={key: np.concatenate([p.observations[key] for p in parts]) for key in keys},
            actions=np.concatenate([p.actions for p in parts]),
            rewards=np.concatenate([p.rewards for p in parts]),
            dones=np.concatenate([p.dones for p in parts]),
        )


def discounted_returns(rewards: ArrayLike, dones: ArrayLike, gamma: float) -> np.ndarray:
    """``G_t = r_t + gamma * G_{t+1}``, restarted after every ``done`` (the episode's end)."""
    reward = np.asarray(rewards, dtype=np.float64)
    done = np.asarray(dones, dtype=bool)
    if reward.shape != done.shape or reward.ndim != 1:
        raise ValueError(f"rewards and dones must be 1-D of one length, got {reward.shape} and {done.shape}")
    returns = np.empty_like(reward)
    following = 0.0
    for t in range(reward.shape[0] - 1, -1, -1):
        following = reward[t] + (0.0 if done[t] else gamma * following)
        returns[t] = following
    return returns


#: What can teach: the baselines, and the coverage oracle (privileged: it reads the true state).
TEACHERS: tuple[str, ...] = (*BASELINES, CoverageOracle.name)


def make_teacher(name: str, env: gym.Env, *, seed: int) -> Agent:
    """The teacher ``name`` (one of :data:`TEACHERS`) acting in ``env``; ``random`` draws from ``seed``.

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`TEACHERS`.
    """
    if name == CoverageOracle.name:
        return CoverageOracle(env)
    if name not in BASELINES:
        raise ValueError(f"teacher: unknown {name!r}; teachers: {', '.join(TEACHERS)}")
    return make_agent(name, env, **({"seed": seed} if name == "random" else {}))


def collect_demonstrations(
    make_env: Callable[[], gym.Env],
    teacher: str,
    seeds: Sequence[int],
    learner: Callable[[Mapping[str, np.ndarray]], np.ndarray] | None = None,
) -> Demonstrations:
    """Episodes from ``env.reset(seed=s)`` for each seed, every state labelled with the teacher's action.

    Parameters
    ----------
    make_env : callable
        Builds one training env (the config's wrappers applied).
    teacher : str
        One of :data:`TEACHERS`.
    seeds : sequence of int
        One episode per seed.
    learner : callable, optional
        Maps an observation to the action that drives the episode (DAgger);
        ``None``: the teacher drives.
    """
    parts = []
    for seed in seeds:
        env = make_env()
        try:
            agent = make_teacher(teacher, env, seed=int(seed))
            observation, _ = env.reset(seed=int(seed))
            agent.reset()
            observations: list[dict[str, np.ndarray]] = []
            actions, rewards, dones = [], [], []
            while True:
                label = np.asarray(agent.predict(observation, deterministic=True)[0], dtype=np.float32).reshape(2)
                action = label if learner is None else np.asarray(learner(observation), dtype=np.float32).reshape(2)
                observations.append({key: np.array(value) for key, value in observation.items()})
                actions.append(label)
                observation, reward, terminated, truncated, _ = env.step(action)
                rewards.append(float(reward))
                dones.append(bool(terminated or truncated))
                if dones[-1]:
                    break
        finally:
            env.close()
        parts.append(
            Demonstrations(
                observations={key: np.stack([o[key] for o in observations]) for key in observations[0]},
                actions=np.stack(actions),
                rewards=np.asarray(rewards),
                dones=np.asarray(dones),
            )
        )
    return Demonstrations.concatenate(parts)


def running_returns(demonstrations: Demonstrations, gamma: float) -> np.ndarray:
    """The running discounted return ``R_t = gamma * R_{t-1} + r_t`` (restarted after each episode's end).

    What ``VecNormalize`` accumulates per env and feeds to its reward statistics
    (``ret_rms``), step by step.
    """
    running = 0.0
    values = np.empty(len(demonstrations))
    for t, (reward, done) in enumerate(zip(demonstrations.rewards, demonstrations.dones, strict=True)):
        running = running * gamma + reward
        values[t] = running
        if done:
            running = 0.0
    return values


def behaviour_clone(
    policy: Any,
    demonstrations: Demonstrations,
    *,
    value_targets: np.ndarray | None = None,
    epochs: int = 10,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    vf_coef: float = 0.5,
    seed: int = 0,
) -> list[float]:
    """Fit ``policy`` (an SB3 ``ActorCriticPolicy``) to the teacher's actions (and the values); mean loss per epoch.

    Notes
    -----
    Loss per batch: ``-mean(log π(a_teacher | s)) + vf_coef * mean((V(s) - G)^2)``,
    the second term over the steps whose ``value_targets`` are finite (none
    without them), Adam, in minibatches.
    """
    import torch

    n = len(demonstrations)
    if n == 0:
        raise ValueError("demonstrations: no steps")
    if int(epochs) < 1 or int(batch_size) < 1:
        raise ValueError(f"epochs and batch_size must be positive, got {epochs} and {batch_size}")
    if value_targets is not None and np.shape(value_targets) != (n,):
        raise ValueError(f"value_targets must have shape ({n},), got {np.shape(value_targets)}")
    generator = np.random.default_rng(seed)
    optimizer = torch.optim.Adam(policy.parameters(), lr=learning_rate)
    policy.set_training_mode(True)
    losses = []
    for _ in range(int(epochs)):
        order = generator.permutation(n)
        total = 0.0
        for start in range(0, n, int(batch_size)):
            rows = order[start : start + int(batch_size)]
            observation, _ = policy.obs_to_tensor({k: v[rows] for k, v in demonstrations.observations.items()})
            actions = torch.as_tensor(demonstrations.actions[rows], device=policy.device)
            values, log_prob, _ = policy.evaluate_actions(observation, actions)
            loss = -log_prob.mean()
            if value_targets is not None and np.isfinite(value_targets[rows]).any():
                known = np.isfinite(value_targets[rows])
                target = torch.as_tensor(value_targets[rows][known], dtype=torch.float32, device=policy.device)
                picked = values.flatten()[torch.as_tensor(known, device=policy.device)]
                loss = loss + vf_coef * torch.mean((picked - target) ** 2)
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
            optimizer.step()
            total += loss.item() * rows.size
        losses.append(total / n)
    policy.set_training_mode(False)
    return losses


def round_seeds(seeds: Sequence[int], dagger_rounds: int) -> list[np.ndarray]:
    """``seeds`` split evenly into the teacher's episodes and each of ``dagger_rounds`` DAgger rounds.

    >>> [batch.tolist() for batch in round_seeds([1, 2, 3, 4, 5], dagger_rounds=1)]
    [[1, 2, 3], [4, 5]]
    """
    rounds = as_count(dagger_rounds, "dagger_rounds") + 1
    if len(seeds) < rounds:
        raise ValueError(f"seeds: need at least {rounds} (one per round), got {len(seeds)}")
    return np.array_split(np.asarray([int(s) for s in seeds]), rounds)


def kickstart(
    model: Any,
    make_env: Callable[[], gym.Env],
    teacher: str,
    *,
    seeds: Sequence[int],
    dagger_rounds: int = 2,
    epochs: int = 10,
    log: Callable[[str], None] | None = None,
) -> Demonstrations:
    """Clone ``teacher`` into ``model`` (an SB3 PPO model): teacher episodes, then ``dagger_rounds`` DAgger rounds.

    The seeds are split evenly between the teacher's episodes and each
    round. The reward statistics of ``model``'s ``VecNormalize`` (if it
    normalises rewards) are set from the teacher's episodes, and the critic
    is fitted to their normalised returns. Returns every labelled step.
    """
    batches = round_seeds(seeds, dagger_rounds)
    first = int(batches[0][0])  # seeds each round's minibatch order
    gamma = float(model.gamma)
    vec_normalize = model.get_vec_normalize_env()
    say = log if log is not None else (lambda _: None)

    teacher_demos = collect_demonstrations(make_env, teacher, batches[0].tolist())
    rewards = teacher_demos.rewards
    if vec_normalize is not None and vec_normalize.norm_reward:
        from stable_baselines3.common.running_mean_std import RunningMeanStd

        vec_normalize.ret_rms = RunningMeanStd(shape=())
        vec_normalize.ret_rms.update(running_returns(teacher_demos, gamma))
        rewards = vec_normalize.normalize_reward(rewards)  # as PPO will see them
    returns = discounted_returns(rewards, teacher_demos.dones, gamma)
    say(f"kickstart: {len(teacher_demos)} teacher steps")
    losses = behaviour_clone(model.policy, teacher_demos, value_targets=returns, epochs=epochs, seed=first)
    say(f"kickstart: cloned, loss {losses[0]:.3f} -> {losses[-1]:.3f}")
    every, targets = teacher_demos, returns

    def drive(observation: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.asarray(model.predict(dict(observation), deterministic=True)[0])

    for k in range(1, len(batches)):
        visited = collect_demonstrations(make_env, teacher, batches[k].tolist(), learner=drive)
        every = Demonstrations.concatenate([every, visited])
        # the critic keeps to the teacher's returns (the value of the teacher's policy); the
        # learner's visits are labelled with actions only
        targets = np.concatenate([targets, np.full(len(visited), np.nan)])
        losses = behaviour_clone(model.policy, every, value_targets=targets, epochs=epochs, seed=first + k)
        say(f"kickstart: DAgger round {k}, {len(every)} steps, loss {losses[0]:.3f} -> {losses[-1]:.3f}")
    return every
