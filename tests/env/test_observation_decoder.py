"""``ObservationDecoder``: the inverse of ``BeliefEncoder``, with the numbers of the env that encoded."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import seif_gym
from seif_gym.observation import BeliefRaster, ObservationConfig, ObservationDecoder, landmark_rows


def _drive(env_id: str, steps: int = 40, **kwargs):
    env = gym.make(env_id, max_episode_steps=steps + 5, **kwargs)
    obs, _ = env.reset(seed=2)
    for t in range(steps):
        obs, *_ = env.step(np.array([0.9, 0.6 * math.sin(t / 7.0)]))
    return env, obs


@pytest.mark.parametrize("env_id", [i for i in seif_gym.VARIANTS if i.endswith("-v1")])
def test_decoding_inverts_encoding(env_id: str):
    env, obs = _drive(env_id)
    base = env.unwrapped
    decoder = ObservationDecoder.from_env(env)
    assert decoder == base.encoder.decoder() and decoder.arena_size == base.world_config.arena_size
    filt = base.filter
    x, y, theta, sx, sy, st = decoder.pose(obs)
    np.testing.assert_allclose([x, y], filt.pose[:2], atol=1e-5 * decoder.half_arena)
    assert abs((theta - filt.pose[2] + math.pi) % (2 * math.pi) - math.pi) < 1e-6
    cov = base.encoder.pose_covariance  # what the observation shows
    np.testing.assert_allclose([sx, sy, st], np.sqrt(np.diag(cov)), rtol=1e-5, atol=1e-7)
    nearest = base.encoder.nearest(filt.pose, filt.landmarks)
    positions = decoder.landmark_positions(obs)
    assert len(positions) == len(nearest) > 0
    np.testing.assert_allclose(positions, filt.landmarks[nearest], atol=1e-5 * decoder.diagonal)
    rows, mask = decoder.landmarks(obs)
    assert mask.sum() == len(nearest) and np.all(rows[~mask] == 0.0)
    assert np.all(rows[mask, 2] >= rows[mask, 3])  # major >= minor semi-axis
    belief = decoder.belief_map(obs)
    assert belief.shape == (3, base.observation_config.map_size, base.observation_config.map_size)
    assert belief.min() >= 0.0 and belief.max() <= 1.0


def test_the_raster_and_the_units():
    decoder = ObservationDecoder(40.0, ObservationConfig(map_size=16, map_extent=4.0))
    raster = decoder.raster()
    assert isinstance(raster, BeliefRaster) and raster.forward.shape == (16, 16) and raster.cell == 0.5
    assert raster.forward[0, 0] == 3.75 and raster.left[0, 0] == 3.75  # row 0 ahead, column 0 left
    assert raster.forward[-1, 0] == -3.75 and raster.left[0, -1] == -3.75
    assert decoder.half_arena == 20.0 and decoder.diagonal == pytest.approx(40.0 * math.sqrt(2.0))
    assert landmark_rows(np.arange(8.0)).shape == (2, 4)


def test_another_envs_observation_or_a_foreign_env_is_refused():
    small, obs = _drive("SeifExplore-v1", steps=2, map_size=36)
    decoder = ObservationDecoder.from_env(gym.make("SeifExplore-v1"))
    with pytest.raises(ValueError, match="belief_map"):
        decoder.pose(obs)
    with pytest.raises(ValueError, match="no 'pose'"):
        decoder.check({})
    with pytest.raises(TypeError, match="env"):
        ObservationDecoder.from_env(None)
    with pytest.raises(TypeError, match="SeifExplore"):
        ObservationDecoder.from_env(gym.make("CartPole-v1"))
    with pytest.raises(ValueError, match="arena_size"):
        ObservationDecoder(-1.0)
    with pytest.raises(TypeError, match="config"):
        ObservationDecoder(20.0, {"map_size": 40})
