"""Tests of :mod:`seif_gym.episodes`: recording, saving and replaying episodes."""

from __future__ import annotations

import dataclasses
import doctest
import inspect
import pickle
from functools import cache

import gymnasium as gym
import numpy as np
import pytest

import seif_gym  # noqa: F401  (registers the envs)
import seif_gym.episodes
from seif_gym.envs.explore import SeifExploreEnv
from seif_gym.episodes import Episode, EpisodeRecorder, ReplayResult, replay
from seif_gym.slam import EIF, EKF, SEIF

STEPS = 100

#: (env id, env kwargs): the env's own filter of each is replayed and must match exactly.
#: The per-second motion noise and range-dependent range noise (about what MRCLAM's calibration gives).
CALIBRATED = (
    ("motion_model", "per_second"),
    ("motion_noise", (1e-4, 0.0, 2e-5, 4e-4, 0.01, 0.02, 0.0, 2e-4, 1e-4)),
    ("range_noise", (0.05, 0.07, 0.2)),
)
CASES = [
    ("SeifExplore-v1", ()),
    ("SeifExplore-v1", CALIBRATED),
    ("SeifExploreLoop-v1", (*CALIBRATED, ("filter", "ekf"), ("innovation_gate", 9.0))),
    ("SeifExploreLoop-v1", (("innovation_gate", 6.0),)),
    ("SeifExploreMRCLAM-v0", ()),
    ("SeifExploreLoop-v1", (*CALIBRATED, ("filter", "eseif"))),
    ("SeifExploreLoop-v1", (("max_active", 4),)),
    ("SeifExploreLoop-v1", (("filter", "eseif"),)),
    ("SeifExploreLoop-v1", (("data_association", "ml"),)),
    ("SeifExploreLoop-v1", (("data_association", "ml"), ("ml_association", "joint"))),
    ("SeifExploreLoop-v1", (("data_association", "ml"), ("ml_association", "revisable"))),
    ("SeifExploreLoop-v2", (("data_association", "ml"), ("ml_association", "likelihood"))),
    ("SeifExploreLoop-v0", (("data_association", "ml"),)),
    ("SeifExplore-v0", ()),
    ("SeifExplore-v0", (("max_active", 4),)),
    ("SeifExplore-v0", (("filter", "ekf"),)),
    ("SeifExplore-v0", (("filter", "eif"),)),
    ("SeifExploreLoop-v0", ()),
    ("SeifExploreLoop-v0", (("max_active", 4),)),
    ("SeifExploreLoop-v0", (("filter", "ekf"),)),
    ("SeifExploreLoop-v0", (("filter", "eif"),)),
]


@dataclasses.dataclass
class Recording:
    episode: Episode
    infos: list[dict]
    rewards: list[float]
    env_config: dict
    final_landmark_ids: np.ndarray
    final_landmarks: np.ndarray


@cache
def record(env_id: str, kwargs: tuple = (), seed: int = 11, steps: int = STEPS) -> Recording:
    """One episode of ``steps`` random actions (from a seeded action space), recorded."""
    env = EpisodeRecorder(gym.make(env_id, max_episode_steps=steps, **dict(kwargs)))
    _, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    infos, rewards = [info], []
    done = False
    while not done:
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        infos.append(info)
        rewards.append(reward)
        done = terminated or truncated
    base = env.unwrapped
    recording = Recording(
        env.episode, infos, rewards, base.config, base.filter.landmark_ids.copy(), base.filter.landmarks.copy()
    )
    env.close()
    return recording


def case_id(case) -> str:
    env_id, kwargs = case
    return env_id + "".join(f"-{k}={v}" for k, v in kwargs)


