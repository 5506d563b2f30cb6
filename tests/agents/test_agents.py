"""Tests of the agents (``agents``) and of the evaluation (``agents.evaluate``).

* every baseline runs on every registered variant, reading no ground truth:
  the agents get a guarded view of the env whose ``world`` (and every other
  truth: the true trajectory, the map error) raises on any use, while the real
  env produces the observations; each reads the observation through that
  env's own geometry, and a missing or foreign env is an error;
* ``predict`` follows SB3 (single and batched observations, ``episode_start``);
* ``random`` is reproducible per seed;
* the evaluation writes the documented CSV columns and JSON keys, and its
  paired statistics match a hand computation.
"""

from __future__ import annotations

import csv
import json
import os

import gymnasium as gym
import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

import seif_gym  # noqa: E402  (registers the environments)
from agents import (  # noqa: E402
    BASELINES,
    Agent,
    evaluate,  # noqa: E402
    make_agent,
)
from agents.baselines import GEOMETRY_READS, INFO_GAIN_READS, Geometry, landmark_rows, read_belief_map  # noqa: E402
from agents.parallel import Executor  # noqa: E402
from seif_gym.observation import ObservationDecoder  # noqa: E402

OBS_ONLY = tuple(name for name in BASELINES if name != "info_gain")
TRUTH = ("world", "trajectory", "map_error", "_map_error", "_log_det_criterion", "_info", "step", "reset")


class GroundTruthAccess(AssertionError):
    """An agent touched the ground truth."""


class PoisonedWorld:
    """Stands in for ``env.unwrapped.world``: any attribute access raises."""

    def __getattribute__(self, name: str):
        raise GroundTruthAccess(f"an agent read world.{name}")

    def __bool__(self) -> bool:
        raise GroundTruthAccess("an agent tested the world")


class GuardedEnv:
    """A view of a real env for the agent: ``world`` is poisoned, the rest is forwarded and logged.

    The real env (stepped by the test) keeps its true world; the agent only
    ever sees this view, as ``env`` and as ``env.unwrapped``.
    """

    def __init__(self, env: gym.Env) -> None:
        object.__setattr__(self, "_base", env.unwrapped)
        object.__setattr__(self, "reads", set())

    @property
    def unwrapped(self) -> GuardedEnv:
        return self

    def __getattr__(self, name: str):
        if name == "world":
            return PoisonedWorld()
        if name in TRUTH:
            raise GroundTruthAccess(f"an agent read env.{name}")
        self.reads.add(name)
        return getattr(self._base, name)


def run_short(env: gym.Env, agent: Agent, seed: int = 0) -> list[np.ndarray]:
    """Run one episode (the env's time limit); return the actions."""
    obs, _ = env.reset(seed=seed)
    actions, start, done = [], True, False
    while not done:
        action, state = agent.predict(obs, episode_start=start)
        assert state is None
        assert action.shape == (2,) and action.dtype == np.float32
        assert np.all(np.abs(action) <= 1.0) and np.all(np.isfinite(action))
        actions.append(action)
        obs, _, terminated, truncated, _ = env.step(action)
        start, done = False, terminated or truncated
    return actions


def agent_kwargs(name: str) -> dict:
    return {"seed": 0} if name == "random" else {}


# -- the interface ----------------------------------------------------------------------------------
def test_registry() -> None:
    assert BASELINES == ("random", "frontier", "revisit", "info_gain")
    env = gym.make("SeifExplore-v0", max_episode_steps=5)
    for name in BASELINES:
        agent = make_agent(name, env)
        assert isinstance(agent, Agent) and agent.name == name
        assert callable(agent.predict)
    with pytest.raises(ValueError, match="unknown agent"):
        make_agent("nope", env)


# -- every baseline on every variant, without the ground truth ---------------------------------------
@pytest.mark.parametrize("name", BASELINES)
@pytest.mark.parametrize("env_id", list(seif_gym.VARIANTS))
def test_baseline_runs_on_variant_without_truth(env_id: str, name: str) -> None:
    env = gym.make(env_id, max_episode_steps=30)
    view = GuardedEnv(env)
    agent = make_agent(name, view, **agent_kwargs(name))
    actions = run_short(env, agent)
    assert len(actions) == 30
    allowed = INFO_GAIN_READS if name == "info_gain" else GEOMETRY_READS
    assert view.reads <= set(allowed), f"{name} read {sorted(view.reads - set(allowed))}"
    # the observation is read through this env's own geometry
    assert agent.geometry.decoder == ObservationDecoder.from_env(env) == env.unwrapped.encoder.decoder()
    assert agent.geometry.arena_size == env.unwrapped.world_config.arena_size
    if name == "info_gain":
        assert "filter" in view.reads and agent.planning_times
    else:
        assert "filter" not in view.reads  # the observation is all it uses
    if name in ("frontier", "revisit"):
        assert np.any(np.stack(actions)[:, 0] > 0.1), "it should drive somewhere"


