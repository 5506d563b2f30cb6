"""seif_gym.slam.rollout: the compiled look-ahead equals deep copies stepped by the filter, bit for bit."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from seif_gym.slam import EIF, ESEIF, SEIF, RangeBearingSensor, _kernels, rollout
from seif_gym.slam.rollout import (
    compiled_rollouts_support,
    expected_rollouts,
    expected_rollouts_reference,
)

#: Every (v, w) of a small grid, turning in place included (the info_gain planner's kind of candidates).
CONTROLS = np.array([(v, w) for v in (0.0, 0.5, 1.0) for w in (-1.0, -0.3, 0.0, 0.6, 1.0)])


def _filter(ring_loop_run, kind, steps, fov=np.pi, **options):
    """A filter fed ``steps`` steps of the ring run; its sensor sees a ``fov`` wide field (the rollout's)."""
    motion, run_sensor, run = ring_loop_run
    sensor = RangeBearingSensor(sigma_range=run_sensor.sigma_range, sigma_bearing=run_sensor.sigma_bearing,
                                max_range=run_sensor.max_range, fov=fov)  # fmt: skip
    filt = kind(motion, sensor, run.initial_pose, **options)
    for t in range(steps):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    return filt, run.dt


def _assert_equal(got, expected):
    for name in ("poses", "pose_covariances", "landmark_std"):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name), err_msg=name)


@pytest.mark.parametrize(
    "kind, steps, fov, options",
    [
        (SEIF, 0, np.pi, {}),  # no landmark yet
        (SEIF, 60, np.pi, {}),
        (SEIF, 300, np.pi, {}),  # the loop closed: a long recovery queue
        (SEIF, 200, 2 * np.pi, {"max_active": 4}),
        (SEIF, 150, np.pi, {"max_active": None}),
        (ESEIF, 200, np.pi, {"max_active": 4}),
    ],
)
def test_compiled_rollouts_equal_deep_copies_bit_for_bit(ring_loop_run, kind, steps, fov, options):
    filt, dt = _filter(ring_loop_run, kind, steps, fov, **options)
    assert compiled_rollouts_support(filt) is None
    before = pickle.dumps(filt)
    got = expected_rollouts(filt, CONTROLS, dt, 8)
    assert pickle.dumps(filt) == before, "the rollout changed the filter"
    expected = expected_rollouts_reference(filt, CONTROLS, dt, 8)
    _assert_equal(got, expected)
    assert got.poses.shape == (len(CONTROLS), 8, 3) and got.landmark_std.shape == (len(CONTROLS), filt.num_landmarks)


def test_neighbour_lists_grow_when_a_step_needs_more_room(ring_loop_run, monkeypatch):
    filt, dt = _filter(ring_loop_run, SEIF, 250)
    monkeypatch.setattr(rollout, "_SPARE_DEGREE", 0)
    _assert_equal(expected_rollouts(filt, CONTROLS, dt, 8), expected_rollouts_reference(filt, CONTROLS, dt, 8))


def test_other_filters_roll_through_their_own_steps(ring_loop_run):
    filt, dt = _filter(ring_loop_run, EIF, 40)
    assert "EIF" in compiled_rollouts_support(filt)
    _assert_equal(expected_rollouts(filt, CONTROLS[:3], dt, 3), expected_rollouts_reference(filt, CONTROLS[:3], dt, 3))
    gated, _ = _filter(ring_loop_run, SEIF, 10, innovation_gate=13.8)
    assert compiled_rollouts_support(gated) == "an innovation gate"


def test_bad_input_is_refused(ring_loop_run):
    filt, dt = _filter(ring_loop_run, SEIF, 5)
    with pytest.raises(TypeError, match="filt"):
        expected_rollouts(object(), CONTROLS, dt, 8)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="controls"):
        expected_rollouts(filt, CONTROLS[:, :1], dt, 8)
    with pytest.raises(ValueError, match="controls"):
        expected_rollouts(filt, np.empty((0, 2)), dt, 8)
    with pytest.raises(ValueError, match="dt"):
        expected_rollouts(filt, CONTROLS, 0.0, 8)
    with pytest.raises(ValueError, match="horizon"):
        expected_rollouts(filt, CONTROLS, dt, 0)


def test_unlogged_wavefront_equals_the_logged_one(ring_loop_run):
    """The scratch copies' recovery: the same means and the same queue as the filter's, bit for bit."""
    filt, _ = _filter(ring_loop_run, SEIF, 300)  # the loop closed: the queue holds most of the map
    store, queue = filt._store, filt._queue
    assert len(queue) > 10
    seeds = np.arange(8, dtype=np.int64)
    seeds = seeds[~filt._is_active[seeds]]
    results = []
    for unlogged in (False, True):
        mean, items, queued, state = store.mean.copy(), queue.items.copy(), queue.queued.copy(), queue.state.copy()
        arrays = (*store.kernel_arrays()[:7], mean, store.block_position, filt._active, seeds, items, queued, state)
        if unlogged:
            _kernels.recover_mean_wavefront_unlogged(*arrays, 64, 1.8, 1e-4)
        else:
            size = (len(seeds) + len(filt._active) + 64) * (2 + store.degree) + 1
            undo = (np.empty(size, np.int8), np.empty(size, np.int64), np.empty((size, 2)), np.zeros(1, np.int64))
            _kernels.recover_mean_wavefront(*arrays, 64, 1.8, 1e-4, *undo)
        results.append((mean, items, queued, state))
    for logged, unlogged in zip(*results):
        np.testing.assert_array_equal(unlogged, logged)
    assert not np.array_equal(results[0][0], store.mean)  # it did move the means
