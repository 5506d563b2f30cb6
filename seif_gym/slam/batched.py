"""Many SEIFs advanced in one compiled call: the filter core of a native vector env.

:class:`BatchedSEIF` holds ``N`` independent SEIFs (known correspondences,
wavefront mean recovery: the configuration of the ``SeifExplore-v1`` envs) in
arrays with a leading filter axis, and advances all of them with one call of a
compiled kernel per step (:func:`~seif_gym.slam._kernels.seif_predict_many`,
:func:`~seif_gym.slam._kernels.seif_update_many`): no Python object per filter
in the step loop. Each filter computes exactly what a
:class:`~seif_gym.slam.seif.SEIF` with the same options computes, the same
kernels in the same order (``tests/slam/test_batched.py`` compares every array
after every step, bit for bit). :class:`BatchedESEIF` and
:class:`BatchedConservativeSEIF` do the same for the
:class:`~seif_gym.slam.eseif.ESEIF` and the
:class:`~seif_gym.slam.cseif.ConservativeSEIF`.

The arrays are sized once: ``capacity`` landmarks per filter (the number of
landmarks of the world, for an env) and as many neighbours each, so nothing
grows in the step loop; memory is ``O(N capacity^2)`` for the links (a
landmark can be linked to every other one), about 29 KB per filter for 30
landmarks, 460 KB for 120.

Notes
-----
The steps are those of :mod:`seif_gym.slam.seif`: motion update
(:func:`~seif_gym.slam.seif.motion_update`), measurement update
(:func:`~seif_gym.slam.seif.measurement_update`), mean recovery (the wavefront
of :func:`~seif_gym.slam.seif.recover_mean_wavefront`) and sparsification
(:func:`~seif_gym.slam.seif.sparsify`), in the order of
:class:`~seif_gym.slam.seif.SEIF`.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import scipy.linalg
from numba import njit
from numpy.typing import ArrayLike

from seif_gym.slam import _kernels
from seif_gym.slam.base import DEFAULT_INITIAL_POSE_COV
from seif_gym.slam.cseif import ConservativeSEIF
from seif_gym.slam.eseif import ESEIF, RELOCALIZATION_RCOND
from seif_gym.slam.information import InformationStore
from seif_gym.slam.models import RangeBearingSensor, VelocityMotionModel, wrap_angle
from seif_gym.slam.seif import SEIF, JournalBuffer, RecoveryQueue
from seif_gym.type_aliases import BoolArray, FloatArray, IntArray
from seif_gym.validation import as_count, as_finite_array, as_positive_scalar

__all__ = ["BatchedSEIF", "BatchedESEIF", "BatchedConservativeSEIF"]


@njit(cache=True)
def _new_landmarks(ids: IntArray, counts: IntArray, id_to_index: IntArray) -> tuple[int, IntArray]:
    """The first filter whose update repeats an id (-1: none), and each filter's count of unmapped ids."""
    new = np.zeros(counts.shape[0], dtype=np.int64)
    for e in range(counts.shape[0]):
        for k in range(counts[e]):
            for j in range(k):
                if ids[e, j] == ids[e, k]:
                    return e, new
            if id_to_index[e, ids[e, k]] < 0:
                new[e] += 1
    return -1, new


#: positions in ``BatchedSEIF.counters``
_LANDMARKS, _ACTIVE, _UPDATES, _ROUND_ROBIN = range(4)


