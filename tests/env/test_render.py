"""Rendering of SeifExplore: rgb_array frames, every filter and variant, RecordVideo, human mode."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import seif_gym
from seif_gym.render import FRAME_SHAPE, Renderer, ellipse_parameters


def _colours(frame: np.ndarray) -> int:
    return len(np.unique(frame.reshape(-1, 3), axis=0))


def _steps(env, count: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(count):
        action = np.array([rng.uniform(0.3, 1.0), rng.uniform(-1.0, 1.0)], dtype=np.float32)
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()


def _check_frame(frame) -> None:
    assert isinstance(frame, np.ndarray)
    assert frame.shape == FRAME_SHAPE
    assert frame.dtype == np.uint8
    assert frame.flags["C_CONTIGUOUS"]
    assert _colours(frame) > 20  # not blank: walls, landmarks, paths, legend, text


@pytest.mark.parametrize("filter_name", ["seif", "eif", "ekf"])
def test_rgb_array_frames(filter_name):
    env = gym.make("SeifExplore-v0", render_mode="rgb_array", filter=filter_name)
    env.reset(seed=1)
    first = env.render()
    _check_frame(first)
    _steps(env, 15)
    later = env.render()
    _check_frame(later)
    assert not np.array_equal(first, later)  # the robot moved, the map grew
    # the renderer hands out a fresh array: an earlier frame is not overwritten
    assert not np.shares_memory(first, later)
    env.close()
    assert env.unwrapped._renderer is None


def test_information_panel_only_with_information_matrix():
    """The sparsity panel (red robot rows) is drawn for SEIF/EIF and left out for the EKF, at the same state."""
    frames = {}
    for filter_name in ("seif", "ekf"):
        env = gym.make("SeifExplore-v0", render_mode="rgb_array", filter=filter_name)
        env.reset(seed=2)
        _steps(env, 5)
        frames[filter_name] = env.render()
        env.close()
    panel = (slice(232, 340), slice(480, 588))  # the right column, where the panel sits
    assert _colours(frames["seif"][panel]) > _colours(frames["ekf"][panel])
    assert np.all(frames["ekf"][panel] == 255)


@pytest.mark.parametrize("env_id", sorted(seif_gym.VARIANTS))
def test_every_variant_renders(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    _steps(env, 3)
    _check_frame(env.render())
    env.close()


def test_render_without_mode_warns_and_returns_none():
    env = gym.make("SeifExplore-v0")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None
    env.close()


def test_record_video(tmp_path):
    pytest.importorskip("moviepy")
    env = gym.make("SeifExplore-v0", render_mode="rgb_array", max_episode_steps=20)
    env = gym.wrappers.RecordVideo(
        env, str(tmp_path / "videos"), episode_trigger=lambda episode: episode == 0, disable_logger=True
    )
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.array([0.8, 0.2], dtype=np.float32))
        done = terminated or truncated
    env.close()
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1
    assert videos[0].stat().st_size > 1000


def test_human_mode_uses_a_window(monkeypatch):
    plt = pytest.importorskip("matplotlib.pyplot")
    previous = plt.get_backend()
    plt.switch_backend("agg")  # no window pops up during the tests
    monkeypatch.setattr(plt, "pause", lambda interval: None)
    try:
        env = gym.make("SeifExplore-v0", render_mode="human", max_episode_steps=5)
        env.reset(seed=0)  # human mode renders in reset and step
        _steps(env, 2)
        renderer = env.unwrapped._renderer
        window = renderer._window
        assert window is not None and plt.fignum_exists(window.number)
        assert env.render() is None
        env.close()
        assert not plt.fignum_exists(window.number)
    finally:
        plt.switch_backend(previous)


@pytest.mark.slow
def test_import_needs_no_pyplot():
    """rgb_array rendering never imports pyplot, so it needs no display and leaves the backend alone."""
    code = (
        "import sys, gymnasium as gym, seif_gym, seif_gym.render\n"
        "env = gym.make('SeifExplore-v0', render_mode='rgb_array')\n"
        "env.reset(seed=0); env.render(); env.close()\n"
        "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot imported'\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr


def test_ellipse_parameters():
    covs = np.array([[[4.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 9.0]]])
    widths, heights, angles = ellipse_parameters(covs, chi2=1.0)
    np.testing.assert_allclose(widths, [4.0, 6.0])
    np.testing.assert_allclose(heights, [2.0, 2.0])
    np.testing.assert_allclose(np.abs(angles) % 180, [0.0, 90.0])
    assert all(len(a) == 0 for a in ellipse_parameters(np.empty((0, 2, 2))))


def test_many_landmarks_use_the_block_diagonal(monkeypatch):
    """Past EXACT_ELLIPSES_LIMIT the SEIF's ellipses come from its own 2x2 information blocks."""
    import seif_gym.render as render

    env = gym.make("SeifExplore-v0", render_mode="rgb_array")
    env.reset(seed=0)
    _steps(env, 10)
    filt = env.unwrapped.filter
    exact_pose, exact = render._covariances(filt)
    monkeypatch.setattr(render, "EXACT_ELLIPSES_LIMIT", 0)
    pose, blocks = render._covariances(filt)
    assert blocks.shape == exact.shape == (filt.num_landmarks, 2, 2)
    # conditioning on the rest of the map can only shrink a landmark's covariance
    assert np.all(np.trace(blocks, axis1=1, axis2=2) <= np.trace(exact, axis1=1, axis2=2) + 1e-12)
    _check_frame(env.render())
    env.close()


def test_renderer_standalone():
    env = gym.make("SeifExplore-v0").unwrapped
    env.reset(seed=0)
    renderer = Renderer(env.world_config.arena_size, env.sensor)
    _check_frame(renderer.draw(env))
    renderer.close()
