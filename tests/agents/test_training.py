"""agents.train on rl-zoo3's ExperimentManager, the task callbacks, checkpoints with their statistics, --init-from."""

from __future__ import annotations

import csv
import json
import pickle
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import seif_gym  # noqa: F401
from agents import make_agent
from agents.benchmark import SHIPPED_POLICIES
from agents.checkpoints import load_vecnormalize_stats, save_with_vecnormalize, vecnormalize_path
from agents.evaluate import SB3Agent
from agents.showcase import SHIPPED_POLICY

pytest.importorskip("rl_zoo3", reason="rl_zoo3 is in the train extra")

from agents.callbacks import MapErrorEvalCallback  # noqa: E402
from agents.hyperparams import load  # noqa: E402
from agents.train import (  # noqa: E402
    build_parser,
    last_update_progress,
    main,
    mixture_ids,
    negative_schedule_warnings,
    prepare,
    train,
)

POLICIES = Path(SHIPPED_POLICY).parent
#: a small, quick run: 2 envs of 10 landmarks and 60-step episodes, 2 rollouts of 2 x 128 steps
SMALL = [
    "--env",
    "SeifExplore-v1",
    "--n-envs",
    "2",
    "--seed",
    "1",
    "--env-kwargs",
    json.dumps({"num_landmarks": 10, "max_episode_steps": 60}),
    "--hyperparams",
    "n_steps=128",
    "batch_size=128",
    "n_epochs=1",
]


def tensorboard_tags(folder: Path) -> set[str]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tags: set[str] = set()
    for events in folder.rglob("events.out.tfevents*"):
        accumulator = EventAccumulator(str(events))
        accumulator.Reload()
        tags.update(accumulator.Tags()["scalars"])
    return tags


def _policy_state(path: Path) -> dict[str, torch.Tensor]:
    from stable_baselines3 import PPO

    return PPO.load(path, device="cpu").policy.state_dict()


def _same_weights(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


# -- the config --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "algo, env_id, path",
    [
        ("ppo", "SeifExplore-v0", SHIPPED_POLICY),
        ("ppo_lstm", "SeifExploreLoopBudget-v2", POLICIES / "ppo_lstm_loop_budget_v2.zip"),
        ("ppo_lstm", "SeifExploreLoopBudget-v2", POLICIES / "ppo_lstm_clustered_budget_v2.zip"),
        ("ppo_lstm", "SeifExploreLoopBudget-v2", POLICIES / "ppo_lstm_loop_v2.zip"),
        ("ppo_lstm", "SeifExplore-v2", POLICIES / "ppo_lstm_seif_explore_v2.zip"),
    ],
)
def test_config_entry_is_the_shipped_policys_recipe(algo, env_id, path):
    """The config entry holds what the shipped model was trained with, shaping included."""
    from agents.evaluate import sb3_algorithm

    entry = load(algo)[env_id]
    shipped = sb3_algorithm(path).load(path, device="cpu")
    for key in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "ent_coef", "vf_coef", "max_grad_norm"):
        assert getattr(shipped, key) == pytest.approx(entry[key]), key
    assert shipped.n_envs == entry["n_envs"]
    assert shipped.lr_schedule(1.0) == pytest.approx(entry["learning_rate"])
    assert shipped.clip_range(1.0) == pytest.approx(entry["clip_range"])
    assert entry["env_wrapper"] == [{"agents.shaping.CoverageShaping": {"coef": 0.5, "gamma": 0.995}}]
    # the shipped network, by the config's policy class and policy_kwargs
    from rl_zoo3.utils import get_class_by_name
    from torch import nn  # noqa: F401  (rl-zoo3 evaluates policy_kwargs with nn in scope)

    policy_class = get_class_by_name(entry["policy"])
    kwargs = eval(entry["policy_kwargs"])  # noqa: S307  (the project's own config, as rl-zoo3 reads it)
    env = gym.make(env_id)
    policy = policy_class(env.observation_space, env.action_space, lambda _: 0.0, **kwargs)
    assert {k: v.shape for k, v in policy.state_dict().items()} == {
        k: v.shape for k, v in shipped.policy.state_dict().items()
    }
    assert policy.activation_fn is shipped.policy.activation_fn


