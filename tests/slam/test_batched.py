"""BatchedSEIF: N SEIFs in one compiled call equal N SEIF objects, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from seif_gym.slam import ESEIF, SEIF, ConservativeSEIF
from seif_gym.slam.batched import BatchedConservativeSEIF, BatchedESEIF, BatchedSEIF
from seif_gym.slam.scenarios import FIDELITY_SCENARIOS, make_loop_run


def _assert_same(batch: BatchedSEIF, e: int, filt: SEIF, step: int) -> None:
    store = filt._store
    n = store.num_landmarks
    where = f"filter {e}, step {step}"
    assert batch.counters[e, 0] == n, where
    dim = 3 + 2 * n
    np.testing.assert_array_equal(batch.mean[e, :dim], store.mean[:dim], err_msg=where)
    np.testing.assert_array_equal(batch.information_vector[e, :dim], store.information_vector[:dim], err_msg=where)
    np.testing.assert_array_equal(batch.robot_info[e], store.robot_info, err_msg=where)
    np.testing.assert_array_equal(batch.robot_links[e, :n], store.robot_links[:n], err_msg=where)
    np.testing.assert_array_equal(batch.landmark_info[e, :n], store.landmark_info[:n], err_msg=where)
    np.testing.assert_array_equal(batch.neighbour_count[e, :n], store.neighbour_count[:n], err_msg=where)
    for i in range(n):
        count = store.neighbour_count[i]
        np.testing.assert_array_equal(
            batch.neighbour_index[e, i, :count], store.neighbour_index[i, :count], err_msg=where
        )
        np.testing.assert_array_equal(
            batch.neighbour_info[e, i, :count], store.neighbour_info[i, :count], err_msg=where
        )
    np.testing.assert_array_equal(batch.active_landmarks(e), filt.active_landmarks, err_msg=where)
    np.testing.assert_array_equal(batch.landmark_ids(e), filt.landmark_ids, err_msg=where)
    np.testing.assert_array_equal(batch.last_observed[e, :n], filt._last_observed[:n], err_msg=where)
    assert batch.counters[e, 2] == filt._update_count and batch.counters[e, 3] == filt._round_robin, where
    np.testing.assert_array_equal(batch.queue_state[e, 1], filt._queue.state[1], err_msg=where)


@pytest.mark.slow
@pytest.mark.parametrize(
    "batch_class, scenario, max_active",
    [
        (BatchedSEIF, "circle", 8),
        (BatchedSEIF, "rectangle-narrow", 4),
        (BatchedSEIF, "figure8-sparse", 16),
        # the ESEIF: relocalizations (split ones at k = 2) and measurements a full bound discards
        (BatchedESEIF, "circle", 2),
        (BatchedESEIF, "rectangle-narrow", 4),
        (BatchedESEIF, "figure8-sparse", 8),
    ],
)
def test_batched_filters_equal_filter_objects_bit_for_bit(batch_class, scenario, max_active):
    seeds = [0, 1, 2]
    runs = [make_loop_run(FIDELITY_SCENARIOS[scenario], seed) for seed in seeds]
    motion, sensor = runs[0][0], runs[0][1]
    runs = [run for _, _, run in runs]
    capacity = max(len(run.landmarks) for run in runs)
    batch = batch_class(len(runs), capacity, motion, sensor, max_active=max_active)
    filters = [batch.FILTER(motion, sensor, run.initial_pose, max_active=max_active) for run in runs]
    for e, run in enumerate(runs):
        batch.reset(e, run.initial_pose)
        _assert_same(batch, e, filters[e], -1)
    steps = min(run.steps for run in runs)
    width = max(len(run.ids[t]) for run in runs for t in range(steps))
    for t in range(steps):
        controls = np.array([run.controls[t] for run in runs])
        batch.predict(controls, runs[0].dt)
        ranges = np.ones((len(runs), width))
        bearings = np.zeros((len(runs), width))
        ids = np.zeros((len(runs), width), dtype=np.int64)
        counts = np.zeros(len(runs), dtype=np.int64)
        for e, (run, filt) in enumerate(zip(runs, filters)):
            filt.predict(run.controls[t], run.dt)
            m = len(run.ids[t])
            ranges[e, :m], bearings[e, :m], ids[e, :m], counts[e] = run.ranges[t], run.bearings[t], run.ids[t], m
            filt.update(run.ranges[t], run.bearings[t], run.ids[t])
        batch.update(ranges, bearings, ids, counts)
        for e, filt in enumerate(filters):
            _assert_same(batch, e, filt, t)
            if isinstance(filt, ESEIF):
                counters = (filt.relocalizations, filt.split_relocalizations, filt.discarded_measurements)
                assert tuple(batch.eseif_counters[e]) == counters, (e, t)
    if batch_class is BatchedESEIF:
        assert batch.eseif_counters[:, 0].min() > 0  # every filter relocalized


def test_batched_seif_checks_its_inputs_before_any_filter_moves():
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["circle"], 0)
    batch = BatchedSEIF(2, 10, motion, sensor)
    with pytest.raises(RuntimeError, match="reset"):
        batch.predict(np.zeros((2, 2)), 0.25)
    batch.reset(0, run.initial_pose)
    batch.reset(1, run.initial_pose)
    before = batch.mean.copy()
    with pytest.raises(ValueError, match="controls"):
        batch.predict(np.array([[0.1, 0.0], [np.nan, 0.0]]), 0.25)
    with pytest.raises(ValueError, match="dt"):
        batch.predict(np.zeros((2, 2)), -1.0)
    with pytest.raises(ValueError, match="ids"):
        batch.update(np.ones((2, 2)), np.zeros((2, 2)), np.array([[0, 99], [0, 1]]), np.array([2, 2]))
    with pytest.raises(ValueError, match="distinct"):
        batch.update(np.ones((2, 2)), np.zeros((2, 2)), np.array([[3, 3], [0, 1]]), np.array([2, 2]))
    with pytest.raises(ValueError, match="ranges"):
        batch.update(
            np.array([[1.0, -1.0], [1.0, 1.0]]), np.zeros((2, 2)), np.array([[0, 1], [0, 1]]), np.array([2, 2])
        )
    with pytest.raises(ValueError, match="counts"):
        batch.update(np.ones((2, 2)), np.zeros((2, 2)), np.array([[0, 1], [0, 1]]), np.array([3, 0]))
    np.testing.assert_array_equal(batch.mean, before)
    with pytest.raises(ValueError, match="num_filters"):
        BatchedSEIF(0, 10, motion, sensor)
    with pytest.raises(TypeError, match="motion"):
        BatchedSEIF(1, 10, sensor, sensor)
    with pytest.raises(ValueError, match="index"):
        batch.reset(5, run.initial_pose)


def test_batched_seif_refuses_filters_it_cannot_reproduce():
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["circle"], 0)
    batch = BatchedSEIF(1, 10, motion, sensor)
    with pytest.raises(ValueError, match="innovation_gate"):
        batch.load(0, SEIF(motion, sensor, run.initial_pose, innovation_gate=13.8))
    with pytest.raises(ValueError, match="options"):
        batch.load(0, SEIF(motion, sensor, run.initial_pose, max_active=4))
    with pytest.raises(TypeError, match="SEIF"):
        batch.load(0, object())
    with pytest.raises(TypeError, match="SEIF"):
        batch.load(0, ESEIF(motion, sensor, run.initial_pose))  # an ESEIF goes to a BatchedESEIF
    eseifs = BatchedESEIF(1, 10, motion, sensor, max_active=4)
    with pytest.raises(ValueError, match="options"):
        eseifs.load(0, ESEIF(motion, sensor, run.initial_pose, max_active=4, split_weight=0.3))
    with pytest.raises(ValueError, match="split_weight"):
        BatchedESEIF(1, 10, motion, sensor, split_weight=1.5)


@pytest.mark.parametrize("batch_class", [BatchedSEIF, BatchedESEIF, BatchedConservativeSEIF])
def test_to_filter_gives_the_filter_the_batch_holds_and_steps_it_alike(batch_class):
    """to_filter is load's inverse: a filter object equal to the batch's row, which steps on as the row does."""
    from seif_gym.slam.rollout import expected_rollouts

    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["circle"], 2)
    batch = batch_class(2, len(run.landmarks), motion, sensor, max_active=4)
    filt = batch.FILTER(motion, sensor, run.initial_pose, max_active=4)
    for e in (0, 1):
        batch.reset(e, run.initial_pose)

    def step(t):
        ranges, bearings, ids = run.ranges[t], run.bearings[t], run.ids[t]
        batch.predict(np.repeat(run.controls[t][None], 2, axis=0), run.dt)
        batch.update(np.stack([ranges, ranges]), np.stack([bearings, bearings]), np.stack([ids, ids]),
                     np.array([len(ids), len(ids)]))  # fmt: skip
        filt.predict(run.controls[t], run.dt)
        filt.update(ranges, bearings, ids)

    for t in range(60):
        step(t)
    copy = batch.to_filter(1)
    assert type(copy) is batch.FILTER and copy.num_landmarks == filt.num_landmarks > 0
    _assert_same(batch, 1, copy, 60)
    controls = np.array([[1.0, 0.3], [0.5, -0.4]])
    mine, theirs = expected_rollouts(copy, controls, run.dt, 6), expected_rollouts(filt, controls, run.dt, 6)
    for name in ("poses", "pose_covariances", "landmark_std"):
        np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name))
    kept = batch.mean.copy()
    for t in range(60, 90):  # the copy steps on as the filter it equals, and the batch does not move
        copy.predict(run.controls[t], run.dt)
        copy.update(run.ranges[t], run.bearings[t], run.ids[t])
    for t in range(60, 90):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    np.testing.assert_array_equal(copy.mean, filt.mean)
    np.testing.assert_array_equal(copy.active_landmarks, filt.active_landmarks)
    np.testing.assert_array_equal(batch.mean, kept)
    with pytest.raises(ValueError, match="index"):
        batch.to_filter(2)


def test_a_vector_envs_sub_filter_is_its_sub_envs_filter():
    import gymnasium as gym

    import seif_gym  # noqa: F401  (registers the environments)

    single = gym.make("SeifExplore-v2")
    vector = gym.make_vec("SeifExplore-v2", num_envs=2)
    single.reset(seed=8)
    vector.reset(seed=[7, 8])
    rng = np.random.default_rng(0)
    for _ in range(30):
        actions = rng.uniform(-1.0, 1.0, (2, 2))
        single.step(actions[1])
        vector.step(actions)
    copy = vector.unwrapped.sub_filter(1)
    np.testing.assert_array_equal(copy.mean, single.unwrapped.filter.mean)
    np.testing.assert_array_equal(copy.landmark_ids, single.unwrapped.filter.landmark_ids)
    np.testing.assert_array_equal(copy.landmark_std(), single.unwrapped.filter.landmark_std())
    with pytest.raises(ValueError, match="sub-env"):
        vector.unwrapped.sub_filter(2)
    vector.close()
    single.close()


# -- the ConservativeSEIF ------------------------------------------------------------------------------------
def _assert_same_cseif(batch: BatchedConservativeSEIF, e: int, filt: ConservativeSEIF, step: int) -> None:
    """Every array of row ``e`` equals ``filt``'s, the split's block ``A`` and the counters included."""
    _assert_same(batch, e, filt, step)
    dim = filt._map_info.shape[0]
    assert dim == (2 * len(filt._active) if filt.max_active is not None else 0), (e, step)
    np.testing.assert_array_equal(batch.map_info[e, :dim, :dim], filt._map_info, err_msg=f"A, filter {e}, step {step}")
    counters = (filt.cuts, filt.deferred_cuts, filt.discarded_measurements)
    assert tuple(batch.cseif_counters[e]) == counters, (e, step)
    head, size = batch.queue_state[e]
    ring = batch.queue[e, (head + np.arange(size)) % batch.capacity]
    np.testing.assert_array_equal(ring, filt._queue.ordered(), err_msg=f"queue, filter {e}, step {step}")


def _step_both(batch, filters, runs, t):
    width = max(len(run.ids[t]) for run in runs)
    batch.predict(np.array([run.controls[t] for run in runs]), runs[0].dt)
    ranges, bearings = np.ones((len(runs), width)), np.zeros((len(runs), width))
    ids, counts = np.zeros((len(runs), width), dtype=np.int64), np.zeros(len(runs), dtype=np.int64)
    for e, (run, filt) in enumerate(zip(runs, filters)):
        filt.predict(run.controls[t], run.dt)
        m = len(run.ids[t])
        ranges[e, :m], bearings[e, :m], ids[e, :m], counts[e] = run.ranges[t], run.bearings[t], run.ids[t], m
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    batch.update(ranges, bearings, ids, counts)


@pytest.mark.parametrize(
    "scenario, max_active, steps",
    [
        ("circle", 8, 120),  # cuts and measurements the hard bound discards
        pytest.param("circle", 8, None, marks=pytest.mark.slow),
        pytest.param("rectangle-narrow", 4, None, marks=pytest.mark.slow),  # deferred cuts
        pytest.param("figure8-sparse", 3, None, marks=pytest.mark.slow),
        ("rectangle-narrow", None, 60),  # no bound: no cuts, no split
    ],
)
def test_batched_cseif_equals_cseif_objects_bit_for_bit(scenario, max_active, steps):
    runs = [make_loop_run(FIDELITY_SCENARIOS[scenario], seed) for seed in (0, 1, 2)]
    motion, sensor = runs[0][0], runs[0][1]
    runs = [run for _, _, run in runs]
    batch = BatchedConservativeSEIF(len(runs), max(len(run.landmarks) for run in runs), motion, sensor,
                                    max_active=max_active)  # fmt: skip
    filters = [ConservativeSEIF(motion, sensor, run.initial_pose, max_active=max_active) for run in runs]
    for e, run in enumerate(runs):
        batch.reset(e, run.initial_pose)
        _assert_same_cseif(batch, e, filters[e], -1)
    steps = min(run.steps for run in runs) if steps is None else steps
    for t in range(steps):
        _step_both(batch, filters, runs, t)
        for e, filt in enumerate(filters):
            _assert_same_cseif(batch, e, filt, t)
    if max_active is not None:
        assert batch.cseif_counters[:, 0].min() > 0  # every filter cut links
    if scenario == "circle":
        assert batch.cseif_counters[:, 2].min() > 0  # the hard bound left measurements out
    if scenario == "rectangle-narrow" and max_active is not None:
        assert batch.cseif_counters[:, 1].min() > 0  # cuts were deferred


def test_batched_cseif_loads_a_filter_mid_run_and_steps_it_alike():
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["rectangle-narrow"], 1)
    filt = ConservativeSEIF(motion, sensor, run.initial_pose, max_active=4)
    for t in range(80):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    assert filt.cuts > 0 and len(filt._active) > 0
    batch = BatchedConservativeSEIF(1, len(run.landmarks), motion, sensor, max_active=4)
    batch.load(0, filt)
    _assert_same_cseif(batch, 0, filt, 80)
    _assert_same_cseif(batch, 0, batch.to_filter(0), 80)
    for t in range(80, 140):
        _step_both(batch, [filt], [run], t)
        _assert_same_cseif(batch, 0, filt, t)


def test_batched_cseif_refuses_filters_it_cannot_reproduce():
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["circle"], 0)
    batch = BatchedConservativeSEIF(1, 10, motion, sensor, max_active=4)
    assert batch.recovery_budget == ConservativeSEIF.OPTIONS["recovery_budget"]
    with pytest.raises(TypeError, match="ConservativeSEIF"):
        batch.load(0, SEIF(motion, sensor, run.initial_pose, max_active=4))
    with pytest.raises(ValueError, match="options"):
        batch.load(0, ConservativeSEIF(motion, sensor, run.initial_pose, max_active=4, cut_budget=0.5))
    with pytest.raises(ValueError, match="options"):
        batch.load(0, ConservativeSEIF(motion, sensor, run.initial_pose, max_active=4, max_active_hard=5))
    with pytest.raises(ValueError, match="cut_budget"):
        BatchedConservativeSEIF(1, 10, motion, sensor, cut_budget=1.5)
    with pytest.raises(NotImplementedError, match="update_trusted"):
        batch.update_arguments()
