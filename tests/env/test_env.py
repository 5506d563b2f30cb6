"""Tests of the ``SeifExplore`` environments (issue #3's test list).

Groups (see the section comments): API checkers, registration, determinism,
the return identity, no ground-truth leak, actions and arguments, the wall,
the episode's end, info keys, observations, vectorised envs, and a long
random run (100 000 steps).
"""

from __future__ import annotations

import copy
import gc
import math
import multiprocessing
import os
import subprocess
import sys
import textwrap
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest

# rendering in the checkers must not need a display
os.environ.setdefault("MPLBACKEND", "Agg")

from seif_gym import ENTRY_POINT, LATEST_VERSION, VARIANTS  # noqa: E402
from seif_gym.envs.explore import Measurements  # noqa: E402
from seif_gym.observation import BeliefEncoder  # noqa: E402

ENV_ID = f"SeifExplore-v{LATEST_VERSION}"  # the newest version
OBS_KEYS = ("pose", "landmarks", "landmarks_mask", "belief_map")
#: dtype of each observation entry: 1-D float32 vectors and a uint8 image (what SB3 expects).
OBS_DTYPES = {"pose": np.float32, "landmarks": np.float32, "landmarks_mask": np.float32, "belief_map": np.uint8}

#: (id, kwargs) for the checkers: every registered variant, and non-default arguments.
CHECK_CASES = [pytest.param(env_id, {}, id=env_id) for env_id in VARIANTS] + [
    pytest.param(ENV_ID, {"filter": "ekf"}, id="ekf"),
    pytest.param(ENV_ID, {"filter": "eif"}, id="eif"),
    pytest.param(ENV_ID, {"max_active": 2}, id="max_active=2"),
    pytest.param(ENV_ID, {"reward": "information_gain"}, id="information_gain"),
    pytest.param(ENV_ID, {"reward": "information_gain", "filter": "ekf"}, id="information_gain-ekf"),
    pytest.param(ENV_ID, {"layout": "clustered", "fov": 2 * math.pi, "num_landmarks": 5}, id="clustered-fov2pi-n5"),
]


# -- helpers ----------------------------------------------------------------------------------------
def make(env_id: str = ENV_ID, **kwargs) -> gym.Env:
    return gym.make(env_id, **kwargs)


def warning_lines(caught) -> str:
    return "\n".join(f"{w.category.__name__} ({w.filename}:{w.lineno}): {w.message}" for w in caught)


def assert_same(a, b, path: str = "", skip: tuple[str, ...] = ("step_time",)) -> None:
    """Exact equality of nested observations / infos (``skip`` keys ignored at any level)."""
    if isinstance(a, dict):
        assert isinstance(b, dict), f"{path}: dict vs {type(b).__name__}"
        assert set(a) == set(b), f"{path}: keys {sorted(a)} != {sorted(b)}"
        for key in a:
            if key not in skip:
                assert_same(a[key], b[key], f"{path}[{key!r}]", skip)
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray), f"{path}: ndarray vs {type(b).__name__}"
        assert a.dtype == b.dtype and a.shape == b.shape, f"{path}: {a.dtype}{a.shape} vs {b.dtype}{b.shape}"
        assert np.array_equal(a, b, equal_nan=True), f"{path}: {a} != {b}"
    elif isinstance(a, tuple):
        # NamedTuples (info["measurements"]) and tuples of ints (info["active_landmarks"]), element by element
        assert type(a) is type(b), f"{path}: {type(a).__name__} vs {type(b).__name__}"
        assert len(a) == len(b), f"{path}: length {len(a)} != {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]", skip)
    elif isinstance(a, float) and math.isnan(a):
        assert isinstance(b, float) and math.isnan(b), f"{path}: nan vs {b}"
    else:
        assert type(a) is type(b), f"{path}: {type(a).__name__} vs {type(b).__name__}"
        assert a == b, f"{path}: {a!r} != {b!r}"


def fixed_actions(steps: int = 100, seed: int = 2024, spread: float = 1.3) -> np.ndarray:
    """A fixed action sequence, some of it outside [-1, 1] (clipped by the env)."""
    return np.random.default_rng(seed).uniform(-spread, spread, (steps, 2)).astype(np.float32)


POLICIES = {
    "zero": lambda t, rng: np.zeros(2, dtype=np.float32),
    "random": lambda t, rng: rng.uniform(-1.0, 1.0, 2).astype(np.float32),
    "straight": lambda t, rng: np.array([1.0, 0.0], dtype=np.float32),
    "reverse": lambda t, rng: np.array([-1.0, 0.0], dtype=np.float32),
    "arc": lambda t, rng: np.array([1.0, 0.3], dtype=np.float32),
}


def rollout(env: gym.Env, policy, seed: int, max_steps: int | None = None):
    """Run one episode; returns (reset info, list of (reward, terminated, truncated, info))."""
    rng = np.random.default_rng(seed + 1)
    _, info0 = env.reset(seed=seed)
    steps = []
    t = 0
    while max_steps is None or t < max_steps:
        _, reward, terminated, truncated, info = env.step(policy(t, rng))
        steps.append((reward, terminated, truncated, info))
        t += 1
        if terminated or truncated:
            break
    return info0, steps


def all_finite(obs: dict) -> bool:
    return all(np.all(np.isfinite(obs[key])) for key in obs)


