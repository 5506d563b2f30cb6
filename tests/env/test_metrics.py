"""One home for each metric (``seif_gym.metrics``), its re-exports, and the helpers for threads and progress."""

from __future__ import annotations

import io
import math
import sys

import numpy as np
import pytest
import scipy.stats

import seif_gym.envs.explore as explore
import seif_gym.harness as harness
import seif_gym.observation as observation
import seif_gym.render as render
import seif_gym.slam.simulation as simulation
from seif_gym import metrics
from seif_gym.progress import Progress
from seif_gym.threads import limit_blas_threads


def test_chi2_constants_are_scipys_exact_quantiles():
    assert metrics.CHI2_95_2DOF == float(scipy.stats.chi2.ppf(0.95, 2))
    assert metrics.CHI2_975_3DOF == float(scipy.stats.chi2.ppf(0.975, 3))
    # one value everywhere: the rendered ellipses and the observation's
    assert render.CHI2_95_2DOF == observation.CHI2_2DOF_95 == metrics.CHI2_95_2DOF


def test_old_import_paths_are_the_same_objects():
    assert explore.map_error is metrics.map_error
    assert explore.filter_map_error is metrics.filter_map_error
    assert explore._nees is metrics.nees_kernel  # the env's private name for the kernel it calls
    assert simulation.pose_nees is metrics.pose_nees
    assert harness.limit_blas_threads is limit_blas_threads


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    basis = rng.normal(size=(n, n))
    return basis @ basis.T + 0.1 * np.eye(n)


def test_the_nees_computations_agree():
    """Three computations, one per caller (each keeps its bits); they agree to rounding."""
    rng = np.random.default_rng(4)
    for n in (2, 3, 5, 12):
        for _ in range(20):
            cov, error = _spd(rng, n), rng.normal(size=n)
            exact = float(error @ np.linalg.solve(cov, error))
            assert metrics.nees(error, cov) == pytest.approx(exact, rel=1e-9)
            assert metrics.nees_kernel(error, cov) == pytest.approx(exact, rel=1e-9)
    truth, estimate = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    covs = np.stack([_spd(rng, 3) for _ in range(50)])
    batched = metrics.pose_nees(truth, estimate, covs)
    for k in range(50):
        error = truth[k] - estimate[k]
        error[2] = (error[2] + math.pi) % (2 * math.pi) - math.pi
        assert batched[k] == pytest.approx(metrics.nees(error, covs[k]), rel=1e-9)
    assert metrics.nees([1.0, 0.0], [[1.0, 0.0], [0.0, -1.0]]) == math.inf  # not positive definite
    assert metrics.nees_kernel(np.ones(2), -np.eye(2)) == math.inf


def test_map_error_by_hand():
    truth = np.array([[0.0, 0.0], [3.0, 4.0], [10.0, 0.0]])
    # landmark 0 off by 0.5, landmark 2 off by 5 (capped at 2), landmark 1 unmapped (2)
    value = metrics.map_error([[0.0, 0.5], [10.0, 5.0]], truth, [0, 2], d_cap=2.0)
    assert value == pytest.approx((0.5 + 2.0 + 2.0) / 3)
    assert metrics.map_error(np.empty((0, 2)), truth, np.empty(0, dtype=np.int64), 2.0) == 2.0


@pytest.mark.parametrize(
    "args, error, match",
    [
        (([[0.0, 0.0]], [[0.0, 0.0]], [0], "2"), TypeError, "d_cap"),
        (([[0.0, 0.0]], [[0.0, 0.0]], [0], -1.0), ValueError, "d_cap"),
        (([[0.0, 0.0]], [[0.0, 0.0]], [3], 1.0), ValueError, "ids"),
        (([[0.0, 0.0]], [[0.0, 0.0]], [0, 0], 1.0), ValueError, "ids"),
        (([0.0, 0.0, 0.0], [[0.0, 0.0]], [0], 1.0), ValueError, "estimates"),
        (([[0.0, 0.0]], [0.0, 0.0], [0], 1.0), ValueError, "truth"),
    ],
)
def test_map_error_rejects_bad_input(args, error, match):
    with pytest.raises(error, match=match):
        metrics.map_error(*args)


def test_nees_rejects_bad_input():
    with pytest.raises(ValueError, match="covariance"):
        metrics.nees([1.0, 2.0], np.eye(3))
    with pytest.raises(ValueError, match="error"):
        metrics.nees(np.ones((2, 2)), np.eye(2))
    with pytest.raises(ValueError, match="finite"):
        metrics.nees([np.nan, 1.0], np.eye(2))
    with pytest.raises(ValueError, match="covariance"):
        metrics.map_nees(np.zeros((2, 2)), np.zeros((2, 2)), np.eye(3))
    with pytest.raises(ValueError, match="poses"):
        metrics.pose_nees(np.zeros(3), np.zeros(3), np.eye(2))


def test_map_nees_of_one_landmark_has_no_relative_part():
    global_nees, relative = metrics.map_nees([[1.0, 0.0]], [[0.0, 0.0]], np.eye(2))
    assert global_nees == pytest.approx(1.0) and math.isnan(relative)


def test_limit_blas_threads_limits_numpys_blas():
    from threadpoolctl import threadpool_info

    libraries = limit_blas_threads(1)
    assert all(isinstance(path, str) for path in libraries)
    assert all(info["num_threads"] == 1 for info in threadpool_info() if info["user_api"] == "blas")
    with pytest.raises(ValueError, match="count"):
        limit_blas_threads(0)
    with pytest.raises(TypeError, match="count"):
        limit_blas_threads(1.5)


def test_progress_is_silent_when_disabled_and_plain_without_tqdm(monkeypatch):
    stream = io.StringIO()
    with Progress(10, "quiet", enabled=False, stream=stream) as bar:
        for _ in range(10):
            bar.update(1, "x")
        bar.write("a line")
    assert stream.getvalue() == "" and bar.done == 10
    monkeypatch.setitem(sys.modules, "tqdm", None)  # as if tqdm were not installed
    stream = io.StringIO()
    with Progress(20, "plain", unit="episodes", stream=stream) as bar:
        for k in range(20):
            bar.update(1, f"seed {k}")
    lines = stream.getvalue().splitlines()
    assert len(lines) == 10 and lines[-1].startswith("plain: 20/20 episodes (100%)") and "seed 19" in lines[-1]
    with pytest.raises(ValueError, match="total"):
        Progress(0, "nothing")
    with pytest.raises(TypeError, match="total"):
        Progress(2.5, "nothing")
