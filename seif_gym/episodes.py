"""Record episodes of ``SeifExplore`` and replay them through any SLAM filter.

An :class:`Episode` holds everything a filter was given in one episode of
:class:`~seif_gym.envs.explore.SeifExploreEnv` (the configuration, the
executed controls and the noisy measurements) together with the ground truth
(landmarks, true poses) and what the env's own filter estimated. It is saved
to and loaded from a ``.npz`` file without pickle.

:class:`EpisodeRecorder` wraps an env and records its episodes;
:func:`replay` feeds an episode through any filter of :mod:`seif_gym.slam`
(or your own), so that filters are compared on identical data. Replaying
with the filter and options the env ran reproduces the env's estimates bit
for bit.

>>> import tempfile, pathlib
>>> import gymnasium as gym
>>> import numpy as np
>>> import seif_gym
>>> from seif_gym.episodes import Episode, EpisodeRecorder, replay
>>> env = EpisodeRecorder(gym.make("SeifExplore-v2", max_episode_steps=10))
>>> _ = env.reset(seed=3)
>>> _ = env.action_space.seed(3)
>>> done = False
>>> while not done:
...     _, _, terminated, truncated, _ = env.step(env.action_space.sample())
...     done = terminated or truncated
>>> episode = env.episode
>>> with tempfile.TemporaryDirectory() as folder:
...     path = episode.save(pathlib.Path(folder) / "run.npz")
...     loaded = Episode.load(path)
>>> loaded == episode
True
>>> own = replay(loaded)                      # the env's filter: its estimates, exactly
>>> bool(np.array_equal(own.poses, episode.estimated_poses))
True
>>> ekf = replay(loaded, "ekf")               # the same data through the EKF
>>> ekf.poses.shape, ekf.map_errors.shape
((11, 3), (11,))
"""

from __future__ import annotations

import json
import operator
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from types import MappingProxyType
from typing import Any, SupportsFloat, cast

import gymnasium as gym
import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from seif_gym._atomic import atomic_write
from seif_gym.datasets._files import load_npz
from seif_gym.envs.explore import SeifExploreEnv, make_models
from seif_gym.metrics import filter_map_error  # the env's E_t: identical bits
from seif_gym.slam import FILTERS, RangeBearingSensor, SlamFilter, VelocityMotionModel
from seif_gym.slam.association import AssociationAudit, make_associator
from seif_gym.slam.base import COMMON_OPTIONS
from seif_gym.slam.noise_models import PerSecondVelocityMotionModel
from seif_gym.type_aliases import FloatArray, IntArray
from seif_gym.validation import as_positive_scalar

__all__ = ["Episode", "EpisodeRecorder", "ReplayResult", "replay", "episode_models"]


#: Version of the ``.npz`` layout written by :meth:`Episode.save`.
FORMAT_VERSION = 1

# name -> (dtype, shape with None for a free axis; "T" = steps, "T+1", "T+2")
_ARRAYS: dict[str, tuple[type, tuple]] = {
    "landmarks": (np.float64, (None, 2)),
    "true_poses": (np.float64, ("T+1", 3)),
    "estimated_poses": (np.float64, ("T+1", 3)),
    "commanded_controls": (np.float64, ("T", 2)),
    "executed_controls": (np.float64, ("T", 2)),
    "ranges": (np.float64, (None,)),
    "bearings": (np.float64, (None,)),
    "ids": (np.int64, (None,)),
    "offsets": (np.int64, ("T+2",)),
    "rewards": (np.float64, ("T",)),
    "map_errors": (np.float64, ("T+1",)),
}


def _read_only(array: ArrayLike, dtype: DTypeLike) -> NDArray:
    result = np.array(array, dtype=dtype, copy=True)
    result.setflags(write=False)
    return result


def _json_config(config: Mapping[str, Any]) -> str:
    if not isinstance(config, Mapping):
        raise TypeError(f"config must be a mapping of env keyword arguments, got {type(config).__name__}")
    try:
        return json.dumps(dict(config), default=_plain)
    except TypeError as error:
        raise TypeError(f"config must hold JSON-serialisable values only: {error}") from None


