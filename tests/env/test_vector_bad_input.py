"""Bad input to ``SeifExploreVectorEnv`` gets a TypeError/ValueError naming the argument, and no sub-env moves.

Both backends (the compiled one and the ``SyncVectorEnv`` of single envs) check ``actions`` and reset's
``options`` and ``seed`` before anything changes. "Unchanged" is asserted twice: every array of the
compiled state is bit-identical after the refusal, and the env then goes on exactly as a twin that never
saw the bad call (observations, rewards and infos equal bit for bit).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from seif_gym.envs.vector import SeifExploreVectorEnv

BACKENDS = {"compiled": {}, "sync": {"filter": "ekf"}}

BAD_ACTIONS = {
    "string": ("left", TypeError, "actions must be one row of 2 real numbers"),
    "None": (None, TypeError, "actions"),
    "ragged": ([[0.1, 0.2], [0.3]], TypeError, "actions"),
    "string dtype": (np.array([["a", "b"], ["c", "d"]]), TypeError, "actions .*dtype <U1"),
    "object dtype": (np.array([[0.1, None], [0.2, 0.3]], dtype=object), TypeError, "actions .*dtype object"),
    "bool dtype": (np.ones((2, 2), dtype=bool), TypeError, "actions .*dtype bool"),
    "complex dtype": (np.ones((2, 2), dtype=complex), TypeError, "actions .*dtype complex128"),
    "one row": (np.zeros(2), ValueError, r"actions must have shape \(2, 2\), got \(2,\)"),
    "three columns": (np.zeros((2, 3)), ValueError, r"actions must have shape \(2, 2\)"),
    "NaN": (np.array([[0.5, 0.0], [math.nan, 0.0]]), ValueError, r"actions must be finite, got non-finite rows \[1\]"),
    "inf": (np.array([[math.inf, 0.0], [0.0, 0.0]]), ValueError, r"actions must be finite.*\[0\]"),
}
BAD_RESETS = {
    "unknown option": ({"options": {"layout": "ring"}}, ValueError, r"options has unknown key\(s\) \['layout'\]"),
    "options not a mapping": ({"options": ["layout"]}, TypeError, "options must be a dict or None"),
    "negative seed": ({"seed": -5}, ValueError, "seed must be a non-negative int"),
    "negative seed in a list": ({"seed": [1, -5]}, ValueError, "seed must list a non-negative int"),
    "float seed in a list": ({"seed": [1, 2.5]}, ValueError, "seed"),
    "seed list of the wrong length": ({"seed": [1, 2, 3]}, ValueError, "seed must be an int, None or a list of 2"),
}


def make(backend: str) -> SeifExploreVectorEnv:
    env = SeifExploreVectorEnv(2, max_episode_steps=20, **BACKENDS[backend])
    assert env.backend == backend
    return env


def compiled_state(env: SeifExploreVectorEnv) -> dict[str, object]:
    """Every array of the compiled state (worlds, batched filters, coverage, observations), raw."""
    state: dict[str, object] = {}
    if env._sync is not None:
        return state
    for prefix, owner in (("env", env), ("world", env._world), ("filters", env._filters)):
        for name, value in vars(owner).items():
            if isinstance(value, np.ndarray):
                state[f"{prefix}.{name}"] = (value.dtype.str, value.shape, value.tobytes())
            elif isinstance(value, dict) and all(isinstance(v, np.ndarray) for v in value.values()):
                for key, array in value.items():
                    state[f"{prefix}.{name}.{key}"] = (array.dtype.str, array.shape, array.tobytes())
    return state


def assert_same_steps(env: SeifExploreVectorEnv, twin: SeifExploreVectorEnv, steps: int = 3) -> None:
    for k in range(steps):
        actions = np.array([[0.6, 0.1 * k], [0.4, -0.2]])
        a, b = env.step(actions), twin.step(actions)
        for key in a[0]:
            np.testing.assert_array_equal(a[0][key], b[0][key], err_msg=key)
        for left, right in zip(a[1:4], b[1:4]):
            np.testing.assert_array_equal(left, right)
        for key in ("pose_error", "map_error"):
            if key in a[4]:
                np.testing.assert_array_equal(a[4][key], b[4][key], err_msg=key)


@pytest.mark.parametrize("backend", sorted(BACKENDS))
@pytest.mark.parametrize("case", sorted(BAD_ACTIONS))
def test_bad_actions_are_refused_and_nothing_moves(backend, case):
    actions, error, match = BAD_ACTIONS[case]
    env, twin = make(backend), make(backend)
    env.reset(seed=4)
    twin.reset(seed=4)
    env.step(np.full((2, 2), 0.3))
    twin.step(np.full((2, 2), 0.3))
    before = compiled_state(env)
    with pytest.raises(error, match=match):
        env.step(actions)
    assert compiled_state(env) == before
    assert_same_steps(env, twin)
    env.close()
    twin.close()


@pytest.mark.parametrize("backend", sorted(BACKENDS))
@pytest.mark.parametrize("case", sorted(BAD_RESETS))
def test_bad_reset_arguments_are_refused_and_nothing_is_reset(backend, case):
    kwargs, error, match = BAD_RESETS[case]
    env, twin = make(backend), make(backend)
    env.reset(seed=4)
    twin.reset(seed=4)
    env.step(np.full((2, 2), 0.3))
    twin.step(np.full((2, 2), 0.3))
    before = compiled_state(env)
    with pytest.raises(error, match=match):
        env.reset(**kwargs)
    assert compiled_state(env) == before
    assert_same_steps(env, twin)
    env.close()
    twin.close()


@pytest.mark.parametrize("backend", sorted(BACKENDS))
def test_empty_options_and_integer_actions_are_accepted(backend):
    """``{}`` is no option; integer actions are real numbers (the same values as floats)."""
    env, twin = make(backend), make(backend)
    env.reset(seed=[3, None if backend == "sync" else 9], options={})
    twin.reset(seed=[3, None if backend == "sync" else 9])
    if backend == "compiled":
        a, b = env.step(np.array([[1, 0], [0, -1]])), twin.step(np.array([[1.0, 0.0], [0.0, -1.0]]))
        np.testing.assert_array_equal(a[1], b[1])
    env.close()
    twin.close()