@pytest.mark.parametrize("name", BASELINES)
def test_every_baseline_needs_the_env_it_acts_in(name: str) -> None:
    """No silent default geometry: a missing or foreign env raises ``TypeError`` naming ``env``."""
    with pytest.raises(TypeError, match="env"):
        make_agent(name, None, **agent_kwargs(name))
    with pytest.raises(TypeError, match="SeifExplore env"):
        make_agent(name, gym.make("CartPole-v1"), **agent_kwargs(name))
    with pytest.raises(TypeError, match="env"):
        make_agent(name, object(), **agent_kwargs(name))


@pytest.mark.parametrize("env_id", list(seif_gym.VARIANTS))
def test_geometry_is_the_env_encoders_inverse(env_id: str) -> None:
    env = gym.make(env_id, max_episode_steps=5)
    geometry = Geometry.from_env(env)
    encoder = env.unwrapped.encoder
    assert geometry.decoder == encoder.decoder()
    assert geometry.arena_size == encoder.arena_size and geometry.map_extent == encoder.config.map_extent
    assert geometry.sensor_range == env.unwrapped.sensor.max_range
    # the landmark offsets decode to metres with this env's arena: a frontier agent of the default
    # geometry would misread SeifExploreLarge's by a factor of 2
    assert geometry.arena_size == seif_gym.VARIANTS[env_id][0].get("arena_size", 20.0)


def test_a_vec_env_of_mixed_geometries_is_refused() -> None:
    envs = [gym.make("SeifExplore-v1", max_episode_steps=5), gym.make("SeifExploreLarge-v1", max_episode_steps=5)]
    with pytest.raises(ValueError, match="differ in geometry"):
        make_agent("frontier", envs)
    frontier = make_agent("frontier", envs[0])
    obs, _ = envs[0].reset(seed=0)
    with pytest.raises(ValueError, match="another env"):
        frontier.predict({**obs, "belief_map": np.zeros((3, 16, 16), dtype=np.uint8)})


def test_info_gain_is_deterministic_and_reads_only_the_belief() -> None:
    env = gym.make("SeifExplore-v0", max_episode_steps=25)
    runs = []
    for _ in range(2):
        view = GuardedEnv(env)
        runs.append(np.stack(run_short(env, make_agent("info_gain", view, replan_every=2), seed=11)))
        assert view.reads <= set(INFO_GAIN_READS)
    np.testing.assert_array_equal(runs[0], runs[1])


def test_the_guard_catches_a_cheating_agent() -> None:
    class Cheater(Agent):
        def _act(self, observation, index):
            landmarks = self.env.unwrapped.world.landmarks  # the truth: not allowed
            return np.zeros(2) + 0 * len(landmarks)

    env = gym.make("SeifExplore-v0", max_episode_steps=5)
    with pytest.raises(GroundTruthAccess):
        run_short(env, Cheater(GuardedEnv(env)))
    with pytest.raises(GroundTruthAccess):
        _ = GuardedEnv(env).trajectory


# -- predict: single and batched ------------------------------------------------------------------
def _batch(observations: list[dict]) -> dict:
    return {key: np.stack([obs[key] for obs in observations]) for key in observations[0]}


@pytest.mark.parametrize("name", BASELINES)
def test_predict_batched_matches_single(name: str) -> None:
    envs = [gym.make("SeifExplore-v0", max_episode_steps=20) for _ in range(3)]
    observations = [env.reset(seed=20 + k)[0] for k, env in enumerate(envs)]
    batched_agent = make_agent(name, envs if name == "info_gain" else envs[0], **agent_kwargs(name))
    single_agents = [make_agent(name, env, **agent_kwargs(name)) for env in envs]
    for step in range(6):
        actions, state = batched_agent.predict(_batch(observations), episode_start=np.full(3, step == 0))
        assert state is None
        assert actions.shape == (3, 2) and actions.dtype == np.float32
        assert np.all(np.abs(actions) <= 1.0)
        if name != "random":  # memory is per env row: the batch equals one agent per env
            for k in range(3):
                single, _ = single_agents[k].predict(observations[k], episode_start=step == 0)
                np.testing.assert_array_equal(actions[k], single)
        observations = [env.step(action)[0] for env, action in zip(envs, actions)]