# -- recording -------------------------------------------------------------------------
@pytest.mark.parametrize("case", CASES[6:7] + CASES[10:11], ids=case_id)
def test_episode_matches_the_env_infos_at_every_step(case):
    rec = record(*case)
    episode, infos = rec.episode, rec.infos
    assert episode.steps == STEPS == len(infos) - 1
    assert dict(episode.config) == rec.env_config
    assert episode.seed == 11
    assert episode.dt == rec.env_config["dt"]
    assert len(episode.landmarks) == rec.env_config["num_landmarks"]
    assert episode.offsets.shape == (STEPS + 2,)
    for t, info in enumerate(infos):
        ranges, bearings, ids = episode.measurements(t)
        measured = info["measurements"]
        np.testing.assert_array_equal(ranges, measured.ranges)
        np.testing.assert_array_equal(bearings, measured.bearings)
        np.testing.assert_array_equal(ids, measured.ids)
        assert ranges.dtype == np.float64 and bearings.dtype == np.float64 and ids.dtype == np.int64
        np.testing.assert_array_equal(episode.true_poses[t], info["true_pose"])
        np.testing.assert_array_equal(episode.estimated_poses[t], info["pose_estimate"])
        assert episode.map_errors[t] == info["map_error"]
        if t > 0:
            np.testing.assert_array_equal(episode.commanded_controls[t - 1], info["control"])
            np.testing.assert_array_equal(episode.executed_controls[t - 1], info["executed_control"])
    np.testing.assert_array_equal(episode.rewards, rec.rewards)
    # every measurement is stored once (steps that saw nothing are empty slices)
    assert len(episode.ranges) == sum(len(info["measurements"].ranges) for info in infos) > 0
    with pytest.raises(IndexError):
        episode.measurements(STEPS + 1)
    with pytest.raises(IndexError):
        episode.measurements(-1)


def test_saved_episode_loads_identical(tmp_path):
    episode = record("SeifExploreLoop-v0").episode
    path = episode.save(tmp_path / "loop")  # .npz is appended
    assert path == tmp_path / "loop.npz" and path.exists()
    loaded = Episode.load(path)
    assert loaded == episode and not (loaded != episode)
    assert loaded.config == episode.config and dict(loaded.config) == record("SeifExploreLoop-v0").env_config
    assert isinstance(loaded.config["motion_noise"], tuple)
    assert loaded.seed == episode.seed and loaded.dt == episode.dt
    for field in dataclasses.fields(Episode):
        value, original = getattr(loaded, field.name), getattr(episode, field.name)
        if isinstance(original, np.ndarray):
            np.testing.assert_array_equal(value, original)
            assert value.dtype == original.dtype and value.shape == original.shape
            assert not value.flags.writeable
    # plain arrays only: everything reads back without pickle
    with np.load(path, allow_pickle=False) as data:
        assert all(data[name].dtype != object for name in data.files)
    # a seedless episode round-trips too, and a changed array breaks equality
    unseeded = dataclasses.replace(episode, seed=None)
    assert Episode.load(unseeded.save(tmp_path / "unseeded.npz")) == unseeded
    assert unseeded != episode
    rewards = episode.rewards.copy()
    rewards[3] += 1e-12
    assert dataclasses.replace(episode, rewards=rewards) != episode


def test_episode_pickles_identical():
    """Episodes travel to worker processes and Ray nodes and back (agents.parallel) by pickle."""
    episode = record("SeifExploreLoop-v0").episode
    copy = pickle.loads(pickle.dumps(episode))
    assert copy == episode and copy.config == episode.config and copy.seed == episode.seed
    assert isinstance(copy.config["motion_noise"], tuple)
    with pytest.raises(TypeError):
        copy.config["layout"] = "grid"  # still read only
    assert not copy.rewards.flags.writeable


def test_episode_is_read_only_and_validated():
    episode = record("SeifExplore-v0").episode
    with pytest.raises(ValueError):
        episode.true_poses[0, 0] = 1.0
    with pytest.raises(TypeError):
        episode.config["dt"] = 1.0  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        episode.seed = 3  # type: ignore[misc]
    with pytest.raises(TypeError):
        hash(episode)
    offsets = episode.offsets.copy()
    offsets[-1] += 1
    with pytest.raises(ValueError, match="offsets"):
        dataclasses.replace(episode, offsets=offsets)
    with pytest.raises(ValueError, match="true_poses"):
        dataclasses.replace(episode, true_poses=episode.true_poses[:-1])
    assert "steps=100" in repr(episode)


