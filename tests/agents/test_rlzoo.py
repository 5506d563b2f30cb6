"""rl-zoo3 trains with the shipped config; its enjoy and record_video replay the run (subprocesses, as for users)."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rl_zoo3", reason="rl_zoo3 is in the train extra")

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "agents" / "hyperparams" / "ppo.yml"
ENV_ID = "SeifExplore-v1"
#: one rollout of the shipped entry (8 envs x 512 steps); 100-step episodes so that some end in it
TRAIN = [
    "--algo",
    "ppo",
    "--env",
    ENV_ID,
    "--gym-packages",
    "seif_gym",
    "--conf-file",
    str(CONFIG),
    "-n",
    "4096",
    "--seed",
    "3",
    "--eval-freq",
    "-1",
    "-tb",
    "tb",
    "--env-kwargs",
    "max_episode_steps:100",
]


def _run(args: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    result = subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f"{' '.join(args[:3])} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result


def tensorboard_tags(folder: Path) -> set[str]:
    """The scalar tags of every event file under ``folder``."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tags: set[str] = set()
    for events in folder.rglob("events.out.tfevents*"):
        accumulator = EventAccumulator(str(events))
        accumulator.Reload()
        tags.update(accumulator.Tags()["scalars"])
    return tags


@pytest.fixture(scope="module")
def zoo_run(tmp_path_factory) -> Path:
    """``python -m rl_zoo3.train`` with the shipped config, in a fresh folder; returns that folder."""
    folder = tmp_path_factory.mktemp("zoo")
    _run(["-m", "rl_zoo3.train", *TRAIN], folder)
    return folder


@pytest.mark.slow
def test_rl_zoo3_trains_with_the_shipped_config(zoo_run):
    run = zoo_run / "logs" / "ppo" / f"{ENV_ID}_1"
    assert (run / f"{ENV_ID}.zip").is_file() and (run / ENV_ID / "vecnormalize.pkl").is_file()
    # the config's callbacks ran inside rl-zoo3: validation on the plain env, the best model with its statistics
    assert (run / "best_map_error" / "model.zip").is_file() and (run / "best_map_error" / "vecnormalize.pkl").is_file()
    rows = list(csv.DictReader((run / "map_error_evaluations.csv").open()))
    assert len(rows) == 1 and int(rows[0]["timesteps"]) == 4096 and 0.0 < float(rows[0]["final_map_error"]) < 10.0
    # the task's metrics in TensorBoard, beside SB3's own
    tags = tensorboard_tags(zoo_run / "tb")
    for tag in (
        "rollout/ep_rew_mean",
        "rollout/final_map_error",
        "rollout/landmarks_mapped",
        "rollout/pose_rmse",
        "eval/final_map_error",
        "eval/landmarks_mapped",
        "eval/pose_rmse",
        "eval/best_final_map_error",
    ):
        assert tag in tags, (tag, sorted(tags))
    # the recipe came from the config: the belief policy, and the shaping as the env wrapper
    from stable_baselines3 import PPO

    from agents.networks import BeliefExtractor, BeliefPolicy

    model = PPO.load(run / f"{ENV_ID}.zip", device="cpu")
    assert isinstance(model.policy, BeliefPolicy) and isinstance(model.policy.features_extractor, BeliefExtractor)
    assert model.n_steps == 512 and model.n_envs == 8 and model.gamma == 0.995
    saved = (run / ENV_ID / "config.yml").read_text()
    assert "agents.shaping.CoverageShaping" in saved and "coef: 0.5" in saved


@pytest.mark.slow
def test_agents_train_trains_as_rl_zoo3_does(zoo_run, tmp_path):
    """The same config, seed and steps through agents.train: the same weights, bit for bit."""
    import torch
    from stable_baselines3 import PPO

    from agents.train import build_parser, train

    folder = train(
        build_parser().parse_args(
            [
                "--env",
                ENV_ID,
                "-n",
                "4096",
                "--seed",
                "3",
                "--out",
                str(tmp_path),
                "--env-kwargs",
                '{"max_episode_steps": 100}',
                "--quiet",
            ]
        )
    )
    ours = PPO.load(folder / f"{ENV_ID}.zip", device="cpu").policy.state_dict()
    theirs = PPO.load(zoo_run / "logs" / "ppo" / f"{ENV_ID}_1" / f"{ENV_ID}.zip", device="cpu").policy.state_dict()
    assert ours.keys() == theirs.keys()
    assert all(torch.equal(ours[k], theirs[k]) for k in ours)