def _plain(value: object) -> Any:
    """Numpy scalars and arrays as Python numbers and lists, for ``json.dumps``."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _tuples(value: Any) -> Any:
    """Lists back to tuples (JSON has no tuples; the env's config holds tuples)."""
    if isinstance(value, list):
        return tuple(_tuples(item) for item in value)
    if isinstance(value, dict):
        return {key: _tuples(item) for key, item in value.items()}
    return value


def _config_from_json(text: str) -> MappingProxyType:
    config = json.loads(text)
    if not isinstance(config, dict):
        raise ValueError("the stored config is not a JSON object")
    return MappingProxyType(_tuples(config))


def _arrays_equal(a: NDArray, b: NDArray) -> bool:
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    return bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))


@dataclass(frozen=True, eq=False, repr=False)
class Episode:
    """One recorded episode of ``SeifExplore``: the filter's inputs and the ground truth.

    ``T`` is the number of steps. Index ``0`` of the per-time arrays is the
    reset: the pose at the start and the first measurement, which the env's
    filter processes before the first step.

    Attributes
    ----------
    config : Mapping
        The env's keyword arguments (``SeifExploreEnv.config``), read only.
        Sequences are tuples, as in the env.
    seed : int or None
        The seed passed to the ``reset`` that started the episode (``None``:
        the episode continued the env's random stream).
    dt : float
        Seconds per step.
    landmarks : ndarray (n, 2)
        True landmark positions; a landmark's id is its row.
    true_poses, estimated_poses : ndarray (T + 1, 3)
        True poses and the env's filter estimate, after the reset and after
        each step.
    commanded_controls : ndarray (T, 2)
        ``(v, omega)`` commanded by the (clipped, scaled) actions.
    executed_controls : ndarray (T, 2)
        What the robot executed and the filter was told (``v = 0`` at a wall).
    ranges, bearings : ndarray (M,)
        All measurements of steps ``0 .. T`` concatenated.
    ids : ndarray (M,) of int64
        Their landmark ids.
    offsets : ndarray (T + 2,) of int64
        Step ``t``'s measurements are ``[offsets[t]:offsets[t + 1]]``.
    rewards : ndarray (T,)
        Rewards returned by the recorded env.
    map_errors : ndarray (T + 1,)
        The env's map error ``E_t`` (``info["map_error"]``).

    All arrays are read-only copies; two episodes compare equal when their
    config, seed, dt and every array (shape, dtype and values) are equal.
    """

    config: Mapping[str, Any]
    seed: int | None
    dt: float
    landmarks: FloatArray
    true_poses: FloatArray
    estimated_poses: FloatArray
    commanded_controls: FloatArray
    executed_controls: FloatArray
    ranges: FloatArray
    bearings: FloatArray
    ids: IntArray
    offsets: IntArray
    rewards: FloatArray
    map_errors: FloatArray

    def __reduce__(self) -> tuple[Any, ...]:
        # pickled (to a worker process or a Ray node and back) through the constructor: the read-only
        # config (a mappingproxy) does not pickle itself, and the copy is checked like a fresh one
        plain = {field.name: getattr(self, field.name) for field in fields(self)}
        plain["config"] = json.loads(_json_config(self.config))
        return (type(self), tuple(plain.values()))

    def __post_init__(self) -> None:
        set_field = object.__setattr__
        set_field(self, "config", _config_from_json(_json_config(self.config)))
        if self.seed is not None:
            if isinstance(self.seed, bool):
                raise TypeError("seed must be an int or None, got bool")
            set_field(self, "seed", operator.index(self.seed))
        dt = as_positive_scalar(self.dt, "dt")
        set_field(self, "dt", dt)
        for name, (dtype, _) in _ARRAYS.items():
            set_field(self, name, _read_only(getattr(self, name), dtype))
        steps = len(self.commanded_controls)
        sizes = {"T": steps, "T+1": steps + 1, "T+2": steps + 2}
        for name, (_, shape) in _ARRAYS.items():
            expected = tuple(sizes.get(axis, axis) for axis in shape)
            actual = getattr(self, name).shape
            if len(actual) != len(expected) or any(e is not None and a != e for a, e in zip(actual, expected)):
                pretty = tuple("n" if e is None else e for e in expected)
                raise ValueError(f"{name} must have shape {pretty} for an episode of {steps} steps, got {actual}")
        count = len(self.ranges)
        if len(self.bearings) != count or len(self.ids) != count:
            raise ValueError(
                f"ranges, bearings and ids must have the same length, got {count}, {len(self.bearings)}, {len(self.ids)}"
            )
        offsets = self.offsets
        if offsets[0] != 0 or offsets[-1] != count or np.any(np.diff(offsets) < 0):
            raise ValueError(f"offsets must rise from 0 to len(ranges) = {count}, got {offsets}")

    # -- access --------------------------------------------------------------
    @property
    def steps(self) -> int:
        """Number of steps ``T``."""
        return len(self.commanded_controls)

    def measurements(self, t: int) -> tuple[FloatArray, FloatArray, IntArray]:
        """``(ranges, bearings, ids)`` made at time ``t`` (0 = at the reset, ``t`` = after step ``t``).

        Read-only views into the episode.
        """
        if isinstance(t, bool):
            raise TypeError("t must be an int, got bool")
        t = operator.index(t)
        if not 0 <= t <= self.steps:
            raise IndexError(f"t must lie in [0, {self.steps}], got {t}")
        rows = slice(int(self.offsets[t]), int(self.offsets[t + 1]))
        return self.ranges[rows], self.bearings[rows], self.ids[rows]

    def models(self) -> tuple[VelocityMotionModel | PerSecondVelocityMotionModel, RangeBearingSensor]:
        """The motion model and the sensor, built from :attr:`config` as the env builds them."""
        return episode_models(self.config)

    # -- comparison ----------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Episode):
            return NotImplemented
        if dict(self.config) != dict(other.config) or self.seed != other.seed or self.dt != other.dt:
            return False
        return all(_arrays_equal(getattr(self, name), getattr(other, name)) for name in _ARRAYS)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return (
            f"Episode(steps={self.steps}, landmarks={len(self.landmarks)}, measurements={len(self.ranges)}, "
            f"filter={self.config.get('filter')!r}, seed={self.seed!r})"
        )

    # -- files ---------------------------------------------------------------
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the episode to ``path`` (``np.savez_compressed``; ``.npz`` is appended if missing).

        Returns the path written. The file holds plain arrays only (the
        config and the seed as JSON strings), so :meth:`load` needs no pickle.
        """
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        arrays = {
            "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
            "config": np.array(_json_config(self.config)),
            "seed": np.array(json.dumps(self.seed)),
            "dt": np.array(self.dt, dtype=np.float64),
            **{name: getattr(self, name) for name in _ARRAYS},
        }

        def write(temporary: Path) -> None:
            with open(temporary, "wb") as handle:  # a handle: numpy appends no suffix to it
                np.savez_compressed(handle, **arrays)

        return atomic_write(path, write)  # whole or not at all

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Episode:
        """Read an episode written by :meth:`save` (``allow_pickle=False``).

        Raises
        ------
        FileNotFoundError
            If ``path`` does not exist.
        ValueError
            One line naming the file: not a readable ``.npz`` archive (corrupt, truncated, another
            format; pickles are never loaded), an array missing or unreadable, or another format version.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such episode file")
        names = ["format_version", "config", "seed", "dt", *_ARRAYS]
        data = load_npz(path, [], optional=names)
        missing = [name for name in names if name not in data]
        if missing:
            raise ValueError(f"{path} is not a saved Episode: missing {', '.join(missing)}")
        version = int(data["format_version"])
        if version != FORMAT_VERSION:
            raise ValueError(f"{path} has episode format {version}; this version reads {FORMAT_VERSION}")
        seed = json.loads(str(data["seed"]))
        return cls(
            config=_config_from_json(str(data["config"])),
            seed=seed,
            dt=float(data["dt"]),
            **{name: data[name] for name in _ARRAYS},
        )