def test_recorder_saves_each_finished_episode(tmp_path):
    env = EpisodeRecorder(gym.make("SeifExplore-v0", max_episode_steps=4), directory=tmp_path / "runs")
    with pytest.raises(RuntimeError):
        _ = env.episode
    env.action_space.seed(0)
    episodes = []
    for seed in (5, None):
        env.reset(seed=seed)
        assert env.episode.steps == 0
        done = False
        while not done:
            *_, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated
        episodes.append(env.episode)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(env.action_space.sample())
    # an episode cut short by a reset is not saved
    env.reset()
    env.step(env.action_space.sample())
    assert env.episode.steps == 1
    env.reset()
    assert env.episode_count == 2
    assert [p.name for p in env.paths] == ["episode_00000.npz", "episode_00001.npz"]
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["episode_00000.npz", "episode_00001.npz"]
    assert [Episode.load(p) for p in env.paths] == episodes
    assert [e.seed for e in episodes] == [5, None]
    assert all(e.steps == 4 for e in episodes)
    env.close()
    with pytest.raises(TypeError, match="SeifExploreEnv"):
        EpisodeRecorder(gym.make("CartPole-v1"))


def test_seed_and_commanded_controls_regenerate_the_episode():
    rec = record("SeifExplore-v0")
    episode = rec.episode
    # SeifExploreEnv.config also holds WorldConfig.wall_margin, which is no constructor argument
    accepted = inspect.signature(SeifExploreEnv).parameters
    env = SeifExploreEnv(**{k: v for k, v in episode.config.items() if k in accepted})
    _, info = env.reset(seed=episode.seed)
    np.testing.assert_array_equal(env.world.landmarks, episode.landmarks)
    scale = np.array([episode.config["max_speed"], episode.config["max_turn_rate"]])
    for t in range(episode.steps):
        *_, info = env.step(episode.commanded_controls[t] / scale)
        np.testing.assert_array_equal(info["true_pose"], episode.true_poses[t + 1])
    np.testing.assert_array_equal(env.filter.pose, episode.estimated_poses[-1])


# -- replay ----------------------------------------------------------------------------
@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_replay_with_the_env_filter_is_bit_exact(case):
    rec = record(*case)
    episode = rec.episode
    result = replay(episode, episode.config["filter"])
    assert isinstance(result, ReplayResult)
    np.testing.assert_array_equal(result.poses, episode.estimated_poses)
    np.testing.assert_array_equal(result.map_errors, episode.map_errors)
    np.testing.assert_array_equal(result.landmark_ids, rec.final_landmark_ids)
    np.testing.assert_array_equal(result.landmarks, rec.final_landmarks)
    assert result.step_seconds.shape == (episode.steps,) and np.all(result.step_seconds >= 0)
    assert not result.poses.flags.writeable
    if episode.config["data_association"] == "ml":
        assert result.association_errors >= 0
        assert result.association_errors == sum(info["association_errors"] for info in rec.infos)
    else:
        assert result.association_errors == -1
    if episode.config["filter"] == "seif":
        # the env's max_active is the default; passing it explicitly is the same run
        assert result.filter.max_active == episode.config["max_active"]
        explicit = replay(episode, "seif", max_active=episode.config["max_active"])
        np.testing.assert_array_equal(explicit.poses, episode.estimated_poses)
        np.testing.assert_array_equal(explicit.map_errors, episode.map_errors)


def test_replay_of_a_loaded_episode_is_bit_exact(tmp_path):
    episode = record("SeifExploreLoop-v0", (("max_active", 4),)).episode
    loaded = Episode.load(episode.save(tmp_path / "e.npz"))
    result = replay(loaded)
    np.testing.assert_array_equal(result.poses, episode.estimated_poses)
    np.testing.assert_array_equal(result.map_errors, episode.map_errors)


class IdsSeen(SEIF):
    """A SEIF that logs the ids of every measurement update it is given."""

    fed: list

    def update_trusted(self, ranges, bearings, ids):
        self.fed.append(np.array(ids))
        super().update_trusted(ranges, bearings, ids)


def ids_seen_factory(fed: list) -> type:
    """A subclass of :class:`IdsSeen` appending to ``fed``."""
    return type("Seen", (IdsSeen,), {"fed": fed})