def test_predict_on_a_vec_env() -> None:
    from stable_baselines3.common.vec_env import DummyVecEnv

    venv = DummyVecEnv([lambda: gym.make("SeifExploreClustered-v0", max_episode_steps=10) for _ in range(2)])
    venv.seed(5)
    agents = [make_agent(name, venv, **agent_kwargs(name)) for name in BASELINES]
    obs = venv.reset()
    k = venv.envs[0].unwrapped.observation_config.nearest_landmarks
    assert obs["landmarks"].shape == (2, 4 * k) and obs["belief_map"].dtype == np.uint8
    assert landmark_rows(obs, batched=True).shape == (2, k, 4)
    assert read_belief_map(obs).shape == obs["belief_map"].shape
    starts = np.ones(2, dtype=bool)
    for _ in range(12):  # across an episode boundary
        for agent in agents[:-1]:
            actions, _ = agent.predict(obs, episode_start=starts)
            assert actions.shape == (2, 2)
        actions, _ = agents[-1].predict(obs, episode_start=starts)  # info_gain drives
        obs, _, dones, _ = venv.step(actions)
        starts = dones
    with pytest.raises(ValueError, match="no env"):
        make_agent("info_gain", venv.envs[0]).predict(obs)
    with pytest.raises(TypeError):
        agents[0].predict(np.zeros(7))


# -- the observation format -----------------------------------------------------------------------
def test_read_belief_map_scales_uint8_to_unit_floats() -> None:
    env = gym.make("SeifExplore-v0", max_episode_steps=5)
    obs, _ = env.reset(seed=0)
    raw = obs["belief_map"]
    assert raw.dtype == np.uint8 and raw.shape == (3, 40, 40)
    belief = read_belief_map(obs)
    assert belief.dtype == np.float64 and belief.shape == raw.shape
    np.testing.assert_array_equal(belief, raw.astype(np.float64) / 255.0)
    assert belief.min() >= 0.0 and belief.max() == 1.0
    np.testing.assert_array_equal(read_belief_map(raw), belief)  # the array itself works too
    # a float map (already in [0, 1]) is not scaled again
    np.testing.assert_array_equal(read_belief_map(belief.astype(np.float32)), belief.astype(np.float32))
    # batched
    batch = np.stack([raw, raw])
    np.testing.assert_array_equal(read_belief_map({"belief_map": batch}), np.stack([belief, belief]))
    assert raw.dtype == np.uint8 and raw.max() == 255  # the observation is left alone


def test_landmark_rows_reshapes_single_and_batched() -> None:
    env = gym.make("SeifExplore-v0", max_episode_steps=5, nearest_landmarks=5)
    obs, _ = env.reset(seed=0)
    assert obs["landmarks"].shape == (20,)
    rows = landmark_rows(obs)
    assert rows.shape == (5, 4) and rows.dtype == np.float64
    np.testing.assert_array_equal(rows[2], obs["landmarks"][8:12])
    np.testing.assert_array_equal(landmark_rows(rows), rows)  # already rows: unchanged
    batch = np.stack([obs["landmarks"], 2 * obs["landmarks"], 3 * obs["landmarks"]])
    batched = landmark_rows(batch, batched=True)
    assert batched.shape == (3, 5, 4)
    for k in range(3):
        np.testing.assert_array_equal(batched[k], landmark_rows(batch[k]))
    assert landmark_rows({"landmarks": batch}, batched=True).shape == (3, 5, 4)


def _old_format(obs: dict) -> dict:
    """The observation in the format before the uint8 map and flat landmarks: float32 [0, 1], (K, 4)."""
    old = dict(obs)
    old["belief_map"] = (obs["belief_map"].astype(np.float64) / 255.0).astype(np.float32)
    old["landmarks"] = obs["landmarks"].reshape(-1, 4)
    return old


@pytest.mark.parametrize("name", ["frontier", "revisit"])
def test_observation_agents_act_the_same_on_the_old_and_new_formats(name: str) -> None:
    """The uint8 map and the flat landmarks change nothing of the decisions."""
    env = gym.make("SeifExplore-v0", max_episode_steps=60)
    kwargs = {"period": 10, "cooldown": 5} if name == "revisit" else {}
    new_agent, old_agent = make_agent(name, env, **kwargs), make_agent(name, env, **kwargs)
    obs, _ = env.reset(seed=5)
    start = True
    for _ in range(60):
        action, _ = new_agent.predict(obs, episode_start=start)
        old_action, _ = old_agent.predict(_old_format(obs), episode_start=start)
        np.testing.assert_array_equal(action, old_action)
        obs, _, terminated, truncated, _ = env.step(action)
        start = False
        if terminated or truncated:
            break
    if name == "revisit":
        assert new_agent._state(0).revisits > 0, "test setup: the landmark rows should have been used"