class BatchedSEIF:
    """``num_filters`` SEIFs with one motion model, one sensor and one set of options.

    Parameters
    ----------
    num_filters : int
        Filters in the batch.
    capacity : int
        Landmarks each filter can hold (at least 1).
    motion : VelocityMotionModel
        Motion model of every filter.
    sensor : RangeBearingSensor
        Sensor model of every filter.
    max_landmark_id : int, optional
        Largest landmark id an update may carry (default ``capacity - 1``).
    max_active, recovery_landmarks, recovery_budget, recovery_relaxation, recovery_tolerance
        The :class:`~seif_gym.slam.seif.SEIF` options of the same names
        (``mean_recovery="wavefront"``, compiled kernels).

    Notes
    -----
    :meth:`reset` starts filter ``e`` at a pose (as ``SEIF(motion, sensor,
    pose)`` does); :meth:`predict` and :meth:`update` advance every filter.
    Inputs are checked once per call for the whole batch, before any filter
    moves.
    """

    #: The filter class whose update the batch computes (and whose filters :meth:`load` copies).
    FILTER: type[SEIF] = SEIF
    #: Options of ``FILTER`` beyond the SEIF's that a loaded filter must share with the batch.
    _FILTER_OPTIONS: tuple[str, ...] = ()

    def __init__(self, num_filters: int, capacity: int, motion: VelocityMotionModel, sensor: RangeBearingSensor, *,
                 max_landmark_id: int | None = None, max_active: int | None = 8, recovery_landmarks: int = 8,
                 recovery_budget: int = 64, recovery_relaxation: float = 1.8, recovery_tolerance: float = 1e-4,
                 **filter_options: Any) -> None:  # fmt: skip
        as_count(num_filters, "num_filters", minimum=1)
        as_count(capacity, "capacity", minimum=1)
        if not isinstance(motion, VelocityMotionModel):
            raise TypeError(f"motion must be a VelocityMotionModel, got {type(motion).__name__}")
        if not isinstance(sensor, RangeBearingSensor):
            raise TypeError(f"sensor must be a RangeBearingSensor, got {type(sensor).__name__}")
        max_id = capacity - 1 if max_landmark_id is None else as_count(max_landmark_id, "max_landmark_id")
        # the filter checks its options; the batch takes them from a filter built with them
        reference = self.FILTER(motion, sensor, np.zeros(3), max_active=max_active,
                                recovery_landmarks=recovery_landmarks, recovery_budget=recovery_budget,
                                recovery_relaxation=recovery_relaxation, recovery_tolerance=recovery_tolerance,
                                **filter_options)  # fmt: skip
        self._reference = reference
        self.num_filters, self.capacity = int(num_filters), int(capacity)
        self.max_landmark_id = int(max_id)
        self.motion, self.sensor = motion, sensor
        self.max_active = -1 if reference.max_active is None else reference.max_active
        self.recovery_landmarks = reference.recovery_landmarks
        self.recovery_budget = reference.recovery_budget
        self.recovery_relaxation = reference.recovery_relaxation
        self.recovery_tolerance = reference.recovery_tolerance
        self._alphas = np.array(motion.alphas, dtype=np.float64)
        self._floor = float(motion.noise_floor)
        self._noise_info = np.array(reference._measurement_info)
        n, c = self.num_filters, self.capacity
        self.robot_info = np.zeros((n, 3, 3))
        self.robot_links = np.zeros((n, c, 3, 2))
        self.landmark_info = np.zeros((n, c, 2, 2))
        self.neighbour_index = np.full((n, c, c), -1, dtype=np.int64)
        self.neighbour_info = np.zeros((n, c, c, 2, 2))
        self.neighbour_count = np.zeros((n, c), dtype=np.int64)
        self.information_vector = np.zeros((n, 3 + 2 * c))
        self.mean = np.zeros((n, 3 + 2 * c))
        self.block_position = np.full((n, c), -1, dtype=np.int64)
        self.active = np.zeros((n, c), dtype=np.int64)
        self.is_active = np.zeros((n, c), dtype=bool)
        self.last_observed = np.zeros((n, c), dtype=np.int64)
        #: per filter: landmarks, active landmarks, updates so far, round-robin position
        self.counters = np.zeros((n, 4), dtype=np.int64)
        self.id_to_index = np.full((n, self.max_landmark_id + 1), -1, dtype=np.int64)
        self.ids = np.zeros((n, c), dtype=np.int64)
        self.queue = np.full((n, c), -1, dtype=np.int64)
        self.queued = np.zeros((n, c), dtype=bool)
        self.queue_state = np.zeros((n, 2), dtype=np.int64)
        self._started = np.zeros(n, dtype=bool)
        self._unused_counters = np.zeros((n, 3), dtype=np.int64)  # the ESEIF's counters' place in update_arguments

    # -- episodes ---------------------------------------------------------------------------------
    def reset(self, index: int, pose: ArrayLike, pose_cov: ArrayLike | None = None) -> None:
        """Start filter ``index`` afresh at ``pose`` (covariance ``pose_cov``; the SEIF's default if omitted)."""
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < self.num_filters:
            raise ValueError(f"index must be an int in [0, {self.num_filters}), got {index!r}")
        start = as_finite_array(pose, "pose", (3,)).copy()
        start[2] = wrap_angle(float(start[2]))
        cov = DEFAULT_INITIAL_POSE_COV if pose_cov is None else as_finite_array(pose_cov, "pose_cov", (3, 3))
        info = scipy.linalg.cho_solve(scipy.linalg.cho_factor(np.array(cov, dtype=np.float64)), np.eye(3))
        e = int(index)
        for array, fill in ((self.robot_links, 0), (self.landmark_info, 0), (self.neighbour_index, -1),
                            (self.neighbour_info, 0), (self.neighbour_count, 0), (self.information_vector, 0),
                            (self.mean, 0), (self.block_position, -1), (self.active, 0), (self.is_active, False),
                            (self.last_observed, 0), (self.counters, 0), (self.id_to_index, -1), (self.ids, 0),
                            (self.queue, -1), (self.queued, False), (self.queue_state, 0)):  # fmt: skip
            array[e] = fill
        self.robot_info[e] = 0.5 * (info + info.T)
        self.mean[e, :3] = start
        self.information_vector[e, :3] = self.robot_info[e] @ start
        self._started[e] = True

    def load(self, index: int, filt: SEIF) -> None:
        """Make filter ``index`` a copy of ``filt`` (a SEIF with this batch's options and known ids).

        The recovery queue keeps its order (its ring may be laid out differently: a FIFO's order
        is all the recovery reads).
        """
        if type(filt) is not self.FILTER:
            raise TypeError(f"filt must be a {self.FILTER.__name__}, got {type(filt).__name__}")
        options = filt.options
        if (options["mean_recovery"] != "wavefront" or options["implementation"] != "compiled"
                or (-1 if filt.max_active is None else filt.max_active) != self.max_active
                or filt.recovery_landmarks != self.recovery_landmarks or filt.recovery_budget != self.recovery_budget
                or filt.recovery_relaxation != self.recovery_relaxation
                or filt.recovery_tolerance != self.recovery_tolerance
                or any(options[name] != self._reference.options[name] for name in self._FILTER_OPTIONS)):  # fmt: skip
            raise ValueError(f"filt's options {options} differ from the batch's")
        # the batch has no innovation gate and one measurement covariance for all ranges
        if options.get("innovation_gate") is not None:
            raise ValueError("filt has an innovation_gate; the batch's update does not gate")
        if getattr(filt.sensor, "range_dependent", False):
            raise ValueError("filt's sensor has range-dependent noise; the batch uses one measurement covariance")
        store = filt._store
        n = store.num_landmarks
        if n > self.capacity:
            raise ValueError(f"filt has {n} landmarks, more than capacity={self.capacity}")
        ids = filt.landmark_ids
        if n and (ids.min() < 0 or ids.max() > self.max_landmark_id):
            raise ValueError(f"filt's landmark ids must lie in [0, {self.max_landmark_id}]")
        self.reset(index, np.zeros(3))
        e = int(index)
        degree = store.neighbour_index.shape[1]
        if degree > self.capacity:
            if n and store.neighbour_count[:n].max() > self.capacity:
                raise ValueError("filt has more neighbours per landmark than the batch can hold")
            degree = self.capacity
        self.robot_info[e] = store.robot_info
        self.robot_links[e, :n] = store.robot_links[:n]
        self.landmark_info[e, :n] = store.landmark_info[:n]
        self.neighbour_index[e, :n, :degree] = store.neighbour_index[:n, :degree]
        self.neighbour_info[e, :n, :degree] = store.neighbour_info[:n, :degree]
        self.neighbour_count[e, :n] = store.neighbour_count[:n]
        self.information_vector[e, : 3 + 2 * n] = store.information_vector[: 3 + 2 * n]
        self.mean[e, : 3 + 2 * n] = store.mean[: 3 + 2 * n]
        active = filt._active
        self.active[e, : len(active)] = active
        self.is_active[e, :n] = filt._is_active[:n]
        self.last_observed[e, :n] = filt._last_observed[:n]
        self.counters[e] = (n, len(active), filt._update_count, filt._round_robin)
        self.ids[e, :n] = ids
        self.id_to_index[e, ids] = np.arange(n)
        ordered = filt._queue.ordered()
        self.queue[e, : len(ordered)] = ordered
        self.queued[e, :n] = filt._queue.queued[:n]
        self.queue_state[e] = (0, len(ordered))

    def _new_filter(self) -> SEIF:
        """A filter with the batch's models and options whose state :meth:`to_filter` fills.

        A shallow copy of the reference filter with its own arrays, dicts and lists (the models and
        the backend, which a step only reads, are shared): a deep copy would walk the models on
        every call, and a planner asks for a filter at every plan.
        """
        reference = self._reference
        filt = type(reference).__new__(type(reference))
        for name, value in reference.__dict__.items():
            if isinstance(value, np.ndarray):
                value = value.copy()
            elif isinstance(value, (dict, list)):
                value = copy.copy(value)
            filt.__dict__[name] = value
        filt._journal, filt._journal_buffer = None, JournalBuffer()
        return filt

    def to_filter(self, index: int) -> SEIF:
        """A new ``FILTER`` (a :class:`~seif_gym.slam.seif.SEIF`) holding filter ``index``'s state: :meth:`load`'s inverse.

        The filter owns copies of the arrays (the batch is not changed, and stepping the filter does
        not step the batch); it computes what filter ``index`` would, bit for bit: its information,
        mean, active set, round-robin position, update count, landmark ids and the recovery queue's
        order are the batch's.

        Parameters
        ----------
        index : int
            The filter, in ``[0, num_filters)``; reset or loaded.

        Returns
        -------
        SEIF
            A :class:`~seif_gym.slam.seif.SEIF` (an :class:`~seif_gym.slam.eseif.ESEIF` for a
            :class:`BatchedESEIF`, a :class:`~seif_gym.slam.cseif.ConservativeSEIF` for a
            :class:`BatchedConservativeSEIF`) with the batch's models and options.

        Raises
        ------
        ValueError
            If ``index`` is not a filter of the batch.
        RuntimeError
            If filter ``index`` has not been reset or loaded.
        """
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < self.num_filters:
            raise ValueError(f"index must be an int in [0, {self.num_filters}), got {index!r}")
        e = int(index)
        if not self._started[e]:
            raise RuntimeError(f"filter {e} has not been reset or loaded")
        n, count = int(self.counters[e, _LANDMARKS]), int(self.counters[e, _ACTIVE])
        filt = self._new_filter()
        used = int(self.neighbour_count[e, :n].max()) if n else 0
        store = InformationStore(max(n, 64), max(used, 16))
        store.num_landmarks = n
        store.robot_info[:] = self.robot_info[e]
        store.robot_links[:n] = self.robot_links[e, :n]
        store.landmark_info[:n] = self.landmark_info[e, :n]
        store.neighbour_index[:n, :used] = self.neighbour_index[e, :n, :used]
        store.neighbour_info[:n, :used] = self.neighbour_info[e, :n, :used]
        store.neighbour_count[:n] = self.neighbour_count[e, :n]
        store.information_vector[: 3 + 2 * n] = self.information_vector[e, : 3 + 2 * n]
        store.mean[: 3 + 2 * n] = self.mean[e, : 3 + 2 * n]
        filt._store = store
        capacity = store.capacity
        filt._active = self.active[e, :count].copy()
        filt._is_active = np.zeros(capacity, dtype=bool)
        filt._is_active[:n] = self.is_active[e, :n]
        filt._last_observed = np.zeros(capacity, dtype=np.int64)
        filt._last_observed[:n] = self.last_observed[e, :n]
        filt._update_count = int(self.counters[e, _UPDATES])
        filt._round_robin = int(self.counters[e, _ROUND_ROBIN])
        head, size = int(self.queue_state[e, 0]), int(self.queue_state[e, 1])
        queue = RecoveryQueue(capacity)
        queue.items[:size] = self.queue[e, (head + np.arange(size)) % self.capacity]
        queue.queued[:n] = self.queued[e, :n]
        queue.state[:] = (0, size)
        filt._queue = queue
        if n:
            filt._append_ids(self.ids[e, :n].copy())
        return filt

    def _check_started(self) -> None:
        if not self._started.all():
            missing = np.flatnonzero(~self._started).tolist()
            raise RuntimeError(f"reset() filters {missing} before stepping the batch")

    # -- steps ----------------------------------------------------------------------------------
    def predict(self, controls: ArrayLike, dt: float) -> None:
        """Motion update of every filter: ``controls[e] = (v, omega)`` for ``dt`` seconds."""
        self._check_started()
        controls = as_finite_array(controls, "controls", (self.num_filters, 2))
        dt = as_positive_scalar(dt, "dt")
        self.predict_trusted(np.ascontiguousarray(controls), dt)

    def predict_trusted(self, controls: FloatArray, dt: float) -> None:
        """:meth:`predict` without its checks, for controls it would accept (the native vector env's own).

        ``controls`` C-contiguous float64 of shape (N, 2), finite; ``dt`` a positive float.
        """
        _kernels.seif_predict_many(*self.kernel_arrays(), self.active, np.ascontiguousarray(self.counters[:, _ACTIVE]),
                                   controls, dt, self._alphas, self._floor)  # fmt: skip

    def update(self, ranges: ArrayLike, bearings: ArrayLike, ids: ArrayLike, counts: ArrayLike) -> None:
        """Measurement update of every filter with its first ``counts[e]`` measurements (known ids).

        Parameters
        ----------
        ranges, bearings : array_like, shape (N, M)
            Measurements, padded beyond ``counts[e]`` (the padding is not read).
        ids : array_like of int, shape (N, M)
            Landmark ids in ``[0, max_landmark_id]``, distinct within a filter's measurements.
        counts : array_like of int, shape (N,)
            Measurements of each filter in this update.
        """
        self._check_started()
        n = self.num_filters
        ranges = as_finite_array(ranges, "ranges", (n, None))
        width = ranges.shape[1]
        bearings = as_finite_array(bearings, "bearings", (n, width))
        ids = np.asarray(ids)
        if ids.shape != (n, width) or not np.issubdtype(ids.dtype, np.integer):
            raise ValueError(f"ids must be an int array of shape {(n, width)}, got {ids.dtype} {ids.shape}")
        counts = np.asarray(counts)
        if (
            counts.shape != (n,)
            or not np.issubdtype(counts.dtype, np.integer)
            or counts.min() < 0
            or counts.max() > width
        ):
            raise ValueError(f"counts must be {n} ints in [0, {width}], got {counts!r}")
        used = np.arange(width) < counts[:, None]
        if np.any(ranges[used] <= 0.0):
            raise ValueError("ranges must be positive")
        if np.any((ids[used] < 0) | (ids[used] > self.max_landmark_id)):
            raise ValueError(f"ids must lie in [0, {self.max_landmark_id}]")
        ids = np.ascontiguousarray(ids, dtype=np.int64)
        counts = counts.astype(np.int64)
        repeated, new = _new_landmarks(ids, counts, self.id_to_index)
        if repeated >= 0:
            raise ValueError(f"ids must be distinct within one update (filter {repeated})")
        if np.any(self.counters[:, _LANDMARKS] + new > self.capacity):
            raise ValueError(f"an update would exceed capacity={self.capacity} landmarks")
        self.update_trusted(np.ascontiguousarray(ranges), np.ascontiguousarray(bearings), ids, counts)

    def update_trusted(self, ranges: FloatArray, bearings: FloatArray, ids: IntArray, counts: IntArray) -> None:
        """:meth:`update` without its checks, for measurements it would accept (the native vector env's own).

        ``ranges`` and ``bearings`` C-contiguous float64, ``ids`` and ``counts`` C-contiguous int64.
        """
        _kernels.seif_update_many(*self.kernel_arrays(), *self.bookkeeping_arrays(), ranges, bearings, ids, counts,
                                  self._noise_info, self.max_active, self.recovery_landmarks, self.recovery_budget,
                                  self.recovery_relaxation, self.recovery_tolerance)  # fmt: skip

    def update_arguments(self) -> tuple[Any, ...]:
        """The update's arguments after the measurements, in the order of :func:`~seif_gym.slam._kernels.eseif_update_env`.

        ``noise_info, noise_cov, max_active, relocalization_landmarks, split_weight, rcond, recovery_landmarks,
        recovery_budget, recovery_relaxation, recovery_tolerance, eseif_counters``; a SEIF batch gives
        ``relocalization_landmarks = 0`` (Thrun's sparsification) and placeholders for the ESEIF's own.
        """
        return (self._noise_info, np.zeros((2, 2)), self.max_active, 0, 0.5, 0.0, self.recovery_landmarks,
                self.recovery_budget, self.recovery_relaxation, self.recovery_tolerance, self._unused_counters)  # fmt: skip

    # -- read-only views -------------------------------------------------------------------------
    def kernel_arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, IntArray, FloatArray, IntArray, FloatArray,
                                     FloatArray, IntArray]:  # fmt: skip
        """The batch's information arrays in the order the kernels take them (``InformationStore.kernel_arrays``)."""
        return (self.robot_info, self.robot_links, self.landmark_info, self.neighbour_index, self.neighbour_info,
                self.neighbour_count, self.information_vector, self.mean, self.block_position)  # fmt: skip

    def bookkeeping_arrays(self) -> tuple[IntArray, IntArray, BoolArray, IntArray, IntArray, IntArray, IntArray,
                                          BoolArray, IntArray]:  # fmt: skip
        """The rest of the batch's state, in the kernels' order after :meth:`kernel_arrays`.

        ``active, counters, is_active, last_observed, id_to_index, ids, queue, queued, queue_state``.
        """
        return (self.active, self.counters, self.is_active, self.last_observed, self.id_to_index, self.ids,
                self.queue, self.queued, self.queue_state)  # fmt: skip

    @property
    def poses(self) -> FloatArray:
        """Pose estimates, shape (N, 3) (a copy)."""
        return self.mean[:, :3].copy()

    @property
    def num_landmarks(self) -> IntArray:
        """Landmarks in each filter's map, shape (N,) (a copy)."""
        return self.counters[:, _LANDMARKS].copy()

    def store(self, index: int) -> InformationStore:
        """Filter ``index``'s information as an :class:`InformationStore` over views of the batch's arrays (no copy)."""
        e = int(index)
        view = InformationStore.__new__(InformationStore)
        view.num_landmarks = int(self.counters[e, _LANDMARKS])
        for name in ("robot_info", "robot_links", "landmark_info", "neighbour_index", "neighbour_info",
                     "neighbour_count", "information_vector", "mean", "block_position"):  # fmt: skip
            setattr(view, name, getattr(self, name)[e])
        return view

    def landmarks(self, index: int) -> FloatArray:
        """Landmark means of filter ``index`` in state order, shape (n, 2) (a copy)."""
        count = int(self.counters[index, _LANDMARKS])
        return self.mean[index, 3 : 3 + 2 * count].reshape(count, 2).copy()

    def landmark_ids(self, index: int) -> IntArray:
        """Ids of filter ``index``'s landmarks in state order (a copy)."""
        return self.ids[index, : self.counters[index, _LANDMARKS]].copy()

    def active_landmarks(self, index: int) -> IntArray:
        """Ids of the landmarks linked to filter ``index``'s robot, in the SEIF's order."""
        return self.ids[index, self.active[index, : self.counters[index, _ACTIVE]]]