# == API checkers ======================================================================================
@pytest.mark.parametrize(("env_id", "kwargs"), CHECK_CASES)
def test_gymnasium_check_env_passes_without_warnings(env_id, kwargs):
    from gymnasium.utils.env_checker import check_env

    env = make(env_id, **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    env.close()
    assert not caught, "check_env warned:\n" + warning_lines(caught)


def test_gymnasium_check_env_with_render_checks_passes_without_warnings():
    """The full checker, including ``rgb_array`` and ``human`` rendering (headless: Agg)."""
    from gymnasium.utils.env_checker import check_env

    env = make(ENV_ID)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    env.close()
    assert not caught, "check_env warned:\n" + warning_lines(caught)


@pytest.mark.parametrize(("env_id", "kwargs"), CHECK_CASES)
def test_sb3_check_env_passes_without_warnings(env_id, kwargs):
    from stable_baselines3.common.env_checker import check_env

    env = make(env_id, **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    env.close()
    assert not caught, "SB3 check_env warned:\n" + warning_lines(caught)


# == registration =====================================================================================
@pytest.mark.parametrize("env_id", list(VARIANTS))
def test_variant_is_registered_with_its_kwargs_and_time_limit(env_id):
    kwargs, steps = VARIANTS[env_id]
    spec = gym.spec(env_id)
    assert spec.entry_point == ENTRY_POINT
    assert spec.kwargs == kwargs
    assert spec.max_episode_steps == steps
    env = make(env_id)
    assert env.spec.max_episode_steps == steps
    config = env.unwrapped.config
    for key, value in kwargs.items():
        assert config[key] == value, key
    obs, info = env.reset(seed=0)
    assert env.unwrapped.world.landmarks.shape == (config["num_landmarks"], 2)
    assert info["landmarks_total"] == config["num_landmarks"]
    env.close()


def test_make_after_import():
    env = gym.make("SeifExplore-v0")
    assert env.unwrapped.__class__.__name__ == "SeifExploreEnv"
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    env.close()


@pytest.mark.slow
def test_make_with_module_prefix_in_fresh_interpreter():
    code = textwrap.dedent(
        """
        import sys
        import gymnasium as gym
        assert "seif_gym" not in sys.modules
        env = gym.make("seif_gym:SeifExplore-v0")
        obs, info = env.reset(seed=0)
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        large = gym.make("seif_gym:SeifExploreLarge-v0")
        print(env.spec.max_episode_steps, large.spec.max_episode_steps, sorted(obs))
        """
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("[")[0].split() == ["400", "1000"]
    assert "'belief_map', 'landmarks', 'landmarks_mask', 'pose'" in result.stdout


def test_kwargs_pass_through_make():
    env = make(num_landmarks=12, nearest_landmarks=3, map_size=16, arena_size=30.0, sensor_range=4.0)
    obs, info = env.reset(seed=0)
    unwrapped = env.unwrapped
    assert unwrapped.world.landmarks.shape == (12, 2)
    assert info["landmarks_total"] == 12
    assert unwrapped.world_config.arena_size == 30.0
    assert unwrapped.sensor.max_range == 4.0
    assert obs["landmarks"].shape == (3 * 4,)
    assert obs["landmarks_mask"].shape == (3,)
    assert obs["belief_map"].shape == (3, 16, 16) and obs["belief_map"].dtype == np.uint8
    assert np.abs(unwrapped.world.landmarks).max() <= 15.0
    env.close()


def test_max_episode_steps_can_be_overridden_at_make():
    env = make(max_episode_steps=7)
    _, steps = rollout(env, POLICIES["zero"], seed=0)
    assert len(steps) == 7 and steps[-1][2] is True
    env.close()


@pytest.mark.parametrize("env_id", list(VARIANTS))
def test_truncation_exactly_at_the_registered_limit(env_id):
    """Zero actions never move the robot (no control, no motion noise): only the time limit ends it."""
    limit = VARIANTS[env_id][1]
    env = make(env_id)
    _, steps = rollout(env, POLICIES["zero"], seed=3, max_steps=limit + 5)
    assert len(steps) == limit
    for t, (_, terminated, truncated, info) in enumerate(steps, start=1):
        assert terminated is False, t
        assert truncated is (t == limit), t
        assert info["diverged"] is False
    env.close()


# == determinism ======================================================================================
DETERMINISM_CASES = [
    pytest.param({}, id="default"),
    pytest.param({"filter": "ekf"}, id="ekf"),
    pytest.param({"filter": "eif", "reward": "information_gain"}, id="eif-information_gain"),
    pytest.param({"layout": "loop", "num_landmarks": 40}, id="loop"),
]


@pytest.mark.parametrize("kwargs", DETERMINISM_CASES)
def test_same_seed_same_episode(kwargs):
    env_a, env_b = make(**kwargs), make(**kwargs)
    obs_a, info_a = env_a.reset(seed=11)
    obs_b, info_b = env_b.reset(seed=11)
    assert_same(obs_a, obs_b, "reset obs")
    assert_same(info_a, info_b, "reset info")
    for t, action in enumerate(fixed_actions(100)):
        out_a, out_b = env_a.step(action), env_b.step(action.copy())
        assert_same(out_a[0], out_b[0], f"obs@{t}")
        for i, name in ((1, "reward"), (2, "terminated"), (3, "truncated")):
            assert_same(out_a[i], out_b[i], f"{name}@{t}")
        assert_same(out_a[4], out_b[4], f"info@{t}")
        if out_a[2] or out_a[3]:
            break
    # the next (unseeded) reset continues both generators identically
    assert_same(env_a.reset()[0], env_b.reset()[0], "second reset")
    env_a.close()
    env_b.close()


def test_reseeding_the_same_env_reproduces_the_episode():
    env = make()
    actions = fixed_actions(60, seed=5)

    def run():
        obs, info = env.reset(seed=123)
        out = [(obs, info)]
        for action in actions:
            obs, reward, terminated, truncated, info = env.step(action)
            out.append((obs, info, reward, terminated, truncated))
        return out

    first, second = run(), run()
    for t, (a, b) in enumerate(zip(first, second)):
        for x, y in zip(a, b):
            assert_same(x, y, f"step {t}")
    env.close()


def test_different_seeds_differ():
    env_a, env_b = make(), make()
    obs_a, _ = env_a.reset(seed=0)
    obs_b, _ = env_b.reset(seed=1)
    assert not np.array_equal(env_a.unwrapped.world.landmarks, env_b.unwrapped.world.landmarks)
    assert not np.array_equal(env_a.unwrapped.world.pose, env_b.unwrapped.world.pose)
    assert not np.array_equal(obs_a["pose"], obs_b["pose"])
    rewards = []
    for env in (env_a, env_b):
        rewards.append([env.step(action)[1] for action in fixed_actions(30)])
    assert rewards[0] != rewards[1]
    env_a.close()
    env_b.close()


def test_motion_and_sensor_noise_depend_on_the_seed():
    """Same layout is not enough: two seeds give different noise draws (pose estimates differ)."""
    estimates = []
    for seed in (7, 8):
        env = make()
        env.reset(seed=seed)
        for action in fixed_actions(20):
            info = env.step(action)[4]
        estimates.append(info["pose_estimate"] - info["true_pose"])
        env.close()
    assert not np.array_equal(estimates[0], estimates[1])


# == return identity ==================================================================================
@pytest.mark.parametrize("policy", ["zero", "random", "straight", "reverse", "arc"])
@pytest.mark.parametrize(
    "kwargs",
    [pytest.param({}, id="seif"), pytest.param({"filter": "ekf", "wall_penalty": 0.1}, id="ekf-wall_penalty=0.1")],
)
def test_return_is_map_error_gain_minus_wall_penalties(policy, kwargs):
    env = make(**kwargs)
    wall_penalty = env.unwrapped.reward_config.wall_penalty
    info0, steps = rollout(env, POLICIES[policy], seed=4)
    previous = info0["map_error"]
    walls = 0
    for t, (reward, _, _, info) in enumerate(steps):
        wall = bool(info["wall_contact"])
        walls += wall
        assert reward == pytest.approx(previous - info["map_error"] - wall_penalty * wall, abs=1e-12), t
        previous = info["map_error"]
    total = math.fsum(reward for reward, *_ in steps)
    expected = info0["map_error"] - steps[-1][3]["map_error"] - wall_penalty * walls
    assert abs(total - expected) <= 1e-9
    if policy in ("straight", "reverse"):
        assert walls > 0, "the policy should have reached the wall"
    if policy == "zero":
        assert walls == 0
    env.close()


def test_information_gain_rewards_are_finite_and_differ_from_map_error():
    rewards = {}
    for reward in ("map_error", "information_gain"):
        env = make(reward=reward)
        _, steps = rollout(env, POLICIES["random"], seed=2, max_steps=60)
        rewards[reward] = np.array([r for r, *_ in steps])
        assert np.all(np.isfinite(rewards[reward]))
        env.close()
    assert not np.allclose(rewards["map_error"], rewards["information_gain"])


# == no ground-truth leak =============================================================================
def far_positions(center: np.ndarray, count: int, radius: float, half: float, rng) -> np.ndarray:
    """``count`` points inside ``[-half, half]^2`` farther than ``radius`` from ``center``."""
    points = []
    while len(points) < count:
        p = rng.uniform(-half, half, 2)
        if np.hypot(*(p - center)) > radius:
            points.append(p)
    return np.array(points)


@pytest.mark.parametrize("filter_name", ["seif", "ekf"])
def test_unseen_true_landmarks_do_not_change_the_observation(filter_name):
    """Moving landmarks that the robot has not seen (and cannot see) changes nothing it observes."""
    seed, steps = 21, 40
    env_a, env_b = make(filter=filter_name), make(filter=filter_name)
    obs_a, _ = env_a.reset(seed=seed)
    obs_b, _ = env_b.reset(seed=seed)
    world_a, world_b = env_a.unwrapped.world, env_b.unwrapped.world
    sensor_range = env_a.unwrapped.sensor.max_range
    start = world_a.pose[:2].copy()
    half = world_a.config.half_size - world_a.config.wall_margin
    mapped = set(env_a.unwrapped.filter.landmark_ids.tolist())
    far = np.hypot(*(world_a.landmarks - start).T) > sensor_range + 1.5
    moved = np.array([i for i in np.flatnonzero(far) if i not in mapped])
    assert len(moved) >= 5, "test setup: expected several far, unmapped landmarks"
    landmarks = world_b.landmarks.copy()
    landmarks[moved] = far_positions(start, len(moved), sensor_range + 1.5, half, np.random.default_rng(0))
    world_b.landmarks = landmarks
    assert not np.array_equal(world_a.landmarks, world_b.landmarks)

    encoder_a, encoder_b = env_a.unwrapped.encoder, env_b.unwrapped.encoder
    assert_same(encoder_a.encode(env_a.unwrapped.filter), encoder_b.encode(env_b.unwrapped.filter), "encode")
    turn = np.array([0.0, 0.6], dtype=np.float32)  # turn in place: the robot stays near the start
    for t in range(steps):
        out_a, out_b = env_a.step(turn), env_b.step(turn)
        assert_same(out_a[0], out_b[0], f"obs@{t}")
        assert out_a[1] == out_b[1], f"reward@{t}"
        for key in ("pose_estimate", "map_error", "landmarks_mapped", "measurements", "pose_nees"):
            assert_same(out_a[4][key], out_b[4][key], f"info[{key}]@{t}")
    # the setup really kept the moved landmarks out of sight in both worlds
    for env in (env_a, env_b):
        assert not set(moved.tolist()) & set(env.unwrapped.filter.landmark_ids.tolist())
        assert np.hypot(*(env.unwrapped.world.pose[:2] - start)) < 1.0
    env_a.close()
    env_b.close()


def test_true_robot_pose_does_not_enter_the_observation():
    env_a, env_b = make(), make()
    env_a.reset(seed=5)
    env_b.reset(seed=5)
    for action in fixed_actions(15):
        env_a.step(action)
        env_b.step(action)
    world_b = env_b.unwrapped.world
    world_b.pose = np.array([-world_b.pose[0], 0.5 * world_b.pose[1], world_b.pose[2] + 2.0])
    assert not np.allclose(env_a.unwrapped.world.pose, world_b.pose)
    obs_a = env_a.unwrapped.encoder.encode(env_a.unwrapped.filter)
    obs_b = env_b.unwrapped.encoder.encode(env_b.unwrapped.filter)
    assert_same(obs_a, obs_b)
    env_a.close()
    env_b.close()


def test_moved_true_robot_gives_the_same_observations_while_nothing_is_seen():
    """With nothing in sensor range the filter only hears the executed controls: moving the *true*
    robot then must not change any observation (swept area included) over many steps."""
    kwargs = {"num_landmarks": 2, "sensor_range": 0.3, "sensor_min_range": 0.0}
    env_a, env_b = make(**kwargs), make(**kwargs)
    env_a.reset(seed=2)
    env_b.reset(seed=2)
    world_b = env_b.unwrapped.world
    world_b.pose = np.array([world_b.pose[0] * 0.5 + 1.0, world_b.pose[1] * 0.5 - 1.0, world_b.pose[2] + 1.5])
    assert np.hypot(*(env_a.unwrapped.world.pose[:2] - world_b.pose[:2])) > 0.5
    action = np.array([0.4, 0.3], dtype=np.float32)  # a circle of radius 1.3 m: stays off the walls
    for t in range(60):
        out_a, out_b = env_a.step(action), env_b.step(action)
        for out in (out_a, out_b):
            assert len(out[4]["measurements"].ids) == 0 and not out[4]["wall_contact"], "test setup"
        assert_same(out_a[0], out_b[0], f"obs@{t}")
        assert_same(out_a[4]["pose_estimate"], out_b[4]["pose_estimate"], f"estimate@{t}")
        assert not np.allclose(out_a[4]["true_pose"], out_b[4]["true_pose"])
    assert np.any(out_a[0]["belief_map"][0])  # the swept channel is part of the comparison
    env_a.close()
    env_b.close()


def test_observation_depends_only_on_the_filter():
    env, other = make(), make()
    env.reset(seed=8)
    other.reset(seed=9)
    for action in fixed_actions(30):
        env.step(action)
        other.step(action)
    unwrapped = env.unwrapped
    filt, encoder = unwrapped.filter, unwrapped.encoder
    first = encoder.encode(filt)
    # another world behind the same filter
    own_world = unwrapped.world
    unwrapped.world = other.unwrapped.world
    assert_same(first, encoder.encode(filt), "other world")
    # no world at all
    unwrapped.world = None
    assert_same(first, encoder.encode(filt), "no world")
    unwrapped.world = own_world
    # a fresh encoder with the same swept area and a copy of the filter
    fresh = BeliefEncoder(unwrapped.world_config.arena_size, unwrapped.sensor, unwrapped.observation_config)
    fresh.coverage[:] = encoder.coverage
    assert_same(first, fresh.encode(copy.deepcopy(filt)), "fresh encoder, copied filter")
    # and the observation does change when the filter does
    other_filter = other.unwrapped.filter
    assert not np.array_equal(first["pose"], encoder.encode(other_filter)["pose"])
    env.close()
    other.close()


@pytest.mark.parametrize("policy", ["random", "straight"])
def test_filter_receives_only_executed_control_and_info_measurements(policy):
    """Replaying ``info['executed_control']`` and ``info['measurements']`` on a copy of the filter
    reproduces the env's filter: nothing else (no true state) reaches the belief."""
    env = make()
    env.reset(seed=6)
    dt = env.unwrapped.robot_config.dt
    rng = np.random.default_rng(0)
    for t in range(80):
        reference = copy.deepcopy(env.unwrapped.filter)
        info = env.step(POLICIES[policy](t, rng))[4]
        reference.predict(info["executed_control"], dt)
        m = info["measurements"]
        reference.update(m.ranges, m.bearings, m.ids)
        filt = env.unwrapped.filter
        assert np.array_equal(reference.landmark_ids, filt.landmark_ids), t
        np.testing.assert_allclose(reference.mean, filt.mean, rtol=1e-10, atol=1e-10, err_msg=f"step {t}")
    env.close()


# == actions and arguments ============================================================================
@pytest.mark.parametrize("bad", [[np.nan, 0.0], [0.0, np.inf], [-np.inf, 0.5], [np.nan, np.nan]])
@pytest.mark.parametrize("wrapped", [True, False], ids=["make", "unwrapped"])
def test_non_finite_action_raises(bad, wrapped):
    env = make()
    target = env if wrapped else env.unwrapped
    target.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        target.step(np.array(bad, dtype=np.float32))
    # the env is still usable after the rejected step
    obs, *_ = target.step(np.zeros(2, dtype=np.float32))
    assert env.observation_space.contains(obs)
    env.close()


@pytest.mark.parametrize(
    "bad",
    [np.zeros(3), np.zeros((1, 2)), np.zeros((2, 1)), np.zeros(0), np.float32(0.5), [[0.1, 0.2]]],
    ids=["(3,)", "(1,2)", "(2,1)", "(0,)", "scalar", "nested-list"],
)
def test_wrong_action_shape_raises(bad):
    env = make()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(bad)
    env.close()


def test_step_before_reset_raises():
    env = make()
    with pytest.raises(RuntimeError, match="reset"):
        env.unwrapped.step(np.zeros(2, dtype=np.float32))
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(2, dtype=np.float32))
    env.close()


def test_out_of_range_actions_are_clipped():
    max_speed, max_turn_rate = 0.5, 2.0
    env = make(max_speed=max_speed, max_turn_rate=max_turn_rate)
    clipped_env = make(max_speed=max_speed, max_turn_rate=max_turn_rate)
    env.reset(seed=1)
    clipped_env.reset(seed=1)
    actions = [[2.0, -3.0], [-1.5, 0.5], [0.3, 7.0], [-9.0, -9.0], [0.25, -0.75], [1e30, -1e30]]
    for action in actions:
        action = np.array(action, dtype=np.float64)
        expected = np.clip(action, -1.0, 1.0) * np.array([max_speed, max_turn_rate])
        out = env.step(action)
        info = out[4]
        np.testing.assert_array_equal(info["control"], expected)
        if not info["wall_contact"]:
            np.testing.assert_array_equal(info["executed_control"], expected)
        # stepping with the clipped action is the same step
        ref = clipped_env.step(np.clip(action, -1.0, 1.0))
        assert_same(out[0], ref[0], "obs")
        assert out[1] == ref[1]
        assert_same(out[4], ref[4], "info")
    env.close()
    clipped_env.close()


def test_list_and_float64_actions_are_accepted():
    env = make()
    env.reset(seed=0)
    for action in ([0.5, -0.5], (1, 0), np.array([0.2, 0.1], dtype=np.float64)):
        obs, reward, *_ = env.step(action)
        assert env.observation_space.contains(obs) and isinstance(reward, float)
    env.close()


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"layout": "maze"}, "layout"),
        ({"num_landmarks": 0}, "num_landmarks"),
        ({"num_landmarks": 2.5}, "num_landmarks"),
        ({"filter": "ukf"}, "filter"),
        ({"reward": "foo"}, "reward"),
        ({"dt": -1}, "dt"),
        ({"sensor_range": 0}, "sensor_range"),
        ({"max_active": 0}, "max_active"),
        ({"render_mode": "ascii"}, "render_mode"),
        ({"d_cap": -1}, "d_cap"),
    ],
    ids=lambda value: repr(value) if isinstance(value, dict) else "arg",
)
def test_bad_kwargs_raise_naming_the_argument(kwargs, name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gym.make's own render_mode warning
        with pytest.raises((ValueError, TypeError), match=name):
            make(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"arena_size": -1.0}, "arena_size"),
        ({"arena_size": float("nan")}, "arena_size"),
        ({"num_landmarks": -3}, "num_landmarks"),
        ({"num_landmarks": True}, "num_landmarks"),
        ({"sensor_range": -2.0}, "sensor_range"),
        ({"sensor_range": float("inf")}, "sensor_range"),
        ({"fov": 0.0}, "fov"),
        ({"fov": 7.0}, "fov"),
        ({"sigma_range": 0.0}, "sigma_range"),
        ({"sigma_bearing": -0.1}, "sigma_bearing"),
        ({"motion_noise": (0.1, 0.2)}, "motion_noise"),
        ({"motion_noise": (0.1, 0.1, 0.1, 0.1, 0.1, -0.1)}, "motion_noise"),
        ({"dt": 0}, "dt"),
        ({"dt": True}, "dt"),
        ({"max_speed": 0.0}, "max_speed"),
        ({"max_turn_rate": float("inf")}, "max_turn_rate"),
        ({"max_active": -1}, "max_active"),
        ({"max_active": 2.5}, "max_active"),
        ({"max_active": True}, "max_active"),
        ({"d_cap": float("inf")}, "d_cap"),
        ({"d_cap": True}, "d_cap"),
        ({"wall_penalty": -0.1}, "wall_penalty"),
        ({"wall_penalty": float("nan")}, "wall_penalty"),
        ({"wall_penalty": True}, "wall_penalty"),
        ({"divergence_threshold": 0.0}, "divergence_threshold"),
        ({"nearest_landmarks": 0}, "nearest_landmarks"),
        ({"map_size": 0}, "map_size"),
        ({"map_extent": 0.0}, "map_extent"),
        ({"std_scale": -1.0}, "std_scale"),
        ({"coverage_resolution": 0.0}, "coverage_resolution"),
        ({"coverage_resolution": -0.5}, "coverage_resolution"),
        ({"coverage_resolution": float("nan")}, "coverage_resolution"),
        ({"not_an_argument": 1}, "not_an_argument"),
    ],
    ids=lambda value: repr(value) if isinstance(value, dict) else "arg",
)
def test_more_bad_kwargs_raise_naming_the_argument(kwargs, name):
    with pytest.raises((ValueError, TypeError), match=name):
        make(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"wall_penalty": True}, "wall_penalty"),
        ({"d_cap": True}, "d_cap"),
        ({"dt": False}, "dt"),
        ({"sensor_range": "5"}, "sensor_range"),
        ({"fov": None}, "fov"),
        ({"sigma_bearing": True}, "sigma_bearing"),
    ],
    ids=lambda value: repr(value) if isinstance(value, dict) else "arg",
)
def test_non_numbers_raise_type_error_naming_the_argument(kwargs, name):
    """Booleans are not numbers here (``wall_penalty=True`` is refused, not read as 1.0)."""
    with pytest.raises(TypeError, match=name):
        make(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        ({"sensor_range": 0.0}, ValueError, "sensor_range"),
        ({"fov": 2 * math.pi + 0.01}, ValueError, "fov"),
        ({"fov": -1.0}, ValueError, "fov"),
        ({"sigma_range": float("inf")}, ValueError, "sigma_range"),
        ({"sigma_bearing": 0.0}, ValueError, "sigma_bearing"),
        ({"sigma_range": True}, TypeError, "sigma_range"),
    ],
    ids=lambda value: repr(value) if isinstance(value, dict) else None,
)
def test_sensor_config_validates_its_fields(kwargs, error, name):
    from seif_gym.envs.explore import SensorConfig

    with pytest.raises(error, match=name):
        SensorConfig(**kwargs)
    assert SensorConfig(fov=2 * math.pi).fov == 2 * math.pi


