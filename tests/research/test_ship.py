"""research.ship: a chosen model shipped with its statistics and config, its optimizer's moments emptied."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

import seif_gym  # noqa: F401
from agents.checkpoints import save_with_vecnormalize, vecnormalize_path
from research import ship as ship_module
from research.ship import OPTIMIZER_ENTRY, empty_optimizer_moments, main, ship

TINY = {"num_landmarks": 10, "max_episode_steps": 20}


@pytest.fixture(scope="module")
def chosen(tmp_path_factory) -> Path:
    """A trained tiny model saved as research.select leaves it: RUN/selected/{model.zip, vecnormalize.pkl, selection.json}."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.networks import BeliefPolicy

    folder = tmp_path_factory.mktemp("run") / "selected"
    venv = VecNormalize(make_vec_env("SeifExplore-v1", n_envs=1, seed=0, env_kwargs=TINY), norm_obs=False)
    model = PPO(BeliefPolicy, venv, n_steps=32, batch_size=32, n_epochs=1, device="cpu", seed=0)
    model.learn(64)  # Adam has moments now
    save_with_vecnormalize(model, folder / "model.zip")
    (folder / "selection.json").write_text(json.dumps({"chosen": "run:best"}))
    (folder.parent / "config.yml").write_text("learning_rate: 0.0003\n")
    (folder.parent / "command.txt").write_text("python -m agents.train --seed 3 --timesteps 64")
    venv.close()
    return folder / "model.zip"


def _optimizer_state(archive: bytes) -> dict:
    with zipfile.ZipFile(io.BytesIO(archive)) as handle:
        return torch.load(io.BytesIO(handle.read(OPTIMIZER_ENTRY)), weights_only=True)


def test_shipping_empties_the_moments_keeps_the_weights_and_the_actions(chosen, tmp_path):
    policies = tmp_path / "policies"
    policies.mkdir()
    shipped = ship(chosen, "tiny_policy", config=chosen.parent.parent / "config.yml", policy_dir=policies)
    assert shipped == policies / "tiny_policy.zip"
    assert sorted(p.name for p in policies.iterdir()) == ["tiny_policy", "tiny_policy.zip"]  # no staging left
    folder = policies / "tiny_policy"
    assert sorted(p.name for p in folder.iterdir()) == ["command.txt", "config.yml", "selection.json",
                                                        "vecnormalize.pkl"]  # fmt: skip
    assert (folder / "command.txt").read_text() == "python -m agents.train --seed 3 --timesteps 64"
    assert vecnormalize_path(shipped) == folder / "vecnormalize.pkl"
    assert (folder / "vecnormalize.pkl").read_bytes() == (chosen.parent / "vecnormalize.pkl").read_bytes()
    assert (folder / "config.yml").read_text() == "learning_rate: 0.0003\n"

    original, stripped = _optimizer_state(chosen.read_bytes()), _optimizer_state(shipped.read_bytes())
    assert len(original["state"]) > 0 and stripped["state"] == {}
    assert stripped["param_groups"] == original["param_groups"]
    assert shipped.stat().st_size < chosen.stat().st_size
    with zipfile.ZipFile(chosen) as before, zipfile.ZipFile(shipped) as after:
        assert before.namelist() == after.namelist()
        for member in before.namelist():
            if member != OPTIMIZER_ENTRY:
                assert before.read(member) == after.read(member), member

    from stable_baselines3 import PPO

    first, second = PPO.load(chosen, device="cpu"), PPO.load(shipped, device="cpu")
    import gymnasium as gym

    env = gym.make("SeifExplore-v1", **TINY)
    observation, _ = env.reset(seed=3)
    for _ in range(10):  # the shipped policy acts as the chosen one along an episode
        action = first.predict(observation, deterministic=True)[0]
        np.testing.assert_array_equal(action, second.predict(observation, deterministic=True)[0])
        observation = env.step(action)[0]
    env.close()
    assert second.policy.optimizer.state_dict()["state"] == {}  # training on from it restarts Adam


def test_a_shipped_name_is_refused_unless_forced_and_bad_input_is_named(chosen, tmp_path):
    policies = tmp_path / "policies"
    policies.mkdir()
    config = chosen.parent.parent / "config.yml"
    ship(chosen, "tiny_policy", config=config, policy_dir=policies)
    before = {p.name: p.stat().st_mtime_ns for p in policies.rglob("*")}
    with pytest.raises(ValueError, match="name: 'tiny_policy' is shipped already"):
        ship(chosen, "tiny_policy", config=config, policy_dir=policies)
    with pytest.raises(ValueError, match="name: 'Tiny-Policy' is not lower case"):
        ship(chosen, "Tiny-Policy", config=config, policy_dir=policies)
    with pytest.raises(TypeError, match="name must be a str"):
        ship(chosen, 3, config=config, policy_dir=policies)
    with pytest.raises(ValueError, match="model: no file"):
        ship(chosen.with_name("nope.zip"), "other", config=config, policy_dir=policies)
    with pytest.raises(ValueError, match="config: no file"):
        ship(chosen, "other", config=tmp_path / "nope.yml", policy_dir=policies)
    with pytest.raises(TypeError, match="force must be a bool"):
        ship(chosen, "other", config=config, policy_dir=policies, force=1)
    with pytest.raises(ValueError, match="model: no VecNormalize statistics"):
        bare = tmp_path / "bare" / "model.zip"
        bare.parent.mkdir()
        bare.write_bytes(chosen.read_bytes())
        ship(bare, "other", config=config, policy_dir=policies)
    assert {p.name: p.stat().st_mtime_ns for p in policies.rglob("*")} == before
    assert ship(chosen, "tiny_policy", config=config, policy_dir=policies, force=True) == policies / "tiny_policy.zip"