class BatchedESEIF(BatchedSEIF):
    """``num_filters`` ESEIFs (:class:`~seif_gym.slam.eseif.ESEIF`) with one motion model, one sensor, one set of options.

    As :class:`BatchedSEIF`, with the ESEIF's update (:func:`~seif_gym.slam._kernels.eseif_update_many`:
    relocalization instead of Thrun's sparsification) and its options ``relocalization_landmarks``
    and ``split_weight``. ``eseif_counters[e]`` holds filter ``e``'s ``relocalizations``,
    ``split_relocalizations`` and ``discarded_measurements``.
    """

    FILTER = ESEIF
    _FILTER_OPTIONS = ("relocalization_landmarks", "split_weight")

    def __init__(self, num_filters: int, capacity: int, motion: VelocityMotionModel, sensor: RangeBearingSensor, *,
                 relocalization_landmarks: int = 2, split_weight: float = 0.5, **options: Any) -> None:  # fmt: skip
        super().__init__(num_filters, capacity, motion, sensor, relocalization_landmarks=relocalization_landmarks,
                         split_weight=split_weight, **options)  # fmt: skip
        reference = self._reference
        assert isinstance(reference, ESEIF)
        self.relocalization_landmarks = reference.relocalization_landmarks
        self.split_weight = reference.split_weight
        self._noise_cov = np.array(reference._measurement_cov)
        #: per filter: relocalizations, split relocalizations, discarded measurements
        self.eseif_counters = np.zeros((self.num_filters, 3), dtype=np.int64)

    def reset(self, index: int, pose: ArrayLike, pose_cov: ArrayLike | None = None) -> None:
        super().reset(index, pose, pose_cov)
        self.eseif_counters[int(index)] = 0

    def load(self, index: int, filt: SEIF) -> None:
        super().load(index, filt)
        assert isinstance(filt, ESEIF)  # load checked the type
        self.eseif_counters[int(index)] = (filt.relocalizations, filt.split_relocalizations,
                                           filt.discarded_measurements)  # fmt: skip

    def to_filter(self, index: int) -> ESEIF:
        filt = super().to_filter(index)
        assert isinstance(filt, ESEIF)  # FILTER
        filt.relocalizations, filt.split_relocalizations, filt.discarded_measurements = (
            int(count) for count in self.eseif_counters[int(index)]
        )
        return filt

    def update_trusted(self, ranges: FloatArray, bearings: FloatArray, ids: IntArray, counts: IntArray) -> None:
        _kernels.eseif_update_many(*self.kernel_arrays(), *self.bookkeeping_arrays(), ranges, bearings, ids, counts,
                                   *self.update_arguments())  # fmt: skip

    def update_arguments(self) -> tuple[Any, ...]:
        return (self._noise_info, self._noise_cov, self.max_active, self.relocalization_landmarks, self.split_weight,
                RELOCALIZATION_RCOND, self.recovery_landmarks, self.recovery_budget, self.recovery_relaxation,
                self.recovery_tolerance, self.eseif_counters)  # fmt: skip