def test_coverage_resolution_sets_the_swept_grid():
    fine, coarse = make(), make(coverage_resolution=2.0)
    assert fine.unwrapped.config["coverage_resolution"] == 0.5
    assert coarse.unwrapped.config["coverage_resolution"] == 2.0
    assert fine.unwrapped.encoder.coverage.shape == (40, 40)
    assert coarse.unwrapped.encoder.coverage.shape == (10, 10)
    obs_fine, _ = fine.reset(seed=0)
    obs_coarse, _ = coarse.reset(seed=0)
    assert coarse.observation_space.contains(obs_coarse)
    # same belief, different rasterisation of the swept area only
    for key in ("pose", "landmarks", "landmarks_mask"):
        np.testing.assert_array_equal(obs_fine[key], obs_coarse[key])
    np.testing.assert_array_equal(obs_fine["belief_map"][1:], obs_coarse["belief_map"][1:])
    assert not np.array_equal(obs_fine["belief_map"][0], obs_coarse["belief_map"][0])
    fine.close()
    coarse.close()


@pytest.mark.parametrize(
    "kwargs",
    [
        {"max_active": None},
        {"filter": "ekf", "max_active": None},
        {"fov": 2 * math.pi},
        {"wall_penalty": 0.0},
        {"num_landmarks": 1},
        {"coverage_resolution": 3.0},
        {"map_size": 36},
    ],  # fmt: skip
    ids=repr,
)
def test_valid_edge_kwargs_are_accepted(kwargs):
    env = make(**kwargs)
    obs, _ = env.reset(seed=0)
    for action in fixed_actions(10):
        obs, reward, *_ = env.step(action)
        assert env.observation_space.contains(obs) and math.isfinite(reward)
    env.close()