# -- agents.train ------------------------------------------------------------------------------------
@pytest.mark.slow
def test_agents_train_writes_a_run_rl_zoo3_reads_and_watches_the_task(tmp_path, capfd):
    out = tmp_path / "run"
    # the native vector env (no env wrapper), validation and checkpoints every rollout, nothing printed
    argv = [
        *SMALL,
        "-n",
        "512",
        "--out",
        str(out),
        "--hyperparams",
        "env_wrapper=null",
        "--vec-env",
        "native",
        "--eval-freq",
        "256",
        "--eval-episodes",
        "2",
        "--checkpoint-freq",
        "256",
        "--quiet",
    ]
    assert main(argv) == 0
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == "", captured
    assert (out / "SeifExplore-v1.zip").is_file() and (out / "SeifExplore-v1" / "vecnormalize.pkl").is_file()
    assert (out / "SeifExplore-v1" / "config.yml").is_file() and (out / "monitor.csv").is_file()
    for steps in (256, 512):  # checkpoints with their own statistics
        assert (
            vecnormalize_path(out / f"rl_model_{steps}_steps.zip") == out / f"rl_model_vecnormalize_{steps}_steps.pkl"
        )
    rows = list(csv.DictReader((out / "map_error_evaluations.csv").open()))
    assert [int(r["timesteps"]) for r in rows] == [256, 512]
    assert (out / "best_map_error" / "model.zip").is_file()
    tags = tensorboard_tags(out / "tb")
    for tag in ("rollout/final_map_error", "rollout/landmarks_mapped", "rollout/pose_rmse", "eval/final_map_error"):
        assert tag in tags, (tag, sorted(tags))
    assert json.loads((out / "train_time.json").read_text())["timesteps"] == 512
    # the best model loads with its own statistics and acts
    env = gym.make("SeifExplore-v1", num_landmarks=10, max_episode_steps=5)
    agent = SB3Agent(out / "best_map_error" / "model.zip", env=env)
    assert agent.vecnormalize is not None
    observation, _ = env.reset(seed=0)
    action, _ = agent.predict(observation, deterministic=True)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0 + 1e-6)


def test_progress_bar_unless_quiet_and_shaping_from_the_config(tmp_path):
    from stable_baselines3.common.callbacks import ProgressBarCallback

    from agents.callbacks import TaskMetricsCallback
    from agents.shaping import CoverageShaping

    experiment, model = prepare(build_parser().parse_args([*SMALL, "--out", str(tmp_path / "a")]))
    assert any(isinstance(c, ProgressBarCallback) for c in experiment.callbacks)
    assert sum(isinstance(c, MapErrorEvalCallback) for c in experiment.callbacks) == 1
    assert sum(isinstance(c, TaskMetricsCallback) for c in experiment.callbacks) == 1
    # the config's env wrapper, outside SB3's Monitor (the logged return stays the env's own)
    assert not experiment.uses_native()
    wrapped = model.get_env().venv.envs[0]
    assert isinstance(wrapped, CoverageShaping) and wrapped.coef == 0.5 and type(wrapped.env).__name__ == "Monitor"
    model.get_env().close()
    quiet, quiet_model = prepare(build_parser().parse_args([*SMALL, "--out", str(tmp_path / "b"), "--quiet"]))
    assert not any(isinstance(c, ProgressBarCallback) for c in quiet.callbacks)
    quiet_model.get_env().close()


def test_bad_arguments_are_refused(tmp_path):
    with pytest.raises(ValueError, match="--env"):
        prepare(build_parser().parse_args(["--env", "NoSuchEnv-v0", "--out", str(tmp_path)]))
    with pytest.raises(ValueError, match="--n-envs"):
        prepare(build_parser().parse_args([*SMALL, "--n-envs", "0", "--out", str(tmp_path)]))
    with pytest.raises(ValueError, match="--wrapper"):
        prepare(build_parser().parse_args([*SMALL, "--wrapper", "agents.shaping", "--out", str(tmp_path)]))
    with pytest.raises(SystemExit):
        build_parser().parse_args([*SMALL, "--eval-freq", "0"])
    with pytest.raises(SystemExit):
        build_parser().parse_args([*SMALL, "--env-kwargs", "[1]"])