class BatchedConservativeSEIF(BatchedSEIF):
    """``num_filters`` :class:`~seif_gym.slam.cseif.ConservativeSEIF` filters with one motion model, one sensor, one set of options.

    As :class:`BatchedSEIF`, with the ConservativeSEIF's update
    (:func:`~seif_gym.slam._kernels.cseif_update_many`: the hard bound on the active set, the split's
    block ``A`` following the active set, certified cuts instead of Thrun's sparsification) and its
    options ``max_active_hard`` and ``cut_budget`` (``recovery_budget`` defaults to the filter's 512).

    ``map_info[e, :2a, :2a]`` is filter ``e``'s ``A`` (``Omega_A`` over its ``a`` active landmarks, in
    the order of its active set; the rest of the array is not read), shape (N, 2 capacity, 2 capacity);
    ``cseif_counters[e]`` holds its ``cuts``, ``deferred_cuts`` and ``discarded_measurements``.
    """

    FILTER = ConservativeSEIF
    _FILTER_OPTIONS = ("max_active_hard", "cut_budget")

    def __init__(self, num_filters: int, capacity: int, motion: VelocityMotionModel, sensor: RangeBearingSensor, *,
                 recovery_budget: int = 512, max_active_hard: int | None = None, cut_budget: float = 0.9,
                 **options: Any) -> None:  # fmt: skip
        super().__init__(num_filters, capacity, motion, sensor, recovery_budget=recovery_budget,
                         max_active_hard=max_active_hard, cut_budget=cut_budget, **options)  # fmt: skip
        reference = self._reference
        assert isinstance(reference, ConservativeSEIF)
        self.max_active_hard = -1 if reference.max_active_hard is None else reference.max_active_hard
        self.cut_budget = reference.cut_budget
        self.map_info = np.zeros((self.num_filters, 2 * self.capacity, 2 * self.capacity))
        #: per filter: cuts, deferred cuts, discarded measurements
        self.cseif_counters = np.zeros((self.num_filters, 3), dtype=np.int64)

    def reset(self, index: int, pose: ArrayLike, pose_cov: ArrayLike | None = None) -> None:
        super().reset(index, pose, pose_cov)
        self.map_info[int(index)] = 0.0
        self.cseif_counters[int(index)] = 0

    def load(self, index: int, filt: SEIF) -> None:
        super().load(index, filt)
        assert isinstance(filt, ConservativeSEIF)  # load checked the type
        e = int(index)
        dim = filt._map_info.shape[0]
        if filt.max_active is not None and dim != 2 * len(filt._active):
            raise ValueError(f"filt's split block has shape {filt._map_info.shape}, not that of its active set")
        self.map_info[e, :dim, :dim] = filt._map_info
        self.cseif_counters[e] = (filt.cuts, filt.deferred_cuts, filt.discarded_measurements)

    def to_filter(self, index: int) -> ConservativeSEIF:
        filt = super().to_filter(index)
        assert isinstance(filt, ConservativeSEIF)  # FILTER
        e = int(index)
        dim = 0 if filt.max_active is None else 2 * int(self.counters[e, _ACTIVE])
        filt._map_info = self.map_info[e, :dim, :dim].copy()
        filt.cuts, filt.deferred_cuts, filt.discarded_measurements = (int(count) for count in self.cseif_counters[e])
        return filt

    def update_trusted(self, ranges: FloatArray, bearings: FloatArray, ids: IntArray, counts: IntArray) -> None:
        _kernels.cseif_update_many(*self.kernel_arrays(), *self.bookkeeping_arrays(), ranges, bearings, ids, counts,
                                   self._noise_info, self.max_active, self.max_active_hard, self.cut_budget,
                                   self.recovery_landmarks, self.recovery_budget, self.recovery_relaxation,
                                   self.recovery_tolerance, self.map_info, self.cseif_counters)  # fmt: skip

    def update_arguments(self) -> tuple[Any, ...]:
        """Not available: the ConservativeSEIF's update is not one of :func:`~seif_gym.slam._kernels.eseif_update_env`'s.

        Raises
        ------
        NotImplementedError
            Always (step a ``BatchedConservativeSEIF`` with :meth:`update` or :meth:`update_trusted`).
        """
        raise NotImplementedError("the ConservativeSEIF's batched update runs through update_trusted only")