def episode_models(
    config: Mapping[str, Any],
) -> tuple[VelocityMotionModel | PerSecondVelocityMotionModel, RangeBearingSensor]:
    """``(motion, sensor)`` from env keyword arguments, exactly as ``SeifExploreEnv`` builds them.

    :func:`seif_gym.envs.explore.make_models`: Thrun's or the per-second
    motion model, a constant or range-dependent range noise.
    """
    return make_models(config)


# ---------------------------------------------------------------------------
# Recording
# ---------------------------------------------------------------------------
class EpisodeRecorder(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Record the episodes of a ``SeifExplore`` env as :class:`Episode` objects.

    Wraps an env whose ``unwrapped`` is a
    :class:`~seif_gym.envs.explore.SeifExploreEnv` (other wrappers, such as
    ``gym.make``'s ``TimeLimit``, may sit in between). Everything is taken
    from the infos of ``reset`` and ``step`` and from the unwrapped env's
    configuration; observations, actions and rewards pass through unchanged.

    Parameters
    ----------
    env : gymnasium.Env
        The env to record.
    directory : str or os.PathLike, optional
        If given, every finished episode (terminated or truncated) is saved
        there as ``episode_{k:05d}.npz``, ``k = 0, 1, ...`` counting the
        finished episodes of this wrapper. Existing files of the same name
        are overwritten. An episode cut short by a new ``reset`` is not
        saved.

    Attributes
    ----------
    episode : Episode
        The current episode (up to the last step) or, after it ended, the
        finished one.
    episode_count : int
        Finished episodes so far.
    paths : list of Path
        Files written so far.

    Example
    -------
    >>> import gymnasium as gym
    >>> import seif_gym
    >>> from seif_gym.episodes import EpisodeRecorder
    >>> env = EpisodeRecorder(gym.make("SeifExplore-v0", max_episode_steps=5))
    >>> _ = env.reset(seed=0)
    >>> _ = env.action_space.seed(0)
    >>> done = False
    >>> while not done:
    ...     _, _, terminated, truncated, _ = env.step(env.action_space.sample())
    ...     done = terminated or truncated
    >>> env.episode.steps
    5
    >>> env.episode.true_poses.shape, env.episode.executed_controls.shape
    ((6, 3), (5, 2))
    >>> env.episode.seed, env.episode_count
    (0, 1)
    >>> ranges, bearings, ids = env.episode.measurements(0)   # the measurement made at reset
    >>> env.close()
    """

    def __init__(self, env: gym.Env, directory: str | os.PathLike[str] | None = None) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, directory=None if directory is None else str(directory))
        gym.Wrapper.__init__(self, env)
        if not isinstance(env.unwrapped, SeifExploreEnv):
            raise TypeError(f"EpisodeRecorder needs a SeifExploreEnv inside, got {type(env.unwrapped).__name__}")
        self.directory: Path | None = None if directory is None else Path(directory)
        if self.directory is not None:
            self.directory.mkdir(parents=True, exist_ok=True)
        self.episode_count = 0
        self.paths: list[Path] = []
        self._recording = False  # an episode is in progress
        self._episode: Episode | None = None  # cache of the current / last episode
        self._buffers: dict[str, Any] = {}

    # -- gymnasium API ---------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        base = cast(SeifExploreEnv, self.env.unwrapped)  # checked by the constructor
        assert base.world is not None  # just reset
        self._buffers = {
            "config": base.config,
            "seed": seed,
            "dt": base.robot_config.dt,
            "landmarks": np.array(base.world.landmarks, dtype=np.float64),
            "true_poses": [],
            "estimated_poses": [],
            "commanded_controls": [],
            "executed_controls": [],
            "measurements": [],
            "rewards": [],
            "map_errors": [],
        }
        self._record(info)
        self._recording = True
        self._episode = None
        return observation, info

    def step(self, action: ArrayLike) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        if not self._buffers:
            raise RuntimeError("call reset() before step()")
        if not self._recording:
            raise RuntimeError("the recorded episode has ended; call reset() before step()")
        observation, reward, terminated, truncated, info = self.env.step(action)
        buffers = self._buffers
        buffers["commanded_controls"].append(np.array(info["control"], dtype=np.float64))
        buffers["executed_controls"].append(np.array(info["executed_control"], dtype=np.float64))
        buffers["rewards"].append(float(reward))
        self._record(info)
        self._episode = None
        if terminated or truncated:
            self._recording = False
            episode = self.episode
            if self.directory is not None:
                self.paths.append(episode.save(self.directory / f"episode_{self.episode_count:05d}.npz"))
            self.episode_count += 1
        return observation, reward, terminated, truncated, info

    def _record(self, info: dict[str, Any]) -> None:
        buffers = self._buffers
        buffers["true_poses"].append(np.array(info["true_pose"], dtype=np.float64))
        buffers["estimated_poses"].append(np.array(info["pose_estimate"], dtype=np.float64))
        buffers["map_errors"].append(float(info["map_error"]))
        measured = info["measurements"]
        buffers["measurements"].append(
            (
                np.array(measured.ranges, dtype=np.float64),
                np.array(measured.bearings, dtype=np.float64),
                np.array(measured.ids, dtype=np.int64),
            )
        )

    # -- the record -----------------------------------------------------------------
    @property
    def episode(self) -> Episode:
        """The current episode, or the last one if it has ended."""
        if self._episode is None:
            if not self._buffers:
                raise RuntimeError("no episode recorded yet: call reset()")
            self._episode = self._build()
        return self._episode

    def _build(self) -> Episode:
        buffers = self._buffers
        measurements = buffers["measurements"]
        counts = [len(ranges) for ranges, _, _ in measurements]
        return Episode(
            config=buffers["config"],
            seed=buffers["seed"],
            dt=buffers["dt"],
            landmarks=buffers["landmarks"],
            true_poses=np.array(buffers["true_poses"]).reshape(-1, 3),
            estimated_poses=np.array(buffers["estimated_poses"]).reshape(-1, 3),
            commanded_controls=np.array(buffers["commanded_controls"]).reshape(-1, 2),
            executed_controls=np.array(buffers["executed_controls"]).reshape(-1, 2),
            ranges=np.concatenate([m[0] for m in measurements]),
            bearings=np.concatenate([m[1] for m in measurements]),
            ids=np.concatenate([m[2] for m in measurements]),
            offsets=np.concatenate([[0], np.cumsum(counts)]),
            rewards=np.array(buffers["rewards"], dtype=np.float64),
            map_errors=np.array(buffers["map_errors"], dtype=np.float64),
        )


# ---------------------------------------------------------------------------
# Replay
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ReplayResult:
    """What a filter made of an episode (:func:`replay`).

    Attributes
    ----------
    poses : ndarray (T + 1, 3)
        Estimated pose after the first measurement and after each step.
    landmark_ids : ndarray (k,)
        Ids of the final map, in the filter's state order.
    landmarks : ndarray (k, 2)
        The final map estimate.
    map_errors : ndarray (T + 1,)
        The env's map error ``E_t`` of the estimate, computed as
        ``SeifExploreEnv.map_error`` does.
    step_seconds : ndarray (T,)
        Wall time of each ``predict`` + ``update`` (association included).
    filter : SlamFilter
        The filter, in its final state.
    association_errors : int
        With association re-run: its wrong, duplicate or discarded decisions
        over the episode (``AssociationAudit``); -1 with the true ids.
    """

    poses: FloatArray
    landmark_ids: IntArray
    landmarks: FloatArray
    map_errors: FloatArray
    step_seconds: FloatArray
    filter: Any
    association_errors: int = -1

    def __post_init__(self) -> None:
        for item in fields(self):
            if item.name not in ("filter", "association_errors"):
                array = np.array(getattr(self, item.name), copy=True)
                array.setflags(write=False)
                object.__setattr__(self, item.name, array)


#: What the :class:`~seif_gym.slam.association.Associator` uses of a filter (beyond ``predict``), checked before an ML replay.
ASSOCIATION_NEEDS: tuple[str, ...] = (
    "pose", "landmarks", "landmark_ids", "num_landmarks", "sensor",
    "local_marginals", "local_joint_covariance", "update_trusted",
)  # fmt: skip


#: The env's filter options an episode's config holds, and what an episode recorded before the option existed ran.
_ENV_FILTER_OPTIONS: dict[str, Any] = {"max_active": None, "mean_recovery": "amortized", "innovation_gate": None}


def _default_options(
    factory: Callable[..., SlamFilter], config: Mapping[str, Any], options: dict[str, Any]
) -> dict[str, Any]:
    """Add the env's filter options (``max_active``, ``mean_recovery``) where the filter takes them and the caller gave none.

    An episode recorded by seif_gym 0.1 has no ``mean_recovery`` in its
    config: it ran Thrun's round-robin recovery, which is what it replays with.
    """
    if not (isinstance(factory, type) and issubclass(factory, SlamFilter)):
        return options
    accepted = {**getattr(factory, "OPTIONS", {}), **COMMON_OPTIONS}  # every filter takes the common options
    added = dict(options)
    for name, recorded_before in _ENV_FILTER_OPTIONS.items():
        if name in accepted and name not in options and (name in config or recorded_before is not None):
            added[name] = config.get(name, recorded_before)
    return added


def replay(
    episode: Episode,
    filter: str = "seif",
    *,
    filter_factory: Callable[..., Any] | None = None,
    callback: Callable[[int, Any], None] | None = None,
    association: str | None = None,
    **options: Any,
) -> ReplayResult:
    """Run ``episode``'s controls and measurements through a filter.

    The motion model and the sensor are rebuilt from ``episode.config`` as
    the env builds them; the filter starts at the true start pose, processes
    the measurement made at the reset, then per step ``predict(executed
    control, dt)`` and ``update(ranges, bearings, ids)``, exactly the calls
    of the env. Replaying with the env's filter and options therefore
    reproduces ``episode.estimated_poses`` and ``episode.map_errors``.

    An episode recorded with ``data_association="ml"`` is replayed with the
    association re-run (a fresh associator of the episode's
    ``ml_association`` preset, scored against the recorded true ids as the
    env does): the filter never sees the true ids unless ``association="known"``
    asks for them.

    Parameters
    ----------
    episode : Episode
    filter : str, default "seif"
        A name of :data:`seif_gym.slam.FILTERS`.
    filter_factory : callable, optional
        Instead of ``filter``: ``filter_factory(motion, sensor, initial_pose,
        **options)`` returns the filter to run, any object with the
        :class:`~seif_gym.slam.SlamFilter` methods ``predict``, ``update``
        and the properties ``pose``, ``landmark_ids``, ``landmarks`` (a
        ``SlamFilter`` subclass itself works).
    callback : callable, optional
        ``callback(t, filter)`` after the measurement of time ``t``
        (``t = 0`` after the first one, ``t = T`` after the last step), e.g.
        to read covariances.
    association : {"known", "ml"}, optional
        ``"known"``: the filter gets the recorded true ids (an explicit
        choice, e.g. to compare an ml episode with known correspondences);
        ``"ml"``: the ids come from maximum-likelihood association of the
        measurements (the episode's ``ml_association`` preset); ``None``
        (default): as the episode was recorded (``config["data_association"]``).
        Association needs a filter with the methods the
        :class:`~seif_gym.slam.association.Associator` calls
        (:data:`ASSOCIATION_NEEDS`).
    **options
        Filter options. If the filter takes ``max_active`` and ``mean_recovery``
        (the SEIF, the ESEIF) and none is given, the episode's config's are used, as the
        env does.

    Returns
    -------
    ReplayResult

    Raises
    ------
    ValueError
        If ``association`` is not ``"known"``, ``"ml"`` or ``None``, or
        association is to be run (asked for, or recorded) with a filter that
        lacks what the associator needs: the true ids are never used in its
        place.
    """
    if not isinstance(episode, Episode):
        raise TypeError(f"episode must be an Episode, got {type(episode).__name__}")
    factory: Callable[..., SlamFilter]
    if filter_factory is None:
        if not isinstance(filter, str) or filter not in FILTERS:
            raise ValueError(f"filter must be one of {tuple(FILTERS)}, got {filter!r}")
        factory = FILTERS[filter]
    else:
        if filter != "seif":
            raise TypeError("pass either filter or filter_factory, not both")
        if not callable(filter_factory):
            raise TypeError(f"filter_factory must be callable, got {type(filter_factory).__name__}")
        factory = filter_factory
    if callback is not None and not callable(callback):
        raise TypeError(f"callback must be callable, got {type(callback).__name__}")
    config = episode.config
    explicit = association is not None
    if association is None:
        association = str(config.get("data_association", "known"))
    if association not in ("known", "ml"):
        raise ValueError(f"association must be 'known', 'ml' or None, got {association!r}")
    options = _default_options(factory, config, options)
    motion, sensor = episode_models(config)
    filt = factory(motion, sensor, episode.true_poses[0].copy(), **options)
    if association == "ml":
        missing = [name for name in ASSOCIATION_NEEDS if not hasattr(filt, name)]
        if missing:
            asked = (
                "association='ml'"
                if explicit
                else "association=None (the episode was recorded with data_association='ml')"
            )
            raise ValueError(
                f"{asked} needs a filter with {', '.join(ASSOCIATION_NEEDS)}; {type(filt).__name__} lacks "
                f"{', '.join(missing)}. Pass association='known' to feed it the true ids instead"
            )

    steps, dt = episode.steps, episode.dt
    d_cap = config["d_cap"]
    poses = np.empty((steps + 1, 3))
    map_errors = np.empty(steps + 1)
    seconds = np.empty(steps)

    # an episode of 0.1 has no ml_association: it ran the individual-compatibility associator
    associator = make_associator(str(config.get("ml_association", "individual"))) if association == "ml" else None
    audit = AssociationAudit() if association == "ml" else None

    def measurement(t: int) -> tuple[NDArray[Any], ...]:
        return tuple(np.array(part) for part in episode.measurements(t))  # writable copies, like the env's

    def update(ranges: ArrayLike, bearings: ArrayLike, true_ids: ArrayLike) -> None:
        """The env's ``_filter_update``: the true ids, or association scored against them."""
        if associator is None:
            filt.update(ranges, bearings, true_ids)
        else:
            assert audit is not None  # made together with the associator
            audit.record(associator, associator.update(filt, ranges, bearings), true_ids)

    update(*measurement(0))
    poses[0] = filt.pose
    map_errors[0] = filter_map_error(filt, episode.landmarks, d_cap, audit)
    if callback is not None:
        callback(0, filt)
    for t in range(steps):
        control = np.array(episode.executed_controls[t])
        ranges, bearings, ids = measurement(t + 1)
        started = time.perf_counter()
        filt.predict(control, dt)
        update(ranges, bearings, ids)
        seconds[t] = time.perf_counter() - started
        poses[t + 1] = filt.pose
        map_errors[t + 1] = filter_map_error(filt, episode.landmarks, d_cap, audit)
        if callback is not None:
            callback(t + 1, filt)
    return ReplayResult(
        poses=poses,
        landmark_ids=np.asarray(filt.landmark_ids),
        landmarks=np.asarray(filt.landmarks),
        map_errors=map_errors,
        step_seconds=seconds,
        filter=filt,
        association_errors=-1 if audit is None else int(audit.errors),
    )
