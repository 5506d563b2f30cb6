"""Bad input to SeifExploreEnv: a clear error naming the argument, raised before any state changes."""

from __future__ import annotations

import numpy as np
import pytest

from seif_gym.envs.explore import MAX_COVERAGE_CELLS, MAX_LANDMARKS, SeifExploreEnv
from seif_gym.world import MAX_ARENA_SIZE, WorldConfig


def _rollout(env: SeifExploreEnv) -> list[np.ndarray]:
    observation, _, _, _, info = env.step(np.array([0.5, 0.2]))
    return [observation["pose"], observation["landmarks"], np.array([info["map_error"]]), env.filter.pose]


def _same(a: list[np.ndarray], b: list[np.ndarray]) -> None:
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("arena_size", [1e9, MAX_ARENA_SIZE * 1.01, 0.01, 4.0, -1.0, float("nan"), float("inf")])
def test_arena_size_out_of_range_names_arena_size(arena_size):
    with pytest.raises(ValueError, match="arena_size") as caught:
        SeifExploreEnv(arena_size=arena_size)
    assert not str(caught.value).startswith("wall_margin")


def test_arena_size_not_a_number_is_a_type_error():
    with pytest.raises(TypeError, match="arena_size"):
        SeifExploreEnv(arena_size="20")


def test_coverage_grid_bound_names_both_arguments():
    with pytest.raises(ValueError, match="arena_size / coverage_resolution") as caught:
        SeifExploreEnv(arena_size=1000.0, coverage_resolution=0.1)
    assert str(MAX_COVERAGE_CELLS) in str(caught.value)
    SeifExploreEnv(arena_size=MAX_ARENA_SIZE)  # the largest arena at the default resolution is accepted


def test_world_config_small_arena_blames_arena_size_and_keeps_wall_margin_checks():
    with pytest.raises(ValueError, match="^arena_size must be more than 4 \\* wall_margin"):
        WorldConfig(arena_size=4.0)
    with pytest.raises(ValueError, match="^wall_margin"):
        WorldConfig(wall_margin=-1.0)
    WorldConfig(arena_size=4.01)


def test_num_landmarks_bound():
    for too_many in (10_000, MAX_LANDMARKS + 1):
        with pytest.raises(ValueError, match=f"num_landmarks must be at most MAX_LANDMARKS = {MAX_LANDMARKS}"):
            SeifExploreEnv(num_landmarks=too_many)
    assert SeifExploreEnv(num_landmarks=MAX_LANDMARKS).world_config.num_landmarks == MAX_LANDMARKS


@pytest.mark.parametrize("action", ["forward", b"forward", None, {"v": 1.0}, [1.0, "x"]])
def test_non_numeric_action_is_a_type_error_and_changes_nothing(action):
    env, fresh = SeifExploreEnv(), SeifExploreEnv()
    env.reset(seed=3)
    fresh.reset(seed=3)
    with pytest.raises(TypeError, match="action must be 2 numbers in the action space Box"):
        env.step(action)
    _same(_rollout(env), _rollout(fresh))


@pytest.mark.parametrize("options", [{"start": [0.0, 0.0, 0.0]}, {"layout": "loop", "seed": 1}])
def test_reset_options_are_refused_before_anything_is_reset(options):
    env, fresh = SeifExploreEnv(), SeifExploreEnv()
    env.reset(seed=5)
    fresh.reset(seed=5)
    with pytest.raises(ValueError, match="unknown key") as caught:
        env.reset(seed=9, options=options)
    for key in options:
        assert repr(key) in str(caught.value)
    assert "accepts no options" in str(caught.value)
    _same(_rollout(env), _rollout(fresh))


def test_reset_options_not_a_mapping():
    env = SeifExploreEnv()
    with pytest.raises(TypeError, match="options"):
        env.reset(seed=0, options=["start"])
    assert env.world is None


def test_empty_options_reset_as_none():
    a, b = SeifExploreEnv(), SeifExploreEnv()
    a.reset(seed=2, options={})
    b.reset(seed=2)
    _same(_rollout(a), _rollout(b))
