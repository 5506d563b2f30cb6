"""NativeVecEnv: the native vector env behind SB3's VecEnv interface, equal to SB3's DummyVecEnv."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

import seif_gym  # noqa: F401
from agents.sb3_vec_env import NativeVecEnv


@pytest.mark.slow
def test_native_vec_env_equals_dummy_vec_env():
    num_envs, limit = 3, 15
    native = NativeVecEnv("SeifExplore-v1", num_envs, seed=4, env_kwargs={"max_episode_steps": limit})
    reference = DummyVecEnv([lambda: gym.make("SeifExplore-v1", max_episode_steps=limit) for _ in range(num_envs)])
    reference.seed(4)
    obs, expected = native.reset(), reference.reset()
    for key in obs:
        np.testing.assert_array_equal(obs[key], expected[key])

    def assert_reset_infos_equal() -> None:
        for mine, theirs in zip(native.reset_infos, reference.reset_infos, strict=True):
            assert set(mine) == set(theirs) and mine["map_error"] == theirs["map_error"]
            np.testing.assert_array_equal(mine["true_pose"], theirs["true_pose"])

    assert_reset_infos_equal()
    rng = np.random.default_rng(0)
    truncations = 0
    for t in range(40):
        actions = rng.uniform(-1, 1, size=(num_envs, 2)).astype(np.float32)
        obs, rewards, dones, infos = native.step(actions)
        e_obs, e_rewards, e_dones, e_infos = reference.step(actions)
        for key in obs:
            np.testing.assert_array_equal(obs[key], e_obs[key], err_msg=f"step {t} {key}")
        np.testing.assert_array_equal(rewards, e_rewards)
        np.testing.assert_array_equal(dones, e_dones)
        for i in range(num_envs):
            assert set(infos[i]) == set(e_infos[i]), (t, i)
            np.testing.assert_array_equal(infos[i]["true_pose"], e_infos[i]["true_pose"])
            assert infos[i]["map_error"] == e_infos[i]["map_error"]
            if dones[i]:
                assert infos[i]["TimeLimit.truncated"] == e_infos[i]["TimeLimit.truncated"]
                truncations += infos[i]["TimeLimit.truncated"]
                for key in obs:
                    np.testing.assert_array_equal(infos[i]["terminal_observation"][key],
                                                  e_infos[i]["terminal_observation"][key])  # fmt: skip
        assert_reset_infos_equal()  # after an autoreset: the new episode's reset info
    assert truncations >= num_envs  # every sub-env went through its time limit and was reset
    assert native.get_attr("world_config")[0] == reference.get_attr("world_config")[0]
    native.close()
    reference.close()


@pytest.mark.slow
def test_ppo_trains_on_the_native_vec_env(tmp_path):
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    from agents.networks import BeliefExtractor

    venv = VecMonitor(NativeVecEnv("SeifExplore-v1", 4, seed=0, env_kwargs={"max_episode_steps": 40}))
    model = PPO("MultiInputPolicy", venv, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu",
                policy_kwargs={"features_extractor_class": BeliefExtractor})  # fmt: skip
    model.learn(total_timesteps=256)
    assert model.num_timesteps >= 256
    model.save(tmp_path / "model.zip")
    assert (tmp_path / "model.zip").stat().st_size > 0
    venv.close()


def test_native_vec_env_checks_arguments():
    with pytest.raises(ValueError, match="num_envs"):
        NativeVecEnv("SeifExplore-v1", 0)