def test_ml_episode_replays_with_association_not_the_true_ids():
    """An ml episode re-runs the association; the true ids only when asked for, and then differently."""
    episode = record("SeifExploreLoop-v1", (("data_association", "ml"),), seed=3, steps=150).episode
    fed: list = []
    result = replay(episode, filter_factory=ids_seen_factory(fed))
    np.testing.assert_array_equal(result.poses, episode.estimated_poses)
    # the filter was given the associator's ids (fresh ones from 0), not the simulator's ids
    true = [np.asarray(episode.measurements(t)[2]) for t in range(episode.steps + 1)]
    assert len(fed) == len(true)
    assert any(not np.array_equal(f, t) for f, t in zip(fed, true))
    known = replay(episode, association="known")
    assert known.association_errors == -1
    assert not np.array_equal(known.landmark_ids, result.landmark_ids) or not np.array_equal(known.poses, result.poses)
    with pytest.raises(ValueError, match="association"):
        replay(episode, association="oracle")


def test_short_ml_episode_replays_its_association_bit_for_bit(tmp_path):
    """60 steps of an ml episode whose associator errs: the replay re-runs it, also from a saved file."""
    rec = record("SeifExplore-v1", (("data_association", "ml"),), seed=7, steps=60)
    episode = rec.episode
    recorded_errors = sum(info["association_errors"] for info in rec.infos)
    assert recorded_errors > 0  # the associator decided differently from the true ids at least once
    loaded = Episode.load(episode.save(tmp_path / "ml.npz"))
    for source in (episode, loaded):
        result = replay(source, source.config["filter"])
        np.testing.assert_array_equal(result.poses, episode.estimated_poses)
        np.testing.assert_array_equal(result.map_errors, episode.map_errors)
        np.testing.assert_array_equal(result.landmark_ids, rec.final_landmark_ids)
        assert result.association_errors == recorded_errors
    # association="known" is an explicit choice: the filter then gets exactly the recorded true ids
    fed: list = []
    known = replay(episode, filter_factory=ids_seen_factory(fed), association="known")
    true = [episode.measurements(t)[2] for t in range(episode.steps + 1)]
    assert len(fed) == len(true) and all(np.array_equal(f, t) for f, t in zip(fed, true))
    assert known.association_errors == -1
    assert not np.array_equal(known.map_errors, episode.map_errors)


def test_ml_replay_never_falls_back_to_the_true_ids():
    """A filter the associator cannot use raises instead of silently getting the true ids."""
    ml_episode = record("SeifExplore-v1", (("data_association", "ml"),), seed=7, steps=60).episode
    known_episode = record("SeifExplore-v0").episode

    class PoseAndMapOnly:
        """The minimal filter of ``replay``'s ``filter_factory``: no association support."""

        def __init__(self, motion, sensor, initial_pose):
            self._inner = EKF(motion, sensor, initial_pose)

        def predict(self, control, dt):
            self._inner.predict(control, dt)

        def update(self, ranges, bearings, ids):
            self._inner.update(ranges, bearings, ids)

        pose = property(lambda self: self._inner.pose)
        landmark_ids = property(lambda self: self._inner.landmark_ids)
        landmarks = property(lambda self: self._inner.landmarks)

    with pytest.raises(ValueError, match=r"association=None .*data_association='ml'.*lacks"):
        replay(ml_episode, filter_factory=PoseAndMapOnly)
    with pytest.raises(ValueError, match=r"association='ml' needs"):
        replay(known_episode, filter_factory=PoseAndMapOnly, association="ml")
    # asked for explicitly, the true ids are fed: the same run as the EKF's with known ids
    minimal = replay(ml_episode, filter_factory=PoseAndMapOnly, association="known")
    np.testing.assert_array_equal(minimal.poses, replay(ml_episode, "ekf", association="known").poses)
    # and a known-ids episode can be replayed with association
    associated = replay(known_episode, association="ml")
    assert associated.association_errors >= 0 and np.all(np.isfinite(associated.poses))
    for bad in ("oracle", "", 1):
        with pytest.raises(ValueError, match="association must be"):
            replay(known_episode, association=bad)