# == wall =============================================================================================
@pytest.mark.parametrize("direction", [1.0, -1.0], ids=["forward", "backward"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_driving_straight_reaches_the_wall_and_is_blocked(direction, seed):
    env = make()
    unwrapped = env.unwrapped
    half = unwrapped.world_config.half_size
    wall_penalty = unwrapped.reward_config.wall_penalty
    dt = unwrapped.robot_config.dt
    _, info = env.reset(seed=seed)
    previous_error = info["map_error"]
    action = np.array([direction, 0.0], dtype=np.float32)
    contacts = 0
    for t in range(400):
        reference = copy.deepcopy(unwrapped.filter)
        _, reward, terminated, truncated, info = env.step(action)
        pose = info["true_pose"]
        assert -half <= pose[0] <= half and -half <= pose[1] <= half, (t, pose)
        np.testing.assert_array_equal(info["control"], [direction * unwrapped.robot_config.max_speed, 0.0])
        gain = previous_error - info["map_error"]
        previous_error = info["map_error"]
        if info["wall_contact"]:
            contacts += 1
            assert info["executed_control"][0] == 0.0
            assert info["executed_control"][1] == info["control"][1]
            assert reward == pytest.approx(gain - wall_penalty, abs=1e-12)
            # the filter was told v = 0
            reference.predict(info["executed_control"], dt)
            m = info["measurements"]
            reference.update(m.ranges, m.bearings, m.ids)
            np.testing.assert_allclose(reference.pose, unwrapped.filter.pose, rtol=1e-10, atol=1e-10)
        else:
            np.testing.assert_array_equal(info["executed_control"], info["control"])
            assert reward == pytest.approx(gain, abs=1e-12)
        if terminated or truncated:
            break
    assert contacts > 0, "driving straight for an episode must reach the wall"
    # near the wall at the end: within one step's travel (plus noise) of it
    assert half - max(abs(pose[0]), abs(pose[1])) < 0.5
    env.close()


def test_wall_contact_happens_when_noise_free_motion_would_leave():
    """The first contact is at the step whose nominal motion would cross the wall."""
    env = make()
    unwrapped = env.unwrapped
    env.reset(seed=0)
    motion, dt, half = unwrapped.motion, unwrapped.robot_config.dt, unwrapped.world_config.half_size
    action = np.array([1.0, 0.0], dtype=np.float32)
    for t in range(200):
        before = unwrapped.world.pose.copy()
        nominal = motion.predict(before, np.array([1.0, 0.0]), dt)
        would_leave = not (-half <= nominal[0] <= half and -half <= nominal[1] <= half)
        info = env.step(action)[4]
        assert info["wall_contact"] is would_leave, t
        if info["wall_contact"]:
            # blocked: the position moved by at most the noise of a turn in place (v = 0, w = 0 -> none)
            np.testing.assert_allclose(info["true_pose"][:2], before[:2], atol=1e-12)
            break
    else:
        pytest.fail("no wall contact in 200 steps")
    env.close()


# == episode end ======================================================================================
def test_tiny_divergence_threshold_terminates_with_diverged():
    threshold = 1e-3
    env = make(divergence_threshold=threshold)
    _, info = env.reset(seed=0)
    assert info["diverged"] is False
    rng = np.random.default_rng(0)
    for t in range(100):
        _, _, terminated, truncated, info = env.step(POLICIES["random"](t, rng))
        assert info["diverged"] is terminated
        assert terminated is (info["pose_error"] > threshold)
        if terminated:
            assert truncated is False
            break
    else:
        pytest.fail("a 1 mm divergence threshold was never crossed")
    env.close()


def test_teleported_true_robot_terminates_with_diverged():
    """A true pose far from the (unchanged) estimate is a diverged estimate."""
    env = make()
    env.reset(seed=0)
    for action in fixed_actions(5):
        env.step(action)
    world = env.unwrapped.world
    towards_centre = -world.pose[:2] / np.linalg.norm(world.pose[:2])
    world.pose = np.array([*(world.pose[:2] + 7.0 * towards_centre), world.pose[2]])
    _, _, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
    assert info["pose_error"] > env.unwrapped.reward_config.divergence_threshold
    assert terminated is True and info["diverged"] is True and truncated is False
    env.close()


@pytest.mark.parametrize("filter_name", ["seif", "ekf"])
def test_default_episodes_end_by_truncation(filter_name):
    env = make(filter=filter_name)
    for seed in (0, 1):
        _, steps = rollout(env, POLICIES["random"], seed=seed)
        assert len(steps) == 400
        assert steps[-1][1] is False and steps[-1][2] is True
        assert all(not info["diverged"] for *_, info in steps)
    env.close()


# == info keys ========================================================================================
INFO_KEYS = {
    "true_pose", "pose_estimate", "pose_error", "map_error", "pose_nees", "pose_nees_blanket", "landmarks_mapped",
    "landmarks_total", "active_landmarks", "control", "measurements", "step_time", "wall_contact", "diverged", "executed_control",
}  # fmt: skip


def check_info(info: dict, env: gym.Env, *, previous_mapped: int = 0) -> None:
    unwrapped = env.unwrapped
    world, filt = unwrapped.world, unwrapped.filter
    n = unwrapped.world_config.num_landmarks
    missing = INFO_KEYS - set(info)
    assert not missing, f"missing info keys {sorted(missing)}"
    for key in ("true_pose", "pose_estimate"):
        value = info[key]
        assert isinstance(value, np.ndarray) and value.shape == (3,) and value.dtype == np.float64, key
        assert np.all(np.isfinite(value)), key
    np.testing.assert_array_equal(info["true_pose"], world.pose)
    np.testing.assert_array_equal(info["pose_estimate"], filt.pose)
    for key in ("pose_error", "map_error", "pose_nees", "pose_nees_blanket", "step_time"):
        assert isinstance(info[key], float) and not isinstance(info[key], bool), key
        assert math.isfinite(info[key]) and info[key] >= 0.0, (key, info[key])
    # pose_nees with the filter's own (exact marginal) covariance, by hand; the blanket one with the observation's
    error = info["true_pose"] - info["pose_estimate"]
    error[2] = (error[2] + math.pi) % (2 * math.pi) - math.pi
    assert info["pose_nees"] == pytest.approx(float(error @ np.linalg.solve(filt.pose_covariance, error)), rel=1e-9)
    blanket = unwrapped.encoder.pose_covariance
    assert info["pose_nees_blanket"] == pytest.approx(float(error @ np.linalg.solve(blanket, error)), rel=1e-9)
    assert info["pose_error"] == pytest.approx(
        math.hypot(*(info["true_pose"][:2] - info["pose_estimate"][:2])), abs=1e-12
    )
    assert 0.0 <= info["map_error"] <= unwrapped.reward_config.d_cap
    assert info["map_error"] == pytest.approx(unwrapped.map_error(), abs=1e-15)
    for key in ("landmarks_mapped", "landmarks_total"):
        assert isinstance(info[key], (int, np.integer)) and not isinstance(info[key], bool), key
    assert info["landmarks_total"] == n
    assert info["landmarks_mapped"] == len(filt.landmark_ids)
    assert previous_mapped <= info["landmarks_mapped"] <= n
    active = info["active_landmarks"]
    assert type(active) is tuple and all(type(i) is int for i in active), active
    assert len(set(active)) == len(active)
    assert set(active) <= set(filt.landmark_ids.tolist())
    if unwrapped.filter_config.filter == "seif":
        # the bound k holds after each update unless more than k landmarks were seen in that update,
        # and then all the active ones were seen in it
        k = unwrapped.filter_config.max_active
        measured = set(info["measurements"].ids.tolist())
        assert len(active) <= max(k, len(measured))
        if len(active) > k:
            assert set(active) <= measured
    else:
        assert sorted(active) == sorted(filt.landmark_ids.tolist())
    for key in ("control", "executed_control"):
        value = info[key]
        assert isinstance(value, np.ndarray) and value.shape == (2,) and value.dtype == np.float64, key
    assert isinstance(info["wall_contact"], bool) and isinstance(info["diverged"], bool)
    m = info["measurements"]
    assert type(m) is Measurements and m._fields == ("ranges", "bearings", "ids")
    ranges, bearings, ids = m
    assert ranges is m.ranges and bearings is m.bearings and ids is m.ids
    assert all(isinstance(a, np.ndarray) and a.ndim == 1 for a in (ranges, bearings, ids))
    assert len(ranges) == len(bearings) == len(ids)
    assert np.issubdtype(ids.dtype, np.integer) and len(set(ids.tolist())) == len(ids)
    assert np.all((ids >= 0) & (ids < n))
    assert np.all(ranges > 0) and np.all(np.abs(bearings) <= math.pi)
    # measured ids are really in range and field of view of the true robot, and are in the map now
    sensor = unwrapped.sensor
    d = world.landmarks[ids] - world.pose[:2]
    assert np.all(np.hypot(d[:, 0], d[:, 1]) <= sensor.max_range + 1e-9)
    true_bearing = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - world.pose[2])))
    assert np.all(np.abs(true_bearing) <= 0.5 * sensor.fov + 1e-9)
    assert set(ids.tolist()) <= set(filt.landmark_ids.tolist())