def test_revisit_targets_the_listed_landmark_from_the_flat_rows() -> None:
    """``revisit`` reads the (4K,) landmarks as K rows: its target is the most uncertain listed landmark."""
    env = gym.make("SeifExplore-v0", max_episode_steps=50)
    agent = make_agent("revisit", env, period=1, cooldown=0)
    obs, _ = env.reset(seed=1)
    for _ in range(5):
        obs = env.step(np.array([0.6, 0.4], dtype=np.float32))[0]
    mask = obs["landmarks_mask"] > 0.5
    assert mask.sum() >= 2, "test setup: several listed landmarks"
    rows = obs["landmarks"].reshape(-1, 4).astype(np.float64)
    best = rows[int(np.argmax(np.where(mask, rows[:, 2], -np.inf)))]
    target = agent._choose_target(obs)
    pose = obs["pose"].astype(np.float64)
    theta = np.arctan2(pose[3], pose[2])
    c, s = np.cos(theta), np.sin(theta)
    forward, left = best[:2] * 2.0 * np.sqrt(2.0)
    np.testing.assert_allclose(target, [pose[0] + c * forward - s * left, pose[1] + s * forward + c * left])


# -- random ---------------------------------------------------------------------------------------
def test_random_is_reproducible_per_seed() -> None:
    env = gym.make("SeifExplore-v0", max_episode_steps=15)
    a = np.stack(run_short(env, make_agent("random", env, seed=42)))
    b = np.stack(run_short(env, make_agent("random", env, seed=42)))
    c = np.stack(run_short(env, make_agent("random", env, seed=43)))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.min() < -0.5 and a.max() > 0.5


# -- evaluation -----------------------------------------------------------------------------------
def test_schema_is_documented() -> None:
    doc = evaluate.__doc__
    for name in (*evaluate.RESULT_COLUMNS, *evaluate.SUMMARY_KEYS, *evaluate.AGENT_KEYS, *evaluate.STAT_KEYS,
                 *evaluate.CURVE_KEYS, *evaluate.PAIRED_KEYS, *evaluate.PAIRED_STAT_KEYS):  # fmt: skip
        assert f"``{name}``" in doc, f"{name} is not documented in agents.evaluate"
    assert set(evaluate.SUMMARY_METRICS) <= set(evaluate.RESULT_COLUMNS)


def test_evaluation_writes_the_documented_schema(tmp_path) -> None:
    specs = ["random", "frontier", "revisit", "info_gain"]
    rows, summary = evaluate.evaluate_agents(specs, 2, 7, "SeifExplore-v0", {"max_episode_steps": 20})
    paths = evaluate.write_outputs(rows, summary, tmp_path)
    with open(paths["csv"], newline="") as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames) == evaluate.RESULT_COLUMNS
        table = list(reader)
    assert len(table) == len(specs) * 2
    for agent in specs:  # the same seeds for every agent
        assert [row["seed"] for row in table if row["agent"] == agent] == ["7", "8"]
    assert all(row["length"] == "20" for row in table)
    data = json.loads(paths["json"].read_text())
    assert tuple(data) == evaluate.SUMMARY_KEYS
    assert data["schema_version"] == evaluate.SCHEMA_VERSION
    assert data["seeds"] == [7, 8] and data["episodes"] == 2 and data["env_kwargs"] == {"max_episode_steps": 20}
    assert list(data["agents"]) == specs
    for entry in data["agents"].values():
        assert tuple(entry) == evaluate.AGENT_KEYS
        for metric in evaluate.SUMMARY_METRICS:
            stat = entry[metric]
            assert tuple(stat) == evaluate.STAT_KEYS and stat["n"] == 2
            assert stat["ci95_low"] <= stat["mean"] <= stat["ci95_high"]
        curve = entry["map_error_over_time"]
        assert tuple(curve) == evaluate.CURVE_KEYS and len(curve["mean"]) == 21
    assert data == json.loads(json.dumps(summary))
    assert paths["plot"].stat().st_size > 0
    assert "| frontier |" in paths["markdown"].read_text()
    # the metrics agree with the rows
    frontier = [float(row["final_map_error"]) for row in table if row["agent"] == "frontier"]
    assert data["agents"]["frontier"]["final_map_error"]["mean"] == pytest.approx(np.mean(frontier))
    # the paired comparison: every agent but the best baseline against it, on the same seeds
    paired = data["paired"]
    assert tuple(paired) == evaluate.PAIRED_KEYS and paired["metric"] == "final_map_error"
    means = {label: entry["final_map_error"]["mean"] for label, entry in data["agents"].items()}
    assert paired["reference"] == min(means, key=means.get)
    assert set(paired["agents"]) == set(specs) - {paired["reference"]}
    for label, entry in paired["agents"].items():
        assert tuple(entry) == (*evaluate.PAIRED_STAT_KEYS, "verdict") and entry["n"] == 2
        assert entry["mean"] == pytest.approx(means[label] - means[paired["reference"]])
    assert "Paired per-seed differences" in paths["markdown"].read_text()