@pytest.mark.slow
def test_rl_zoo3_enjoy_runs_the_trained_model(zoo_run):
    result = _run(
        [
            "-m",
            "rl_zoo3.enjoy",
            "--algo",
            "ppo",
            "--env",
            ENV_ID,
            "--gym-packages",
            "seif_gym",
            "-f",
            "logs",
            "--no-render",
            "-n",
            "120",
        ],
        zoo_run,
    )
    # the training's env_kwargs (args.yml) came with it: 100-step episodes
    assert "Episode Length 100" in result.stdout, result.stdout[-2000:]


@pytest.mark.slow
def test_record_video_of_the_trained_model(zoo_run, tmp_path):
    # rl_zoo3.record_video has no --gym-packages: agents.zoo registers the envs and runs it unchanged
    _run(
        [
            "-m",
            "agents.zoo",
            "record_video",
            "--algo",
            "ppo",
            "--env",
            ENV_ID,
            "-f",
            "logs",
            "-n",
            "20",
            "-o",
            str(tmp_path),
        ],
        zoo_run,
    )
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000, videos


@pytest.mark.slow
def test_rl_zoo3_tunes_with_the_shipped_config(tmp_path):
    """One Optuna trial: the sampler's policy_kwargs replace the config's, the belief extractor stays (the policy's)."""
    from stable_baselines3 import PPO

    from agents.networks import BeliefExtractor

    trials = tmp_path / "trials"
    args = [
        "-m",
        "rl_zoo3.train",
        "--algo",
        "ppo",
        "--env",
        ENV_ID,
        "--gym-packages",
        "seif_gym",
        "--conf-file",
        "agents.hyperparams.ppo",
        "-optimize",
        "--n-trials",
        "1",
        "--sampler",
        "random",
        "--pruner",
        "none",
        "-n",
        "512",
        "--n-evaluations",
        "1",
        "--eval-episodes",
        "1",
        "--seed",
        "0",
        "--no-optim-plots",
        "--hyperparams",
        "n_envs:2",
        "--env-kwargs",
        "max_episode_steps:50",
        "--optimization-log-path",
        str(trials),
    ]
    _run(args, tmp_path)
    (report,) = (tmp_path / "logs" / "ppo").glob("report_*.csv")
    rows = list(csv.DictReader(report.open()))
    assert len(rows) == 1 and rows[0]["state"] == "COMPLETE", rows
    model = PPO.load(trials / "trial_0" / "best_model.zip", device="cpu")
    assert isinstance(model.policy.features_extractor, BeliefExtractor)


def test_every_task_of_the_newest_version_has_a_ppo_entry():
    """agents.train reads the recipe by env id: each benchmark task (agents.benchmark.default_variants) has one."""
    from agents.benchmark import default_variants
    from agents.hyperparams import load

    entries = load("ppo")
    assert [env_id for env_id in default_variants() if env_id not in entries] == []
    for algo in ("sac", "ppo_lstm"):  # the loop budget, where the algorithms were compared, at every version since 0.2
        assert {"SeifExploreLoopBudget-v1", "SeifExploreLoopBudget-v2"} <= set(load(algo))


def test_the_config_loads_by_module_name_as_by_path():
    import yaml

    from agents.hyperparams import load
    from agents.hyperparams.ppo import hyperparams

    assert hyperparams == load("ppo") == yaml.safe_load(CONFIG.read_text())
    from agents.hyperparams.ppo_lstm import hyperparams as lstm_hyperparams
    from agents.hyperparams.sac import hyperparams as sac_hyperparams

    assert sac_hyperparams == load("sac") == yaml.safe_load((CONFIG.parent / "sac.yml").read_text())
    assert lstm_hyperparams == load("ppo_lstm") == yaml.safe_load((CONFIG.parent / "ppo_lstm.yml").read_text())