@pytest.mark.parametrize(
    "kwargs",
    [pytest.param({}, id="seif"), pytest.param({"filter": "ekf"}, id="ekf"), pytest.param({"filter": "eif"}, id="eif"),
     pytest.param({"max_active": 2, "fov": 2 * math.pi}, id="seif-k2-fov2pi")],
)  # fmt: skip
def test_info_contract(kwargs):
    env = make(**kwargs)
    _, info = env.reset(seed=3)
    check_info(info, env)
    np.testing.assert_array_equal(info["control"], [0.0, 0.0])
    assert info["wall_contact"] is False and info["diverged"] is False
    # the filter starts at the true pose (then processes one measurement)
    np.testing.assert_allclose(info["pose_estimate"], info["true_pose"], atol=1e-6)
    mapped = info["landmarks_mapped"]
    rng = np.random.default_rng(1)
    for t in range(120):
        info = env.step(POLICIES["random"](t, rng))[4]
        check_info(info, env, previous_mapped=mapped)
        mapped = info["landmarks_mapped"]
    assert mapped > 0
    env.close()


def test_step_time_is_zero_unless_measured():
    """``step_time`` is 0.0 by default (reproducible infos) and the filter's wall-clock time with measure_time."""
    env = make()
    _, info = env.reset(seed=0)
    assert info["step_time"] == 0.0
    assert env.step(np.array([0.5, 0.1], dtype=np.float32))[4]["step_time"] == 0.0
    env.close()
    env = make(measure_time=True)
    _, info = env.reset(seed=0)
    times = [info["step_time"]] + [env.step(action)[4]["step_time"] for action in fixed_actions(10)]
    assert all(isinstance(t, float) and 0.0 < t < 1.0 for t in times), times
    env.close()
    with pytest.raises(TypeError, match="measure_time"):
        make(measure_time=1)