def test_last_update_progress_is_where_sb3_updates_last():
    # 100 000 steps in rollouts of 8 x 512: 25 rollouts, the last update after 102 400 steps
    assert last_update_progress(100_000, 4096) == pytest.approx(1 - 102_400 / 100_000)
    assert last_update_progress(102_400, 4096) == 0.0
    assert last_update_progress(10, 4096) == pytest.approx(1 - 4096 / 10)
    with pytest.raises(ValueError, match="rollout_steps"):
        last_update_progress(100, 0)


def test_a_decaying_schedule_that_would_turn_negative_is_reported(tmp_path, capfd):
    # SMALL collects rollouts of 2 x 128 = 256 steps: 300 steps end at 512, progress 1 - 512/300
    args = [*SMALL, "learning_rate=lin_3e-4", "clip_range=lin_0.2", "--out", str(tmp_path), "--timesteps", "300"]
    _, model = prepare(build_parser().parse_args(args))
    lines = negative_schedule_warnings(model, 300)
    assert [line.split()[0] for line in lines] == ["learning_rate", "clip_range"]
    assert f"{3e-4 * (1 - 512 / 300):.3g}" in lines[0] and "e.g. 512" in lines[0]
    assert "agents.train: learning_rate is" in capfd.readouterr().err
    assert negative_schedule_warnings(model, 512) == []  # a whole number of rollouts ends at zero
    with pytest.raises(ValueError, match="total_timesteps"):
        negative_schedule_warnings(model, 0)
    _, constant = prepare(build_parser().parse_args([*SMALL, "--out", str(tmp_path / "c"), "--timesteps", "300"]))
    assert negative_schedule_warnings(constant, 300) == []


def test_mix_env_cycles_the_training_envs_through_the_ids_and_validates_on_env(tmp_path):
    out = tmp_path / "mix"
    argv = [*SMALL, "--mix-env", "SeifExploreLoop-v1", "--n-envs", "3", "--out", str(out), "--quiet"]
    experiment, model = prepare(build_parser().parse_args(argv))
    assert not experiment.uses_native()  # a mixture runs single envs
    envs = model.get_env().venv.envs
    assert [env.spec.id for env in envs] == ["SeifExplore-v1", "SeifExploreLoop-v1", "SeifExplore-v1"]
    # the arguments reach every env, the layout stays each id's own
    assert [env.unwrapped.config["num_landmarks"] for env in envs] == [10, 10, 10]
    assert [env.unwrapped.config["layout"] for env in envs] == ["uniform", "loop", "uniform"]
    (validation,) = [c for c in experiment.callbacks if isinstance(c, MapErrorEvalCallback)]
    assert validation.env_id == "SeifExplore-v1"
    model.learn(384)  # a rollout of 3 x 128 steps: each rank logs its own id's episodes
    model.get_env().close()
    heads = [json.loads((out / f"{rank}.monitor.csv").read_text().splitlines()[0][1:])["env_id"] for rank in range(3)]
    assert heads == ["SeifExplore-v1", "SeifExploreLoop-v1", "SeifExplore-v1"]


def test_mix_env_refuses_unknown_ids_and_other_spaces_before_building_the_run(tmp_path):
    out = tmp_path / "mix"
    with pytest.raises(ValueError, match="--mix-env: unknown env 'NoSuchEnv-v0'"):
        prepare(build_parser().parse_args([*SMALL, "--mix-env", "NoSuchEnv-v0", "--out", str(out)]))
    with pytest.raises(ValueError, match="--mix-env: 'CartPole-v1' has other observation or action spaces"):
        prepare(build_parser().parse_args(["--env", "SeifExplore-v1", "--mix-env", "CartPole-v1", "--out", str(out)]))
    assert mixture_ids("SeifExplore-v1", []) == ["SeifExplore-v1"]
    assert not out.exists()