# -- paired statistics -----------------------------------------------------------------------------
#: A small fixed table: final map errors of three agents on the seeds 5, 6, 7, 8.
FIXED = {
    "frontier": [0.30, 0.25, 0.40, 0.35],
    "revisit": [0.20, 0.30, 0.30, 0.25],
    "ppo": [0.10, 0.15, 0.20, 0.10],
}


def _fixed_rows() -> list[dict]:
    return [{"agent": agent, "seed": 5 + k, "final_map_error": value}
            for agent, values in FIXED.items() for k, value in enumerate(values)]  # fmt: skip


def test_paired_difference_matches_a_hand_computation() -> None:
    # frontier - revisit, per seed: 0.10, -0.05, 0.10, 0.10
    # mean 0.0625; s_d = sqrt((3 * 0.0375**2 + 0.1125**2) / 3) = 0.075; t(0.975, 3) = 3.1824463052837078
    # half width = 3.1824463052837078 * 0.075 / sqrt(4) = 0.11934173644813903
    result = evaluate.paired_difference(FIXED["frontier"], FIXED["revisit"])
    assert result["n"] == 4
    assert result["mean"] == pytest.approx(0.0625, abs=1e-15)
    assert result["std"] == pytest.approx(0.075, abs=1e-15)
    assert result["ci95_low"] == pytest.approx(0.0625 - 0.11934173644813903, abs=1e-12)
    assert result["ci95_high"] == pytest.approx(0.0625 + 0.11934173644813903, abs=1e-12)
    assert result["bootstrap_ci95_low"] is None
    assert evaluate.paired_verdict(result) == "tie (interval holds 0)"
    # ppo - revisit: -0.10, -0.15, -0.10, -0.15: mean -0.125, s_d = 0.028867513459481284,
    # half width = 3.1824463052837078 * 0.028867513459481284 / 2 = 0.04593465577592696: [-0.1709, -0.0791]
    result = evaluate.paired_difference(FIXED["ppo"], FIXED["revisit"])
    assert result["mean"] == pytest.approx(-0.125, abs=1e-15)
    assert result["ci95_high"] == pytest.approx(-0.125 + 0.04593465577592696, abs=1e-12)
    assert evaluate.paired_verdict(result) == "beats"
    assert evaluate.paired_verdict(evaluate.paired_difference(FIXED["revisit"], FIXED["ppo"])) == "worse"


def test_paired_comparison_of_a_fixed_table() -> None:
    # means: frontier 0.325, revisit 0.2625, ppo 0.1375: the best *baseline* is revisit (ppo is not a baseline)
    paired = evaluate.paired_comparison(_fixed_rows(), baselines=["frontier", "revisit"], bootstrap=2000)
    assert paired["reference"] == "revisit" and list(paired["agents"]) == ["frontier", "ppo"]
    ppo = paired["agents"]["ppo"]
    assert ppo["verdict"] == "beats" and ppo["mean"] == pytest.approx(-0.125)
    # the bootstrap interval lies within the sample's range of differences and holds the mean
    assert -0.15 - 1e-12 <= ppo["bootstrap_ci95_low"] <= -0.125 <= ppo["bootstrap_ci95_high"] <= -0.10 + 1e-12
    assert paired["agents"]["frontier"]["verdict"] == "tie (interval holds 0)"
    # reproducible, and "beats" only when the interval excludes zero
    assert evaluate.paired_comparison(_fixed_rows(), ["frontier", "revisit"], bootstrap=2000) == paired
    summary = {"seeds": [5, 6, 7, 8], "paired": paired}
    table = evaluate.paired_table(summary)
    assert "| ppo | -0.125 | [-0.171, -0.079] | " in table and "beats revisit |" in table
    assert "| frontier | +0.062 | [-0.057, +0.182] | " in table  # 0.0625 rounds to even
    # no baseline: nothing to compare with
    assert evaluate.paired_comparison(_fixed_rows(), baselines=[])["reference"] is None