def test_exact_pose_nees_off_changes_nothing_but_the_nees():
    """``exact_pose_nees=False``: every observation, reward, end and info as before, ``pose_nees`` NaN.

    80 landmarks seen all round to 12 m take the map past the dense threshold (60), so both ways of
    factorising the exact marginal are left out somewhere in the episode.
    """
    kwargs = {"num_landmarks": 80, "sensor_range": 12.0, "fov": 2 * math.pi, "max_episode_steps": 120}
    exact, cheap = make(**kwargs), make(exact_pose_nees=False, **kwargs)
    assert cheap.unwrapped.config["exact_pose_nees"] is False
    obs_a, info_a = exact.reset(seed=6)
    obs_b, info_b = cheap.reset(seed=6)
    assert_same(obs_a, obs_b)
    assert_same(info_a, info_b, skip=("step_time", "pose_nees"))
    mapped = 0
    for action in fixed_actions(120, seed=6):
        *out_a, info_a = exact.step(action)
        *out_b, info_b = cheap.step(action)
        assert_same(tuple(out_a), tuple(out_b))
        assert_same(info_a, info_b, skip=("step_time", "pose_nees"))
        assert math.isfinite(info_a["pose_nees"]) and math.isnan(info_b["pose_nees"])
        mapped = info_a["landmarks_mapped"]
        if out_a[1] or out_a[2]:
            break
    assert mapped > 60, mapped  # the sparse factorisation's side was reached
    exact.close()
    cheap.close()
    with pytest.raises(TypeError, match="exact_pose_nees"):
        make(exact_pose_nees="no")


