"""A check shared by the tests of the policy-side entries (the budget's clock, the coverage memory)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np


def assert_acts_as_trained(agent: Any, predict: Callable, training_env: Any, env: Any, seeds: Iterable[int],
                           steps: int) -> None:  # fmt: skip
    """``agent`` on the plain ``env`` takes the actions ``predict`` (the model's own) takes on ``training_env``'s observations."""
    for seed in seeds:
        observation, _ = training_env.reset(seed=seed)
        plain_observation, _ = env.reset(seed=seed)
        agent.reset()
        for step in range(steps):
            expected, _ = predict(observation, deterministic=True)
            action, _ = agent.predict(plain_observation, episode_start=np.array([step == 0]), deterministic=True)
            np.testing.assert_array_equal(action, expected)
            observation, *_ = training_env.step(action)
            plain_observation, *_ = env.step(action)
