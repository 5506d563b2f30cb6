"""Unit tests of :mod:`seif_gym.world` and :mod:`seif_gym.observation` (the env's building blocks)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from seif_gym.observation import BeliefEncoder, ObservationConfig
from seif_gym.slam import RangeBearingSensor, VelocityMotionModel, make_filter
from seif_gym.world import LAYOUTS, World, WorldConfig, make_landmarks

NOISE_FREE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def noise_free_world(pose, landmarks=((0.0, 0.0),), arena_size=20.0, fov=math.pi, max_range=5.0) -> World:
    config = WorldConfig(arena_size=arena_size, num_landmarks=len(landmarks))
    sensor = RangeBearingSensor(sigma_range=1e-9, sigma_bearing=1e-9, max_range=max_range, fov=fov)
    return World(
        config, VelocityMotionModel(alphas=NOISE_FREE), sensor, np.array(landmarks, float), np.array(pose, float)
    )


# == WorldConfig and make_landmarks ===================================================================
@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        ({"arena_size": 0.0}, ValueError, "arena_size"),
        ({"arena_size": float("inf")}, ValueError, "arena_size"),
        ({"layout": "maze"}, ValueError, "layout"),
        ({"num_landmarks": 0}, ValueError, "num_landmarks"),
        ({"num_landmarks": 10_001}, ValueError, "num_landmarks"),
        ({"num_landmarks": 3.0}, TypeError, "num_landmarks"),
        ({"num_landmarks": False}, TypeError, "num_landmarks"),
        ({"wall_margin": -1.0}, ValueError, "wall_margin"),
        ({"wall_margin": 5.0}, ValueError, "wall_margin"),
    ],
    ids=lambda value: repr(value) if isinstance(value, dict) else None,
)
def test_world_config_validation(kwargs, error, name):
    with pytest.raises(error, match=name):
        WorldConfig(**kwargs)


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("num_landmarks", [1, 7, 120])
def test_make_landmarks_shape_bounds_and_determinism(layout, num_landmarks):
    config = WorldConfig(arena_size=20.0, layout=layout, num_landmarks=num_landmarks, wall_margin=1.0)
    a = make_landmarks(config, np.random.default_rng(5))
    b = make_landmarks(config, np.random.default_rng(5))
    c = make_landmarks(config, np.random.default_rng(6))
    assert a.shape == (num_landmarks, 2) and a.dtype == np.float64
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.all(np.abs(a) <= config.half_size - config.wall_margin)


def test_loop_layout_lies_on_a_ring():
    config = WorldConfig(arena_size=40.0, layout="loop", num_landmarks=2000, wall_margin=1.0)
    radii = np.hypot(*make_landmarks(config, np.random.default_rng(0)).T)
    assert np.median(radii) == pytest.approx(0.35 * 40.0, rel=0.02)
    assert np.std(radii) == pytest.approx(0.05 * 40.0, rel=0.1)


def test_clustered_layout_is_clustered():
    """Most landmarks are much closer to their nearest neighbour than in the uniform layout."""
    rng_seed = 3

    def mean_nn(layout):
        config = WorldConfig(arena_size=20.0, layout=layout, num_landmarks=60)
        p = make_landmarks(config, np.random.default_rng(rng_seed))
        d = np.hypot(*(p[:, None, :] - p[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        return d.min(axis=1).mean()

    assert mean_nn("clustered") < 0.8 * mean_nn("uniform")


# == World ============================================================================================
def test_world_landmarks_are_read_only():
    world = noise_free_world((0, 0, 0))
    with pytest.raises(ValueError):
        world.landmarks[0, 0] = 1.0


def test_free_step_follows_the_motion_model():
    world = noise_free_world((0.0, 0.0, 0.0))
    executed, wall = world.step(np.array([1.0, 0.0]), 0.5, np.random.default_rng(0))
    assert wall is False
    np.testing.assert_array_equal(executed, [1.0, 0.0])
    np.testing.assert_allclose(world.pose, [0.5, 0.0, 0.0], atol=1e-12)
    executed, wall = world.step(np.array([1.0, 1.0]), 0.5, np.random.default_rng(0))
    np.testing.assert_allclose(world.pose, world.motion.predict(np.array([0.5, 0.0, 0.0]), np.array([1.0, 1.0]), 0.5))


@pytest.mark.parametrize(
    ("pose", "control"),
    [
        ((9.9, 0.0, 0.0), (1.0, 0.3)),  # east wall, driving forward
        ((-9.9, 2.0, 0.0), (-1.0, -0.2)),  # west wall, reversing
        ((0.0, 9.95, math.pi / 2), (0.5, 0.0)),  # north wall
        ((3.0, -9.9, -math.pi / 2), (1.0, 1.0)),  # south wall
    ],
)
def test_wall_blocks_translation_and_keeps_the_turn(pose, control):
    world = noise_free_world(pose)
    before = world.pose.copy()
    executed, wall = world.step(np.array(control), 0.25, np.random.default_rng(0))
    assert wall is True
    np.testing.assert_array_equal(executed, [0.0, control[1]])
    np.testing.assert_allclose(world.pose[:2], before[:2], atol=1e-12)
    expected_heading = math.remainder(before[2] + control[1] * 0.25, 2 * math.pi)
    assert world.pose[2] == pytest.approx(expected_heading, abs=1e-12)


def test_step_towards_the_centre_near_the_wall_is_free():
    world = noise_free_world((9.9, 0.0, math.pi))
    executed, wall = world.step(np.array([1.0, 0.0]), 0.25, np.random.default_rng(0))
    assert wall is False and executed[0] == 1.0
    assert world.pose[0] == pytest.approx(9.65)


def test_noise_never_takes_the_robot_outside():
    config = WorldConfig(arena_size=4.0, num_landmarks=1, wall_margin=0.5)
    motion = VelocityMotionModel(alphas=(0.5, 0.5, 0.5, 0.5, 0.5, 0.5))
    world = World(config, motion, RangeBearingSensor(), np.zeros((1, 2)), np.array([1.9, 1.9, 0.7]))
    rng = np.random.default_rng(0)
    walls = 0
    for _ in range(2000):
        _, wall = world.step(rng.uniform(-1, 1, 2) * [2.0, 3.0], 0.25, rng)
        walls += wall
        assert world.inside(world.pose[:2]), world.pose
        assert -math.pi <= world.pose[2] <= math.pi
    assert walls > 0


def test_measure_sees_only_landmarks_in_range_and_field_of_view():
    landmarks = [(2.0, 0.0), (0.5, 3.0), (-2.0, 0.0), (6.0, 0.0), (4.0, 4.0), (0.5, -4.8)]
    world = noise_free_world((0.0, 0.0, 0.0), landmarks=landmarks, fov=math.pi, max_range=5.0)
    ranges, bearings, ids = world.measure(np.random.default_rng(0))
    # ahead (0), ahead-left (1), ahead-right (5); not behind (2), not beyond 5 m (3, 4)
    assert ids.tolist() == [0, 1, 5]
    np.testing.assert_allclose(ranges, world.sensor.predict(world.pose, np.array(landmarks)[ids])[:, 0], atol=1e-6)
    np.testing.assert_allclose(bearings, world.sensor.predict(world.pose, np.array(landmarks)[ids])[:, 1], atol=1e-6)
    all_round = noise_free_world((0.0, 0.0, 0.0), landmarks=landmarks, fov=2 * math.pi, max_range=5.0)
    _, _, ids = all_round.measure(np.random.default_rng(0))
    assert ids.tolist() == [0, 1, 2, 5]


# == BeliefEncoder ====================================================================================
def encoder_and_filter(pose, landmarks, filter_name="ekf", arena_size=20.0, config=None, fov=2 * math.pi):
    sensor = RangeBearingSensor(max_range=8.0, fov=fov)
    motion = VelocityMotionModel()
    filt = make_filter(filter_name, motion, sensor, np.array(pose, float))
    z = sensor.predict(np.array(pose, float), np.array(landmarks, float))
    filt.update(z[:, 0], z[:, 1], np.arange(len(landmarks)))
    encoder = BeliefEncoder(arena_size, sensor, config or ObservationConfig())
    return encoder, filt


def test_encoder_space_and_shapes():
    config = ObservationConfig(nearest_landmarks=5, map_size=12)
    encoder, filt = encoder_and_filter((0, 0, 0), [(2.0, 0.0)], config=config)
    obs = encoder.encode(filt)
    assert encoder.observation_space.contains(obs)
    # flat 1-D vectors and a channel-first uint8 image (what stable-baselines3 expects)
    assert obs["landmarks"].shape == (5 * 4,) and obs["landmarks"].dtype == np.float32
    assert obs["landmarks_mask"].shape == (5,) and obs["pose"].shape == (7,)
    assert obs["belief_map"].shape == (3, 12, 12) and obs["belief_map"].dtype == np.uint8
    space = encoder.observation_space["belief_map"]
    assert space.dtype == np.uint8 and np.all(space.low == 0) and np.all(space.high == 255)
    assert encoder.observation_space["landmarks"].shape == (20,)


def test_default_map_size_is_large_enough_for_sb3_image_checks():
    from stable_baselines3.common.preprocessing import is_image_space

    config = ObservationConfig()
    assert config.map_size == 40 and config.map_size >= 36  # SB3's NatureCNN minimum
    encoder, _ = encoder_and_filter((0, 0, 0), [(2.0, 0.0)], config=config)
    assert is_image_space(encoder.observation_space["belief_map"])


@pytest.mark.parametrize("filter_name", ["ekf", "eif", "seif"])
@pytest.mark.parametrize("heading", [0.0, 1.0, -2.5])
def test_landmark_features_are_egocentric_and_nearest_first(filter_name, heading):
    pose = np.array([1.0, -2.0, heading])
    c, s = math.cos(heading), math.sin(heading)
    # in the robot frame: 2 m ahead, 3 m to the left, 4 m to the right-behind
    local = np.array([[2.0, 0.0], [0.0, 3.0], [-2.0, -3.4641016]])
    world_points = pose[:2] + local @ np.array([[c, s], [-s, c]])
    encoder, filt = encoder_and_filter(pose, world_points, filter_name)
    obs = encoder.encode(filt)
    assert obs["landmarks"].shape == (8 * 4,)
    rows = obs["landmarks"].reshape(8, 4)  # (forward, left, major, minor) per landmark
    diagonal = 20.0 * math.sqrt(2.0)
    np.testing.assert_allclose(rows[:3, :2], local / diagonal, atol=1e-4)
    np.testing.assert_array_equal(obs["landmarks_mask"], [1, 1, 1, 0, 0, 0, 0, 0])
    assert np.all(rows[:3, 2] >= rows[:3, 3])  # major >= minor
    assert np.all(rows[:3, 3] > 0)
    assert not np.any(rows[3:])  # zeros pad
    np.testing.assert_allclose(obs["pose"][:4], [1.0 / 10.0, -2.0 / 10.0, c, s], atol=1e-6)


def test_nearest_returns_the_k_nearest_in_order():
    encoder, _ = encoder_and_filter((0, 0, 0), [(1.0, 0.0)], config=ObservationConfig(nearest_landmarks=4))
    rng = np.random.default_rng(0)
    landmarks = rng.uniform(-10, 10, (50, 2))
    pose = np.array([0.5, -0.5, 0.0])
    expected = np.argsort(np.hypot(*(landmarks - pose[:2]).T), kind="stable")[:4]
    np.testing.assert_array_equal(encoder.nearest(pose, landmarks), expected)
    np.testing.assert_array_equal(
        encoder.nearest(pose, landmarks[:2]), np.argsort(np.hypot(*(landmarks[:2] - pose[:2]).T))
    )
    assert len(encoder.nearest(pose, np.empty((0, 2)))) == 0


def test_belief_map_orientation():
    """Row 0 is ahead, column 0 is left; channel 2 marks the outside of the arena."""
    config = ObservationConfig(map_size=16, map_extent=8.0)
    # robot near the east wall (x = 7 of 10), heading north; one landmark 4.5 m ahead (0.5 m left),
    # one 4.5 m to the left (0.5 m ahead); cells are 1 m
    pose = (7.0, 0.0, math.pi / 2)
    encoder, filt = encoder_and_filter(pose, [(6.5, 4.5), (2.5, 0.5)], config=config)
    obs = encoder.encode(filt)
    landmarks_channel, outside = obs["belief_map"][1], obs["belief_map"][2]
    rows, cols = np.nonzero(landmarks_channel)
    cells = sorted(zip(rows.tolist(), cols.tolist()))
    # row = floor(8 - forward), column = floor(8 - left)
    assert cells == [(3, 7), (7, 3)]
    # east of the robot is its right: the rightmost columns are outside (x > 10), the leftmost are not
    assert np.all(outside[:, -1] == 255) and np.all(outside[:, 0] == 0)
    assert np.all(outside[:, :8] == 0)
    assert set(np.unique(outside).tolist()) == {0, 255}


def test_swept_area_comes_from_the_sweeps_only():
    config = ObservationConfig(map_size=16, map_extent=8.0)
    encoder, filt = encoder_and_filter((0.0, 0.0, 0.0), [(2.0, 0.0)], config=config, fov=math.pi)
    assert not np.any(encoder.encode(filt)["belief_map"][0])  # nothing swept yet
    encoder.sweep(filt.pose)
    swept = encoder.encode(filt)["belief_map"][0]
    assert swept.dtype == np.uint8 and set(np.unique(swept).tolist()) == {0, 255}
    assert swept[2, 8] == 255  # 5.5 m ahead: within the sensor's 8 m
    assert swept[15, 8] == 0  # behind, outside the half-plane field of view
    encoder.reset()
    assert not np.any(encoder.encode(filt)["belief_map"][0])


def test_encode_has_no_side_effect_on_the_swept_area():
    encoder, filt = encoder_and_filter((0.0, 0.0, 0.3), [(2.0, 0.0)])
    encoder.sweep(filt.pose)
    coverage = encoder.coverage.copy()
    first = encoder.encode(filt)
    second = encoder.encode(filt)
    np.testing.assert_array_equal(encoder.coverage, coverage)
    for key in first:
        np.testing.assert_array_equal(first[key], second[key])


@pytest.mark.parametrize("std_scale", [1.0, 0.01, 1e-4])
def test_belief_map_landmark_channel_is_255_times_the_confidence(std_scale):
    """Channel 1 is ``round(255 / (1 + std / s))``, at least 1 where a landmark is (however uncertain)."""
    config = ObservationConfig(map_size=16, map_extent=8.0, std_scale=std_scale)
    landmarks = [(2.5, 0.5), (0.5, 3.5), (-4.5, -2.5)]
    encoder, filt = encoder_and_filter((0.0, 0.0, 0.0), landmarks, config=config)
    channel = encoder.encode(filt)["belief_map"][1]
    assert channel.dtype == np.uint8
    confidence = 1.0 / (1.0 + filt.landmark_std() / std_scale)
    expected = np.clip(np.round(255.0 * confidence), 1, 255).astype(np.uint8)
    for k, (x, y) in enumerate(np.asarray(filt.landmarks)):
        i, j = int((8.0 - x) / 1.0), int((8.0 - y) / 1.0)  # heading 0: forward = x, left = y; 1 m cells
        assert channel[i, j] == expected[k], (k, channel[i, j], expected[k])
    assert np.count_nonzero(channel) == len(landmarks)
    if std_scale == 1e-4:
        assert np.all(expected == 1)  # tiny confidences still mark the cell


@pytest.mark.parametrize("resolution, size, extent", [(0.5, 40, 8.0), (0.3, 16, 8.0), (0.7, 37, 5.5)])
def test_fast_belief_map_equals_the_reference_bit_for_bit(resolution, size, extent):
    """The encoders' ``_fill_belief_map`` equals the readable ``_belief_map``: every channel of every cell.

    Poses inside, on the edge of and outside the arena, any heading (also beyond [-pi, pi)), landmarks
    in and out of the raster, a random coverage grid.
    """
    from seif_gym.observation import _belief_map, _fill_belief_map

    rng = np.random.default_rng(3)
    half_arena = 10.0
    cells = math.ceil(2 * half_arena / resolution)
    out = np.full((3, size, size), 7, dtype=np.uint8)  # stale values: every cell must be written
    outside = swept = 0
    for trial in range(300):
        coverage = (rng.random((cells, cells)) < rng.random()).astype(np.uint8)
        x, y = rng.uniform(-13.0, 13.0, 2) if trial % 3 else rng.choice([-10.0, 10.0, 0.0], 2)
        theta = rng.uniform(-8.0, 8.0) if trial % 5 else rng.choice([0.0, math.pi / 2, -math.pi])
        landmarks = rng.uniform(-12.0, 12.0, (rng.integers(0, 40), 2))
        confidence = rng.random(landmarks.shape[0])
        expected = _belief_map(coverage, resolution, half_arena, x, y, theta, size, extent, landmarks, confidence)
        _fill_belief_map(out, coverage, resolution, half_arena, x, y, theta, size, extent, landmarks, confidence)
        np.testing.assert_array_equal(out, expected, err_msg=f"trial {trial}")
        outside += bool(np.any(expected[2] == 255))
        swept += bool(np.any(expected[0] == 255))
    assert outside > 50 and swept > 50  # both branches of a cell were compared many times


def test_batched_world_equals_worlds_bit_for_bit():
    from seif_gym.world import BatchedWorld

    config = WorldConfig(arena_size=12.0, num_landmarks=25)
    motion = VelocityMotionModel(alphas=(0.01, 0.001, 0.001, 0.01, 0.0005, 0.0005))
    sensor = RangeBearingSensor(sigma_range=0.1, sigma_bearing=0.035, max_range=5.0, fov=np.pi)
    n = 4
    batch = BatchedWorld(n, config, motion, sensor, buffer=60)  # small buffer: refills happen often
    worlds, rngs = [], []
    for e in range(n):
        rng = np.random.default_rng(100 + e)
        landmarks = make_landmarks(config, rng)
        start = np.array([*rng.uniform(-3, 3, 2), rng.uniform(-np.pi, np.pi)])
        motion_rng, sensor_rng = np.random.default_rng(e), np.random.default_rng(50 + e)
        worlds.append(World(config, motion, sensor, landmarks, start))
        rngs.append((motion_rng, sensor_rng))
        batch.reset(e, landmarks, start, *(np.random.default_rng(e), np.random.default_rng(50 + e)))
    actions = np.random.default_rng(7)
    walls = 0
    for _ in range(600):
        controls = actions.uniform([-0.2, -1.0], [1.0, 1.0], size=(n, 2))
        executed, wall = batch.step(controls, 0.25)
        ranges, bearings, ids, counts = batch.measure()
        for e, world in enumerate(worlds):
            expected_control, expected_wall = world.step(controls[e], 0.25, rngs[e][0])
            r, b, i = world.measure(rngs[e][1])
            np.testing.assert_array_equal(batch.poses[e], world.pose)
            np.testing.assert_array_equal(executed[e], expected_control)
            assert wall[e] == expected_wall
            assert counts[e] == len(i)
            np.testing.assert_array_equal(ranges[e, : counts[e]], r)
            np.testing.assert_array_equal(bearings[e, : counts[e]], b)
            np.testing.assert_array_equal(ids[e, : counts[e]], i)
            walls += expected_wall
    assert walls > 10  # the wall branch was exercised