def test_config_round_trips_through_make():
    kwargs = {"layout": "loop", "num_landmarks": 17, "filter": "ekf", "fov": 2.0, "d_cap": 1.5, "map_size": 24}
    env = make(**kwargs)
    config = env.unwrapped.config
    for key, value in kwargs.items():
        assert config[key] == value, key
    again = make(**config)
    assert again.unwrapped.config == config
    obs_a, info_a = env.reset(seed=3)
    obs_b, info_b = again.reset(seed=3)
    assert_same(obs_a, obs_b)
    assert_same(info_a, info_b)
    env.close()
    again.close()


def test_info_arrays_are_copies():
    env = make()
    _, info = env.reset(seed=0)
    info = env.step(np.array([0.5, 0.5], dtype=np.float32))[4]
    pose, estimate = env.unwrapped.world.pose.copy(), env.unwrapped.filter.pose.copy()
    info["true_pose"][:] = 99.0
    info["pose_estimate"][:] = 99.0
    active = env.unwrapped.filter.active_landmarks.copy()
    assert info["active_landmarks"] == tuple(active.tolist())  # a tuple: cannot be written through
    info["measurements"].ids[...] = -1
    np.testing.assert_array_equal(env.unwrapped.world.pose, pose)
    np.testing.assert_array_equal(env.unwrapped.filter.pose, estimate)
    np.testing.assert_array_equal(env.unwrapped.filter.active_landmarks, active)
    env.close()


# == observations =====================================================================================
@pytest.mark.parametrize(
    "kwargs",
    [pytest.param({}, id="default"), pytest.param({"nearest_landmarks": 3, "map_size": 20}, id="K3-H20"),
     pytest.param({"filter": "ekf", "layout": "clustered"}, id="ekf-clustered"),
     pytest.param({"num_landmarks": 5, "fov": 2 * math.pi, "nearest_landmarks": 12}, id="n5-K12"),
     pytest.param({"max_active": 2, "std_scale": 0.1}, id="k2-std0.1")],
)  # fmt: skip
def test_observations_are_in_the_space_and_consistent(kwargs):
    env = make(**kwargs)
    space = env.observation_space
    assert set(space.spaces) == set(OBS_KEYS)
    k = env.unwrapped.observation_config.nearest_landmarks
    h = env.unwrapped.observation_config.map_size
    expected_shapes = {"pose": (7,), "landmarks": (4 * k,), "landmarks_mask": (k,), "belief_map": (3, h, h)}
    for key, shape in expected_shapes.items():
        assert space[key].shape == shape and space[key].dtype == OBS_DTYPES[key], key
    assert space["belief_map"].low.min() == 0 and space["belief_map"].high.max() == 255
    rng = np.random.default_rng(0)
    for episode in range(2):
        obs, info = env.reset(seed=episode)
        for t in range(150):
            assert set(obs) == set(OBS_KEYS)
            for key in OBS_KEYS:
                assert obs[key].dtype == OBS_DTYPES[key] and obs[key].shape == expected_shapes[key], key
            assert space.contains(obs), (episode, t, {key: (obs[key].min(), obs[key].max()) for key in obs})
            assert all_finite(obs)
            count = min(k, info["landmarks_mapped"])
            np.testing.assert_array_equal(obs["landmarks_mask"], (np.arange(k) < count).astype(np.float32))
            rows = obs["landmarks"].reshape(k, 4)
            assert not np.any(rows[count:])
            assert obs["pose"][2] ** 2 + obs["pose"][3] ** 2 == pytest.approx(1.0, abs=1e-6)
            # swept and outside: 0 or 255; a cell outside the arena is never swept
            assert set(np.unique(obs["belief_map"][2]).tolist()) <= {0, 255}
            assert set(np.unique(obs["belief_map"][0]).tolist()) <= {0, 255}
            assert not np.any(obs["belief_map"][0] & obs["belief_map"][2])
            # a listed landmark within the raster marks its cell with a certainty of at least 1
            extent = env.unwrapped.observation_config.map_extent
            diagonal = env.unwrapped.world_config.arena_size * math.sqrt(2.0)
            step = 2.0 * extent / h
            for forward, left in rows[:count, :2].astype(np.float64) * diagonal:
                u, v = (extent - forward) / step, (extent - left) / step
                near_edge = min(abs(u - round(u)), abs(v - round(v))) < 1e-4  # float32 rounding may cross it
                if 0 <= u < h and 0 <= v < h and not near_edge:
                    assert obs["belief_map"][1, int(u), int(v)] >= 1, (forward, left)
            # nearest first
            distances = np.hypot(rows[:count, 0], rows[:count, 1])
            assert np.all(np.diff(distances) >= -1e-6)
            obs, _, terminated, truncated, info = env.step(POLICIES["random"](t, rng))
            if terminated or truncated:
                break
    env.close()


def test_returned_observations_are_not_reused():
    env = make()
    obs_0, _ = env.reset(seed=0)
    snapshot = copy.deepcopy(obs_0)
    obs_1 = env.step(np.array([1.0, 0.5], dtype=np.float32))[0]
    for key in OBS_KEYS:
        assert obs_0[key] is not obs_1[key]
    assert_same(obs_0, snapshot)
    env.close()


# == vectorised =======================================================================================
def close_vec(envs, failed: bool) -> None:
    """Close a Gymnasium vector env; after a failed call an AsyncVectorEnv would wait forever, so terminate."""
    if failed and isinstance(envs, gym.vector.AsyncVectorEnv):
        envs.close(terminate=True)
    else:
        envs.close()


@pytest.mark.parametrize("mode", ["sync", "async", "vector_entry_point"])
def test_gymnasium_make_vec(mode):
    """``gym.make_vec`` batches observations and infos (variable-length entries as object arrays), warning-free."""
    num_envs = 8
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        envs = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode=mode)
        failed = True
        try:
            single = envs.single_observation_space
            assert single == make().observation_space
            obs, infos = envs.reset(seed=0)
            for key in OBS_KEYS:
                assert obs[key].shape == (num_envs, *single[key].shape), key
                assert obs[key].dtype == single[key].dtype == OBS_DTYPES[key], key
            assert envs.observation_space.contains(obs)
            # different sub-env seeds: different layouts
            assert len({tuple(p) for p in np.round(obs["pose"][:, :2], 6)}) == num_envs
            envs.action_space.seed(0)
            for t in range(20):
                obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())
                assert rewards.shape == (num_envs,) and np.all(np.isfinite(rewards))
                assert terminated.shape == truncated.shape == (num_envs,)
                assert not terminated.any() and not truncated.any(), t
                for key in OBS_KEYS:
                    assert obs[key].shape == (num_envs, *single[key].shape) and obs[key].dtype == OBS_DTYPES[key], key
                assert envs.observation_space.contains(obs)
                for key in ("map_error", "pose_error", "step_time"):
                    assert infos[key].shape == (num_envs,) and infos[key].dtype == np.float64, key
                    assert infos[f"_{key}"].all(), key
                assert infos["true_pose"].shape == infos["pose_estimate"].shape == (num_envs, 3)
                assert infos["control"].shape == infos["executed_control"].shape == (num_envs, 2)
                assert infos["landmarks_mapped"].shape == (num_envs,)
                # the variable-length entries: one tuple per sub-env in an object array
                for key, kind in (("active_landmarks", tuple), ("measurements", Measurements)):
                    assert infos[key].shape == (num_envs,) and infos[key].dtype == object, key
                    assert all(type(value) is kind for value in infos[key]), key
                for i in range(num_envs):
                    ranges, bearings, ids = infos["measurements"][i]
                    assert len(ranges) == len(bearings) == len(ids)
                    assert len(infos["active_landmarks"][i]) <= infos["landmarks_mapped"][i]
                assert np.all(infos["step_time"] == 0.0)
            failed = False
        finally:
            close_vec(envs, failed)
    assert not caught, f"make_vec ({mode}) warned:\n" + warning_lines(caught)