def test_paired_statistics_reject_bad_input() -> None:
    with pytest.raises(ValueError, match="values and reference"):
        evaluate.paired_difference([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="confidence"):
        evaluate.paired_difference([1.0, 2.0], [1.0, 1.0], confidence=1.5)
    with pytest.raises(ValueError, match="bootstrap"):
        evaluate.paired_difference([1.0, 2.0], [1.0, 1.0], bootstrap=-1)
    one = evaluate.paired_difference([1.0], [0.5])
    assert one["mean"] == 0.5 and one["ci95_low"] is None and evaluate.paired_verdict(one) == "n/a (one seed)"
    rows = _fixed_rows()[:-1]  # ppo lost its last seed
    with pytest.raises(ValueError, match="different seeds"):
        evaluate.paired_comparison(rows, ["revisit"])


def test_belief_extractor_gets_the_uint8_map_as_unit_floats() -> None:
    """SB3 treats the uint8 belief map as an image: scaled to [0, 1] before ``BeliefExtractor``."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.preprocessing import is_image_space, preprocess_obs
    from stable_baselines3.common.vec_env import DummyVecEnv

    from agents.networks import BeliefExtractor

    venv = DummyVecEnv([lambda: gym.make("SeifExplore-v0", max_episode_steps=10) for _ in range(2)])
    assert is_image_space(venv.observation_space["belief_map"])
    model = PPO("MultiInputPolicy", venv, n_steps=8, batch_size=16, n_epochs=1, device="cpu", seed=0,
                policy_kwargs={"features_extractor_class": BeliefExtractor})  # fmt: skip
    model.learn(16)
    obs = venv.reset()
    tensors = preprocess_obs({key: torch.as_tensor(value) for key, value in obs.items()}, venv.observation_space)
    belief = tensors["belief_map"]
    assert belief.dtype == torch.float32 and float(belief.min()) >= 0.0 and float(belief.max()) == 1.0
    torch.testing.assert_close(belief, torch.as_tensor(obs["belief_map"], dtype=torch.float32) / 255.0)
    features = model.policy.features_extractor(tensors)
    k = venv.envs[0].unwrapped.observation_config.nearest_landmarks
    assert features.shape == (2, 128 + 7 + 4 * k + k)
    actions, _ = model.predict(obs)
    assert actions.shape == (2, 2)


def test_cli_with_an_sb3_model_and_vecnormalize(tmp_path, capsys) -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    # the uint8 belief map is an image (SB3's policy scales it by 1/255 itself): normalise the vectors only.
    # (VecNormalize would otherwise replace the image's space by a float32 box *in place*, i.e. in the env's own
    # Dict space, and the env's passive checker would warn that its uint8 observations leave that space.)
    venv = VecNormalize(
        DummyVecEnv([lambda: gym.make("SeifExplore-v0", max_episode_steps=10)]),
        norm_reward=False, norm_obs_keys=["pose", "landmarks", "landmarks_mask"],
    )  # fmt: skip
    assert venv.observation_space["belief_map"].dtype == np.uint8
    model = PPO("MultiInputPolicy", venv, n_steps=8, batch_size=8, n_epochs=1, device="cpu", seed=0)
    model.learn(8)
    (tmp_path / "model").mkdir()
    model.save(tmp_path / "model" / "policy.zip")
    venv.save(tmp_path / "model" / "vecnormalize.pkl")
    agent = evaluate.build_agent(
        str(tmp_path / "model" / "policy.zip"), gym.make("SeifExplore-v0"), "SeifExplore-v0", {}, 0
    )
    assert agent.vecnormalize is not None and not agent.vecnormalize.training
    out = tmp_path / "out"
    status = evaluate.main([
        "--agents", f"frontier,{tmp_path / 'model' / 'policy.zip'}", "--episodes", "2", "--seed", "3",
        "--env-kwargs", '{"max_episode_steps": 10}', "--out", str(out),
    ])  # fmt: skip
    assert status == 0
    captured = capsys.readouterr()
    printed = captured.out
    assert "| policy |" in printed and "| frontier |" in printed
    assert "Paired per-seed differences of final map error to the best baseline, frontier" in printed
    assert "| policy | " in printed.split("Paired")[1]
    assert "frontier: 2 episodes" in captured.err  # progress on stderr (none with --quiet)
    assert {path.name for path in out.iterdir()} == {
        "results.csv",
        "summary.json",
        "summary.md",
        "map_error.png",
        "manifest.json",
    }
    assert list(json.loads((out / "summary.json").read_text())["agents"]) == ["frontier", "policy"]


def test_a_stored_run_joins_and_pairs_as_if_its_agents_had_run_again(tmp_path, capsys) -> None:
    kwargs = {"max_episode_steps": 12}
    together_rows, together = evaluate.evaluate_agents(
        ["revisit", "frontier", "random"], 3, 5, "SeifExplore-v1", kwargs
    )
    status = evaluate.main(["--agents", "revisit,frontier", "--episodes", "3", "--seed", "5", "--env", "SeifExplore-v1",
                            "--env-kwargs", json.dumps(kwargs), "--out", str(tmp_path / "stored"), "--quiet"])  # fmt: skip
    assert status == 0
    rows, summary = evaluate.evaluate_agents(["random"], 3, 5, "SeifExplore-v1", kwargs, stored_run=tmp_path / "stored")
    assert summary["stored_run"] == str(tmp_path / "stored") and together["stored_run"] is None
    assert list(summary["agents"]) == ["random", "revisit", "frontier"]
    # the stored episodes are the ones a run of all three gives, and so is the paired comparison
    key = lambda row: (row["agent"], row["seed"])  # noqa: E731
    for mine, theirs in zip(sorted(rows, key=key), sorted(together_rows, key=key)):
        assert {k: v for k, v in mine.items() if k != "decision_time_ms"} == {
            k: v for k, v in theirs.items() if k != "decision_time_ms"
        }
    assert summary["paired"]["reference"] == together["paired"]["reference"]
    assert summary["paired"]["agents"]["random"] == together["paired"]["agents"]["random"]
    # through the command line too, written out with the stored agents
    capsys.readouterr()
    status = evaluate.main(["--agents", "random", "--episodes", "3", "--seed", "5", "--env", "SeifExplore-v1",
                            "--env-kwargs", json.dumps(kwargs), "--out", str(tmp_path / "new"), "--quiet",
                            "--stored-run", str(tmp_path / "stored")])  # fmt: skip
    assert status == 0
    assert "| random | " in capsys.readouterr().out.split("Paired")[1]
    with open(tmp_path / "new" / "results.csv", newline="") as handle:
        assert sorted({row["agent"] for row in csv.DictReader(handle)}) == ["frontier", "random", "revisit"]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"episodes": 2}, "seeds"),
        ({"seed": 6}, "seeds"),
        ({"env_id": "SeifExplore-v2"}, "env_id"),
        ({"env_kwargs": {"max_episode_steps": 13}}, "env_kwargs"),
        ({"specs": ["revisit"]}, "already has the agents"),
    ],
)
def test_a_stored_run_of_another_task_or_seeds_is_refused_before_any_episode(tmp_path, change, message) -> None:
    kwargs = {"max_episode_steps": 12}
    rows, summary = evaluate.evaluate_agents(["revisit"], 3, 5, "SeifExplore-v1", kwargs)
    evaluate.write_outputs(rows, summary, tmp_path / "stored")
    arguments = {"specs": ["random"], "episodes": 3, "seed": 5, "env_id": "SeifExplore-v1", "env_kwargs": kwargs}
    arguments.update(change)

    class Refused(Exception):
        pass

    def no_episode(*_: object, **__: object) -> None:
        raise Refused  # an episode would have run

    executor = Executor()
    executor.map = no_episode  # type: ignore[method-assign]
    with pytest.raises(ValueError, match=message):
        evaluate.evaluate_agents(arguments["specs"], arguments["episodes"], arguments["seed"], arguments["env_id"],
                                 arguments["env_kwargs"], stored_run=tmp_path / "stored", executor=executor)  # fmt: skip
    with pytest.raises(FileNotFoundError, match="summary.json"):
        evaluate.evaluate_agents(["random"], 3, 5, "SeifExplore-v1", kwargs, stored_run=tmp_path / "nothing")
    with pytest.raises(TypeError, match="stored_run must be a folder's path"):
        evaluate.evaluate_agents(["random"], 3, 5, "SeifExplore-v1", kwargs, stored_run=3)  # type: ignore[arg-type]
    (tmp_path / "stored" / "summary.json").write_text("{not json")
    with pytest.raises(ValueError, match="is not JSON"):
        evaluate.evaluate_agents(["random"], 3, 5, "SeifExplore-v1", kwargs, stored_run=tmp_path / "stored",
                                 executor=executor)  # fmt: skip


def test_quiet_evaluation_writes_nothing_on_stderr(tmp_path, capsys) -> None:
    status = evaluate.main(["--agents", "frontier,random", "--episodes", "2", "--seed", "1", "--env", "SeifExplore-v1",
                            "--env-kwargs", '{"max_episode_steps": 5}', "--out", str(tmp_path), "--quiet"])  # fmt: skip
    assert status == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    assert "| random | " in captured.out.split("Paired")[1]  # the paired table is still printed


def test_showcase_verdict_comes_from_the_paired_interval() -> None:
    from agents.showcase import verdict_sentence

    rows = _fixed_rows()
    agents = {label: {"final_map_error": {"mean": float(np.mean(values))}} for label, values in FIXED.items()}
    summary = {"agents": agents, "paired": evaluate.paired_comparison(rows, ["frontier", "revisit"])}
    sentence = verdict_sentence(summary, "ppo")
    assert sentence.startswith("ppo (0.138 m) beats the best baseline, revisit (0.263 m): ")
    assert "-0.125 m, 95% t interval [-0.171, -0.079] m over 4 seeds" in sentence
    # a lower mean alone is not enough: revisit has a lower mean than frontier, but the interval holds 0
    summary["paired"] = evaluate.paired_comparison(rows, ["frontier"])  # frontier is the only baseline
    assert "does not beat" in verdict_sentence(summary, "revisit") and "holds 0" in verdict_sentence(summary, "revisit")


def test_json_object_arguments_are_read_once_for_every_command_line(capsys):
    import doctest

    import agents.cli
    from agents.evaluate import main as evaluate_main
    from agents.robustness import main as robustness_main
    from research.select import main as select_main

    assert doctest.testmod(agents.cli).failed == 0
    for main, argv in (
        (evaluate_main, ["--agents", "random"]),
        (robustness_main, []),
        (select_main, ["run", "--env", "SeifExplore-v1"]),
    ):
        for text, message in (("[1]", "expected a JSON object"), ("{oops", "not valid JSON")):
            with pytest.raises(SystemExit) as exit_info:
                main([*argv, "--env-kwargs", text])
            assert exit_info.value.code == 2
            error = capsys.readouterr().err
            assert "--env-kwargs" in error and message in error, error


def test_showcase_takes_the_protocol_episode_count_of_its_env(capsys) -> None:
    from agents.showcase import main as showcase_main

    with pytest.raises(SystemExit):
        showcase_main(["--env", "Nope-v0"])  # the protocol's count is looked up before anything runs
    assert "--env: env_id: unknown env 'Nope-v0'" in capsys.readouterr().err


def test_showcase_gif_runs_a_recurrent_policy_with_its_memory(tmp_path, monkeypatch) -> None:
    """The GIF's episode is the evaluation's: the same actions, the LSTM's state carried from step to step."""
    from agents.benchmark import SHIPPED_POLICIES
    from agents.evaluate import SB3Agent, run_episode
    from agents.showcase import record_gif

    policy = SHIPPED_POLICIES["ppo_lstm_clustered_budget_v2"]
    actions: list[np.ndarray] = []
    predict = SB3Agent.predict

    def logged(self, observation, state=None, episode_start=None, deterministic=True):
        action, new_state = predict(
            self, observation, state=state, episode_start=episode_start, deterministic=deterministic
        )
        actions.append(np.array(action))
        return action, new_state

    monkeypatch.setattr(SB3Agent, "predict", logged)
    env = gym.make(policy.task)
    run_episode(SB3Agent(policy.path, env=env), env, seed=3)
    env.close()
    evaluated, actions[:] = list(actions), []
    gif = record_gif(policy.path, tmp_path / "episode.gif", seed=3, every=25, size=64, env_id=policy.task)
    assert gif.stat().st_size > 0
    assert len(actions) == len(evaluated) == gym.spec(policy.task).max_episode_steps
    assert all(np.array_equal(a, b) for a, b in zip(actions, evaluated, strict=True))


def test_evaluation_env_leaves_out_only_the_exact_nees():
    """The evaluation's env (exact_pose_nees off) gives every metric of run_episode bit for bit as the plain env."""
    from agents.evaluate import make_evaluation_env, run_episode

    kwargs = {"num_landmarks": 80, "sensor_range": 12.0, "fov": 2 * np.pi, "max_episode_steps": 80}
    cheap, plain = make_evaluation_env("SeifExplore-v2", kwargs), gym.make("SeifExplore-v2", **kwargs)
    assert cheap.unwrapped.exact_pose_nees is False and plain.unwrapped.exact_pose_nees is True
    row_cheap, trace_cheap = run_episode(make_agent("frontier", cheap), cheap, 4)
    row_plain, trace_plain = run_episode(make_agent("frontier", plain), plain, 4)
    row_cheap.pop("decision_time_ms"), row_plain.pop("decision_time_ms")  # wall-clock time
    assert row_cheap == row_plain and trace_cheap == trace_plain
    assert row_plain["landmarks_mapped"] > 60  # past the dense factorisation: the sparse one left out too
    with pytest.raises(TypeError, match="env_kwargs"):
        make_evaluation_env("SeifExplore-v2", [("num_landmarks", 80)])
    asked = make_evaluation_env("SeifExplore-v2", {"exact_pose_nees": True})
    assert asked.unwrapped.exact_pose_nees is True  # env_kwargs still decide
    for env in (cheap, plain, asked):
        env.close()