# -- the validation callback -------------------------------------------------------------------------
@pytest.fixture()
def small_model(tmp_path):
    """A PPO on 2 normalised envs (observation statistics on the vector keys), with a CSV logger."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.networks import BeliefPolicy

    venv = make_vec_env("SeifExplore-v1", n_envs=2, seed=0, env_kwargs={"num_landmarks": 10, "max_episode_steps": 20})
    venv = VecNormalize(venv, norm_obs=True, norm_reward=True, norm_obs_keys=["pose", "landmarks"])
    model = PPO(BeliefPolicy, venv, n_steps=32, batch_size=32, device="cpu", seed=0)
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    yield model
    venv.close()


def test_eval_callback_keeps_the_checkpoint_with_the_lowest_map_error(small_model, tmp_path, monkeypatch):
    import agents.evaluate

    errors = iter([0.9, 0.4, 0.6])  # the second evaluation is the best

    def scripted_episode(policy, env, seed):
        error = current["error"]
        return {
            "final_map_error": error + 1e-3 * (seed % 2),
            "landmarks_mapped": 7,
            "landmarks_total": 10,
            "pose_rmse": 0.1,
        }, [error]

    current: dict[str, float] = {}
    monkeypatch.setattr(agents.evaluate, "run_episode", scripted_episode)
    callback = MapErrorEvalCallback(eval_freq=100, n_episodes=2, first_seed=7, save_path=tmp_path / "run", verbose=0)
    callback.init_callback(small_model)
    assert callback.env_id == "SeifExplore-v1" and callback.env_kwargs["max_episode_steps"] == 20
    assert callback.seeds == [7, 8]
    weights, statistics = [], []
    for k in range(3):
        with torch.no_grad():  # a distinct model and distinct statistics at each evaluation
            next(small_model.policy.parameters()).fill_(float(k))
        vec_normalize = small_model.get_vec_normalize_env()
        vec_normalize.obs_rms["pose"].mean[:] = float(k)
        small_model.num_timesteps = 100 * (k + 1)
        current["error"] = next(errors)
        callback.evaluate()
        weights.append({name: t.clone() for name, t in small_model.policy.state_dict().items()})
        statistics.append(float(k))
    assert callback.best_map_error == pytest.approx(0.4005)
    assert callback.best_timesteps == 200
    assert _same_weights(_policy_state(callback.best_model_path), weights[1])
    saved = load_vecnormalize_stats(vecnormalize_path(callback.best_model_path))
    assert np.all(saved.obs_rms["pose"].mean == statistics[1])
    rows = list(csv.DictReader((tmp_path / "run" / "map_error_evaluations.csv").open()))
    assert [int(r["best"]) for r in rows] == [1, 1, 0] and [int(r["timesteps"]) for r in rows] == [100, 200, 300]


def test_eval_callback_validates_on_the_plain_env(small_model, tmp_path):
    from agents.shaping import CoverageShaping

    callback = MapErrorEvalCallback(eval_freq=100, n_episodes=1, save_path=tmp_path, verbose=0)
    callback.init_callback(small_model)
    row = callback.evaluate()
    assert not isinstance(callback._env, CoverageShaping) and callback._env.unwrapped.spec.id == "SeifExplore-v1"
    assert 0.0 < row["final_map_error"] and row["landmarks_total"] == 10


def test_eval_callback_without_a_run_folder_warns_and_writes_nothing(small_model, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    callback = MapErrorEvalCallback(eval_freq=100, n_episodes=1, verbose=0)
    with pytest.warns(UserWarning, match="save_path"):
        callback.init_callback(small_model)  # no monitor log (as in rl-zoo3's Optuna trials)
    row = callback.evaluate()
    assert row["best"] == 1 and callback.best_timesteps == 0
    assert [p.name for p in tmp_path.iterdir()] == ["log"]  # the fixture's logger only
    with pytest.raises(ValueError, match="save_path"):
        _ = callback.best_model_path


def test_run_folder_is_where_the_monitor_writes(tmp_path):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.callbacks import run_folder
    from agents.shaping import CoverageShaping

    venv = make_vec_env("SeifExplore-v1", n_envs=1, monitor_dir=str(tmp_path / "run"), wrapper_class=CoverageShaping)
    assert run_folder(VecNormalize(venv)) == tmp_path / "run"
    venv.close()
    assert run_folder(make_vec_env("SeifExplore-v1", n_envs=1)) is None


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"eval_freq": 0}, ValueError),
        ({"eval_freq": 1.5}, TypeError),
        ({"n_episodes": 0}, ValueError),
        ({"first_seed": -1}, ValueError),
        ({"save_path": 3}, TypeError),
        ({"env_kwargs": [1]}, TypeError),
    ],
)
def test_eval_callback_refuses_bad_arguments(kwargs, error):
    with pytest.raises(error, match=next(iter(kwargs))):
        MapErrorEvalCallback(**kwargs)


# -- checkpoints and their statistics ----------------------------------------------------------------
def test_vecnormalize_path_pairs_each_model_with_its_own_statistics(tmp_path):
    for name in (
        "rl_model_100_steps.zip",
        "rl_model_vecnormalize_100_steps.pkl",
        "rl_model_200_steps.zip",
        "vecnormalize.pkl",
        "model.zip",
        "SeifExplore-v1.zip",
    ):
        (tmp_path / name).touch()
    (tmp_path / "SeifExplore-v1").mkdir()
    (tmp_path / "SeifExplore-v1" / "vecnormalize.pkl").touch()
    assert vecnormalize_path(tmp_path / "rl_model_100_steps.zip") == tmp_path / "rl_model_vecnormalize_100_steps.pkl"
    # a checkpoint without its own statistics gets none, not the folder's later ones
    assert vecnormalize_path(tmp_path / "rl_model_200_steps.zip") is None
    assert vecnormalize_path(tmp_path / "model.zip") == tmp_path / "vecnormalize.pkl"
    (tmp_path / "vecnormalize.pkl").unlink()
    assert vecnormalize_path(tmp_path / "SeifExplore-v1.zip") == tmp_path / "SeifExplore-v1" / "vecnormalize.pkl"
    assert vecnormalize_path(tmp_path / "model.zip") is None
    with pytest.raises(ValueError, match="model_path"):
        vecnormalize_path(tmp_path / "model.pkl")
    with pytest.raises(TypeError, match="model_path"):
        vecnormalize_path(3)


def test_sb3_agent_loads_a_checkpoints_own_statistics(small_model, tmp_path):
    vec_normalize = small_model.get_vec_normalize_env()
    for steps, mean in ((100, 0.25), (200, -0.5)):
        vec_normalize.obs_rms["pose"].mean[:] = mean
        save_with_vecnormalize(small_model, tmp_path / f"rl_model_{steps}_steps.zip")
    vec_normalize.obs_rms["pose"].mean[:] = 9.0
    save_with_vecnormalize(small_model, tmp_path / "final" / "model.zip")
    env = gym.make("SeifExplore-v1", num_landmarks=10)
    for path, mean in (
        (tmp_path / "rl_model_100_steps.zip", 0.25),
        (tmp_path / "rl_model_200_steps.zip", -0.5),
        (tmp_path / "final" / "model.zip", 9.0),
    ):
        agent = SB3Agent(path, env=env)
        assert np.all(agent.vecnormalize.obs_rms["pose"].mean == mean), path


def test_an_error_during_training_keeps_its_traceback(tmp_path, monkeypatch):
    """Only prepare's errors become a one-line exit; numpy's LinAlgError (a ValueError) in learning propagates."""
    import agents.train as train_module

    class Failing:
        def learn(self, model):
            raise np.linalg.LinAlgError("Matrix is not positive definite.")

    monkeypatch.setattr(train_module, "prepare", lambda args, before_learn=None: (Failing(), None))
    with pytest.raises(np.linalg.LinAlgError, match="positive definite"):
        main([*SMALL, "--out", str(tmp_path)])


# -- SAC and RecurrentPPO ----------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(
    "algo, algorithm, tiny",
    [
        ("sac", "SAC", ["learning_starts=64", "batch_size=32", "buffer_size=1000"]),
        ("ppo_lstm", "RecurrentPPO", ["n_steps=64", "batch_size=64", "n_epochs=1"]),
    ],
)
def test_other_algorithms_train_from_their_config_and_evaluate(tmp_path, algo, algorithm, tiny):
    """sac.yml and ppo_lstm.yml train through agents.train; the evaluation harness loads and runs what they save."""
    from agents.evaluate import run_episode, sb3_algorithm

    env_kwargs = {"num_landmarks": 10, "max_episode_steps": 30}
    argv = ["--algo", algo, "--env", "SeifExploreLoopBudget-v1", "--n-envs", "2", "--seed", "1"]
    argv += ["--env-kwargs", json.dumps(env_kwargs), "--hyperparams", *tiny, "-n", "256"]
    argv += ["--eval-freq", "128", "--eval-episodes", "1", "--out", str(tmp_path), "--quiet"]
    assert main(argv) == 0
    best = tmp_path / "best_map_error" / "model.zip"
    assert sb3_algorithm(best).__name__ == algorithm
    entry = load(algo)["SeifExploreLoopBudget-v1"]
    assert entry["env_wrapper"] == load("ppo")["SeifExploreLoopBudget-v1"]["env_wrapper"]  # the task side of PPO's
    env = gym.make("SeifExploreLoopBudget-v1", **env_kwargs)
    agent = SB3Agent(best, env=env)
    assert type(agent.model).__name__ == algorithm and agent.vecnormalize is not None
    observation, _ = env.reset(seed=3)
    action, state = agent.predict(observation, episode_start=np.array([True]), deterministic=True)
    assert action.shape == (2,) and (state is not None) == (algo == "ppo_lstm")  # the LSTM's state comes back
    row, trace = run_episode(agent, env, seed=3)
    assert row["length"] == 30 and len(trace) == 31


def test_sb3_algorithm_refuses_what_is_not_a_model(tmp_path):
    from agents.evaluate import sb3_algorithm

    (tmp_path / "x.zip").write_bytes(b"not a zip")
    for path in (tmp_path / "x.zip", tmp_path / "missing.zip"):
        with pytest.raises(ValueError, match="path"):
            sb3_algorithm(path)


# -- --init-from -------------------------------------------------------------------------------------
def test_init_from_restores_weights_and_statistics(tmp_path):
    normalize = [
        "--hyperparams",
        "normalize=dict(norm_obs=True, norm_reward=True, norm_obs_keys=['pose', 'landmarks'])",
        "env_wrapper=null",
    ]
    first = tmp_path / "first"
    train(
        build_parser().parse_args(
            [
                *SMALL,
                "-n",
                "256",
                "--out",
                str(first),
                *normalize,
                "--eval-freq",
                "-1",
                "--checkpoint-freq",
                "256",
                "--quiet",
            ]
        )
    )
    checkpoint = first / "rl_model_256_steps.zip"
    stats = load_vecnormalize_stats(vecnormalize_path(checkpoint))
    assert stats.obs_rms["pose"].count > 1  # the statistics moved during the run
    experiment, model = prepare(
        build_parser().parse_args(
            [*SMALL, "--out", str(tmp_path / "second"), *normalize, "--init-from", str(checkpoint), "--quiet"]
        )
    )
    assert _same_weights(model.policy.state_dict(), _policy_state(checkpoint))
    restored = model.get_vec_normalize_env()
    for key in ("pose", "landmarks"):
        assert np.array_equal(restored.obs_rms[key].mean, stats.obs_rms[key].mean)
        assert np.array_equal(restored.obs_rms[key].var, stats.obs_rms[key].var)
    assert restored.ret_rms.count == stats.ret_rms.count and np.array_equal(restored.ret_rms.var, stats.ret_rms.var)
    model.get_env().close()
    # a run that does not normalise observations cannot start from weights that expect them normalised
    with pytest.raises(ValueError, match="normalises observations"):
        prepare(
            build_parser().parse_args(
                [
                    *SMALL,
                    "--out",
                    str(tmp_path / "third"),
                    "--hyperparams",
                    "env_wrapper=null",
                    "--init-from",
                    str(checkpoint),
                    "--quiet",
                ]
            )
        )
    with pytest.raises(FileNotFoundError, match="init-from"):
        prepare(
            build_parser().parse_args(
                [*SMALL, "--out", str(tmp_path / "fourth"), "--quiet", "--init-from", str(tmp_path / "missing.zip")]
            )
        )


def test_init_from_the_shipped_policy(tmp_path):
    """The shipped model (MultiInputPolicy + BeliefExtractor, no statistics) starts a run of the config's policy."""
    experiment, model = prepare(
        build_parser().parse_args(
            [
                *SMALL[:-4],
                "--env",
                "SeifExplore-v0",
                "--out",
                str(tmp_path),
                "--init-from",
                str(SHIPPED_POLICY),
                "--quiet",
            ]
        )
    )
    assert _same_weights(model.policy.state_dict(), _policy_state(SHIPPED_POLICY))
    model.get_env().close()