def logging_filter(cls, log: list):
    """``cls`` with every ``predict`` and ``update`` call appended to ``log``."""

    class Logged(cls):
        def __init__(self, motion, sensor, initial_pose, *args, **options):
            log.append(("init", np.array(initial_pose), repr(motion), repr(sensor)))
            super().__init__(motion, sensor, initial_pose, *args, **options)

        def predict(self, control, dt):
            log.append(("predict", np.array(control), dt))
            super().predict(control, dt)

        def update(self, ranges, bearings, ids):
            log.append(("update", np.array(ranges), np.array(bearings), np.array(ids)))
            super().update(ranges, bearings, ids)

    return Logged


def test_every_filter_gets_the_same_data():
    episode = record("SeifExploreLoop-v0").episode
    logs = {}
    for cls in (SEIF, EKF, EIF):
        logs[cls.__name__] = []
        result = replay(episode, filter_factory=logging_filter(cls, logs[cls.__name__]))
        assert type(result.filter).__mro__[1] is cls
        assert np.all(np.isfinite(result.poses)) and result.map_errors[-1] < result.map_errors[0]
    reference = logs["SEIF"]
    assert len(reference) == 1 + 1 + 2 * episode.steps
    assert reference[0][0] == "init"
    np.testing.assert_array_equal(reference[0][1], episode.true_poses[0])
    for t in range(episode.steps + 1):
        call = reference[1 + 2 * t]  # init, update(0), predict(1), update(1), ...
        assert call[0] == "update"
        for logged, stored in zip(call[1:], episode.measurements(t)):
            np.testing.assert_array_equal(logged, stored)
        if t > 0:
            kind, control, dt = reference[2 * t]
            assert kind == "predict" and dt == episode.dt
            np.testing.assert_array_equal(control, episode.executed_controls[t - 1])
    for name in ("EKF", "EIF"):
        other = logs[name]
        assert len(other) == len(reference)
        for a, b in zip(reference, other):
            assert a[0] == b[0]
            for x, y in zip(a[1:], b[1:]):
                if isinstance(x, np.ndarray):
                    np.testing.assert_array_equal(x, y)
                    assert x.dtype == y.dtype
                else:
                    assert x == y


def test_filter_factory_subclass_gets_the_env_options():
    episode = record("SeifExplore-v0", (("max_active", 4),)).episode
    log: list = []
    result = replay(episode, filter_factory=logging_filter(SEIF, log))
    assert result.filter.max_active == 4
    np.testing.assert_array_equal(result.poses, episode.estimated_poses)
    # an EKF episode replayed through the SEIF uses the config's max_active (as the env with filter="seif")
    ekf_episode = record("SeifExplore-v0", (("filter", "ekf"),)).episode
    assert replay(ekf_episode, "seif").filter.max_active == ekf_episode.config["max_active"]
    assert replay(ekf_episode, "seif", max_active=2).filter.max_active == 2


def test_replay_callback_and_argument_checks():
    episode = record("SeifExplore-v0").episode
    seen = []
    result = replay(episode, "ekf", callback=lambda t, filt: seen.append((t, filt.pose.copy())))
    assert [t for t, _ in seen] == list(range(episode.steps + 1))
    np.testing.assert_array_equal(np.array([pose for _, pose in seen]), result.poses)
    # a plain function as factory, without default options
    calls = []

    def factory(motion, sensor, initial_pose, **options):
        calls.append(options)
        return EKF(motion, sensor, initial_pose)

    replay(episode, filter_factory=factory)
    assert calls == [{}]
    with pytest.raises(ValueError, match="filter must be one of"):
        replay(episode, "fastslam")
    with pytest.raises(TypeError, match="either filter or filter_factory"):
        replay(episode, "ekf", filter_factory=factory)
    with pytest.raises(TypeError, match="unknown option"):
        replay(episode, "ekf", max_active=3)
    with pytest.raises(TypeError, match="Episode"):
        replay({"not": "an episode"})


def test_module_doctests_pass():
    results = doctest.testmod(seif_gym.episodes, optionflags=doctest.ELLIPSIS)
    assert results.attempted > 0
    assert results.failed == 0