def test_sync_and_async_vector_envs_agree():
    actions = fixed_actions(20, seed=9).reshape(20, 1, 2).repeat(3, axis=1)
    results = []
    for mode in ("sync", "async"):
        envs = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode=mode)
        failed = True
        try:
            obs, _ = envs.reset(seed=42)
            trace = [obs]
            for action in actions:
                obs, rewards, *_ = envs.step(action)
                trace.append((obs, rewards))
            failed = False
        finally:
            close_vec(envs, failed)
        results.append(trace)
    for t, (a, b) in enumerate(zip(*results)):
        if isinstance(a, tuple):
            assert_same(a[0], b[0], f"obs@{t}")
            np.testing.assert_array_equal(a[1], b[1])
        else:
            assert_same(a, b, "reset")


#: What SB3's ``SubprocVecEnv`` needs to build the env in its workers. SB3 (>= 2.x) starts them with
#: ``forkserver`` where available (Linux), fresh interpreters that never import seif_gym: the plain id
#: ``"SeifExplore-v0"`` is unknown there. The ``"seif_gym:SeifExplore-v0"`` id imports seif_gym first
#: (the documented way), and so does a callable that pickles by reference into seif_gym (the env
#: class); ``start_method="fork"`` workers inherit the parent's registry, so the plain id works there.
SB3_VEC_CASES = [
    pytest.param("dummy", ENV_ID, None, id="DummyVecEnv"),
    pytest.param(
        "subproc", "seif_gym:SeifExplore-v0", None, id="SubprocVecEnv-default-start-prefixed-id", marks=pytest.mark.slow
    ),
    pytest.param("subproc", "env-class", None, id="SubprocVecEnv-default-start-env-class", marks=pytest.mark.slow),
    pytest.param("subproc", ENV_ID, {"start_method": "fork"}, id="SubprocVecEnv-fork-plain-id"),
]


@pytest.mark.parametrize(("vec_env", "env_id", "vec_env_kwargs"), SB3_VEC_CASES)
def test_sb3_vec_envs(vec_env, env_id, vec_env_kwargs):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if env_id == "env-class":
        from seif_gym.envs.explore import SeifExploreEnv as env_id
    cls = DummyVecEnv if vec_env == "dummy" else SubprocVecEnv
    n_envs = 2
    envs = make_vec_env(env_id, n_envs=n_envs, seed=0, vec_env_cls=cls, vec_env_kwargs=vec_env_kwargs)
    try:
        if vec_env == "subproc":
            # the workers really run under the start method of the case (SB3's default: forkserver on Linux)
            default = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
            method = (vec_env_kwargs or {}).get("start_method", default)
            expected = {"fork": "ForkProcess", "forkserver": "ForkServerProcess", "spawn": "SpawnProcess"}[method]
            assert {type(process).__name__ for process in envs.processes} == {expected}
        single = envs.observation_space
        assert single == make().observation_space
        obs = envs.reset()
        for key in OBS_KEYS:
            assert obs[key].shape == (n_envs, *single[key].shape) and obs[key].dtype == OBS_DTYPES[key], key
        rng = np.random.default_rng(0)
        for _ in range(20):
            obs, rewards, dones, infos = envs.step(rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32))
            assert rewards.shape == (n_envs,) and np.all(np.isfinite(rewards))
            assert dones.shape == (n_envs,) and len(infos) == n_envs
            for key in OBS_KEYS:
                assert obs[key].shape == (n_envs, *single[key].shape) and obs[key].dtype == OBS_DTYPES[key], key
                assert np.all(np.isfinite(obs[key]))
            assert all("map_error" in info for info in infos)
            assert all(type(info["measurements"]) is Measurements for info in infos)
    finally:
        envs.close()


# == long runs ========================================================================================
def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def random_run(env: gym.Env, steps: int, seed: int) -> tuple[int, int]:
    """``steps`` random steps with resets; asserts finiteness. Returns (episodes, wall contacts)."""
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    episodes = walls = 0
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert math.isfinite(reward), reward
        assert all_finite(obs)
        walls += info["wall_contact"]
        if terminated or truncated:
            obs, _ = env.reset()
            assert all_finite(obs)
            episodes += 1
    return episodes, walls


@pytest.mark.slow
def test_short_random_run_is_finite_and_does_not_leak():
    """Fast companion of the 100 000-step run: traced Python memory stays flat over episodes."""
    import tracemalloc

    env = make(max_episode_steps=100)
    random_run(env, 1_000, seed=0)  # warm-up: numba, caches, first growth of the filter's buffers
    gc.collect()
    tracemalloc.start()
    try:
        random_run(env, 1_000, seed=1)
        gc.collect()
        before = tracemalloc.get_traced_memory()[0]
        random_run(env, 3_000, seed=2)
        gc.collect()
        after = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    env.close()
    assert after - before < 512 * 1024, f"traced memory grew by {(after - before) / 1024:.0f} KiB over 30 episodes"


@pytest.mark.slow
def test_100k_random_steps_no_nan_no_memory_growth():
    """A soak of 100 000 random steps: no NaN, no growth of memory (the slow tier)."""
    total, warm_up = 100_000, 10_000
    env = make()
    started = time.perf_counter()
    random_run(env, warm_up, seed=0)
    gc.collect()
    rss_before = rss_bytes()
    episodes, walls = random_run(env, total - warm_up, seed=1)
    gc.collect()
    rss_after = rss_bytes()
    elapsed = time.perf_counter() - started
    env.close()
    growth = rss_after - rss_before
    print(
        f"\n100k steps: {elapsed:.1f} s, {episodes} episodes, {walls} wall contacts, RSS growth {growth / 2**20:.2f} MiB"
    )
    assert episodes >= (total - warm_up) // 400 - 1
    assert growth < 8 * 2**20, f"RSS grew by {growth / 2**20:.1f} MiB"


def test_pose_nees_uses_the_filters_own_covariance():
    """The SEIF's exact marginal is wider than the blanket covariance: pose_nees <= pose_nees_blanket; equal for the EKF."""
    for filter_name in ("seif", "ekf"):
        env = make(filter=filter_name)
        env.reset(seed=4)
        env.action_space.seed(4)
        for _ in range(150):
            _, _, _, _, info = env.step(env.action_space.sample())
            check_info(info, env)
            if filter_name == "ekf":
                assert info["pose_nees"] == pytest.approx(info["pose_nees_blanket"], rel=1e-9)
            else:
                assert info["pose_nees"] <= info["pose_nees_blanket"] * (1 + 1e-9)
        env.close()