# -- the shipped policies ----------------------------------------------------------------------------
def final_map_errors(agent, seeds, env_id: str = "SeifExplore-v0") -> list[float]:
    """Each episode as the evaluation runs it (``agents.evaluate.run_episode``: a recurrent policy's state carried)."""
    from agents.evaluate import run_episode

    env = gym.make(env_id)
    try:
        return [run_episode(agent, env, seed)[0]["final_map_error"] for seed in seeds]
    finally:
        env.close()


@pytest.mark.slow
def test_shipped_policy_loads_and_beats_random_on_ten_seeds():
    assert SHIPPED_POLICY.exists(), f"the shipped policy {SHIPPED_POLICY} is missing"
    env = gym.make("SeifExplore-v0")
    policy = SB3Agent(SHIPPED_POLICY, env=env)
    seeds = range(2000, 2010)
    ppo = final_map_errors(policy, seeds)
    random = final_map_errors(make_agent("random", env, seed=0), seeds)
    assert np.mean(ppo) < np.mean(random)
    # and not by a hair: every episode of the policy ends below random's mean
    assert max(ppo) < np.mean(random), (ppo, random)


@pytest.mark.slow
@pytest.mark.parametrize("label", [label for label in SHIPPED_POLICIES if label != "ppo"])
def test_every_shipped_explorer_loads_and_beats_random_on_its_variant(label):
    """Each policy of ``agents.benchmark.SHIPPED_POLICIES`` (``ppo``: the test above), on five seeds of its task."""
    policy = SHIPPED_POLICIES[label]
    assert policy.path.exists(), f"the shipped policy {policy.path} is missing"
    env = gym.make(policy.task)  # the task it is shipped for (chosen on), which may not be the one it trained on
    agent = SB3Agent(policy.path, env=env)
    assert agent.vecnormalize is not None or vecnormalize_path(policy.path) is None  # its statistics, if any, load
    seeds = range(2000, 2005)
    learned = final_map_errors(agent, seeds, policy.task)
    random = final_map_errors(make_agent("random", env, seed=0), seeds, policy.task)
    assert max(learned) < np.mean(random), (learned, random)