def test_a_failure_midway_leaves_the_policies_as_they_were(chosen, tmp_path, monkeypatch):
    policies = tmp_path / "policies"
    policies.mkdir()
    config = chosen.parent.parent / "config.yml"
    ship(chosen, "tiny_policy", config=config, policy_dir=policies)
    before = {str(p.relative_to(policies)): p.read_bytes() for p in policies.rglob("*") if p.is_file()}
    copies = []

    def failing_copy(source, target):
        copies.append(target)
        if len(copies) == 2:  # the statistics are staged, the config fails
            raise OSError("disk full")
        return Path(target).write_bytes(Path(source).read_bytes())

    monkeypatch.setattr(ship_module.shutil, "copyfile", failing_copy)
    with pytest.raises(OSError, match="disk full"):
        ship(chosen, "tiny_policy", config=config, policy_dir=policies, force=True)
    with pytest.raises(OSError, match="disk full"):
        copies.clear()
        ship(chosen, "new_policy", config=config, policy_dir=policies)
    after = {str(p.relative_to(policies)): p.read_bytes() for p in policies.rglob("*") if p.is_file()}
    assert after == before
    monkeypatch.undo()
    replace = ship_module.os.replace

    def failing_replace(source, target):
        if Path(target) == policies / "tiny_policy.zip" and Path(source).parent.name != "replaced":
            raise OSError("rename failed")  # the new folder is in place, the new weights are not
        return replace(source, target)

    monkeypatch.setattr(ship_module.os, "replace", failing_replace)
    with pytest.raises(OSError, match="rename failed"):
        ship(chosen, "tiny_policy", config=config, policy_dir=policies, force=True)
    after = {str(p.relative_to(policies)): p.read_bytes() for p in policies.rglob("*") if p.is_file()}
    assert after == before and sorted(p.name for p in policies.iterdir()) == ["tiny_policy", "tiny_policy.zip"]


def test_empty_optimizer_moments_names_bad_archives():
    with pytest.raises(TypeError, match="model_zip must be bytes"):
        empty_optimizer_moments("model.zip")
    with pytest.raises(ValueError, match="model_zip: not a zip archive"):
        empty_optimizer_moments(b"not a zip")
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as handle:
        handle.writestr("data", "{}")
    with pytest.raises(ValueError, match="model_zip: no policy.optimizer.pth"):
        empty_optimizer_moments(buffer.getvalue())


def test_the_command_ships_and_reports_errors_as_usage_errors(chosen, tmp_path, capsys):
    policies = tmp_path / "policies"
    policies.mkdir()
    config = str(chosen.parent.parent / "config.yml")
    assert main([str(chosen), "tiny_policy", "--config", config, "--policy-dir", str(policies)]) == 0
    assert "shipped" in capsys.readouterr().out and (policies / "tiny_policy.zip").is_file()
    with pytest.raises(SystemExit) as exit_info:
        main([str(chosen), "tiny_policy", "--config", config, "--policy-dir", str(policies)])
    assert exit_info.value.code == 2 and "is shipped already" in capsys.readouterr().err


def test_for_acting_zeroes_the_value_function_and_acts_as_the_original(chosen, tmp_path):
    import gymnasium as gym
    from stable_baselines3 import PPO

    from research.ship import POLICY_ENTRY, for_acting

    original = chosen.read_bytes()
    acting = tmp_path / "acting.zip"
    acting.write_bytes(for_acting(original))
    with zipfile.ZipFile(acting) as handle:
        weights = torch.load(io.BytesIO(handle.read(POLICY_ENTRY)), weights_only=True)
    assert not weights["value_net.weight"].any() and weights["action_net.weight"].any()
    assert _optimizer_state(acting.read_bytes())["state"] == {}
    full, lean = PPO.load(chosen, device="cpu"), PPO.load(acting, device="cpu")
    env = gym.make("SeifExplore-v1", **TINY)
    observation, _ = env.reset(seed=5)
    for _ in range(10):
        action = full.predict(observation, deterministic=True)[0]
        np.testing.assert_array_equal(lean.predict(observation, deterministic=True)[0], action)
        observation = env.step(action)[0]
    with pytest.raises(ValueError, match="not a zip"):
        for_acting(b"not a zip")