@pytest.mark.parametrize("name", ["ppo.zip", "ppo_adversary_v1.zip"])
def test_shipped_models_match_the_env_spaces(name):
    env = gym.make("SeifExplore-v0")
    agent = SB3Agent(POLICIES / name, env=env)
    assert agent.model.observation_space == env.observation_space
    assert agent.model.action_space == env.action_space


def test_checkpoint_statistics_are_picklable_objects(small_model, tmp_path):
    """``load_vecnormalize_stats`` reads what ``VecNormalize.save`` wrote (no env needed)."""
    _, stats_path = save_with_vecnormalize(small_model, tmp_path / "x" / "model.zip")
    assert stats_path == tmp_path / "x" / "vecnormalize.pkl"
    with open(stats_path, "rb") as handle:
        direct = pickle.load(handle)
    assert np.array_equal(load_vecnormalize_stats(stats_path).obs_rms["pose"].mean, direct.obs_rms["pose"].mean)


def _single_envs(model) -> list:
    """The single envs under a model's vector env, whichever backend trains it."""
    venv = model.get_env()
    while not hasattr(venv, "envs"):
        venv = venv.venv
    return [getattr(env, "unwrapped", env) for env in venv.envs]


@pytest.mark.parametrize(
    "extra, native",
    [
        (["env_wrapper=null"], True),  # the native vector env
        (["env_wrapper=agents.shaping.CoverageShaping"], False),  # single envs under a wrapper
    ],
    ids=["native", "wrapped"],
)
def test_training_envs_leave_out_the_exact_nees_unless_asked(tmp_path, extra, native):
    """No training env factorises Omega for info['pose_nees']; --env-kwargs may ask for it; config.yml records neither."""
    for asked in (None, True):
        kwargs = {"num_landmarks": 10, "max_episode_steps": 60, **({} if asked is None else {"exact_pose_nees": asked})}
        argv = [*SMALL, *extra, "--out", str(tmp_path / f"run_{asked}"), "--quiet"]
        argv[argv.index("--env-kwargs") + 1] = json.dumps(kwargs)
        experiment, model = prepare(build_parser().parse_args(argv))
        assert experiment.uses_native() is native
        want = asked is True
        assert [env.exact_pose_nees for env in _single_envs(model)] == [want, want]
        (validation,) = [c for c in experiment.callbacks if isinstance(c, MapErrorEvalCallback)]
        assert validation.env_kwargs["exact_pose_nees"] is want
        model.get_env().close()
        config = (tmp_path / f"run_{asked}" / "SeifExplore-v1" / "config.yml").read_text()
        assert ("exact_pose_nees" in config) is (asked is not None)
