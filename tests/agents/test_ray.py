"""RLlib training and the RLlib agent on a local two-node Ray cluster (loopback only).

Skipped only when ray is not installed (the README's test command installs
the ``ray`` extra, so CI runs these). Every Ray process of the cluster binds to
127.0.0.1; the cluster is shut down by its fixture, whether the tests pass or
fail.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

# before ray is imported: node addresses resolve to loopback, no auth token is written under ~/.ray
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

import gymnasium as gym
import numpy as np
import pytest

ray = pytest.importorskip("ray", reason="the optional 'ray' extra is not installed")
pytest.importorskip("ray.rllib", reason="the optional 'ray' extra is not installed")

import torch
from ray.cluster_utils import Cluster

import seif_gym  # noqa: F401
from agents import load_agent
from agents.evaluate import evaluate_agents
from agents.parallel import Executor
from agents.rllib_agent import BeliefRLModule, RLlibAgent, module_checkpoint
from agents.rllib_train import PROGRESS_COLUMNS, build_config, make_env, stop_algorithm, train
from agents.robustness import evaluate as robustness

LOOPBACK = "127.0.0.1"
#: One iteration's worth of steps: 2 runners x 2 envs x 16 steps.
TINY = {
    "num_env_runners": 2,
    "num_envs_per_env_runner": 2,
    "train_batch_size": 64,
    "minibatch_size": 32,
    "num_epochs": 1,
    "seed": 3,
}


@pytest.fixture(scope="module")
def cluster():
    """A two-node cluster on 127.0.0.1 (one CPU each), this process connected to it; always shut down.

    Its session files and its address file live in a private temporary
    directory (``RAY_TMPDIR``), not in ``/tmp/ray``: a ``ray.init()`` run
    elsewhere on the machine meanwhile does not find and join it.
    """
    previous = os.environ.get("RAY_TMPDIR")
    os.environ["RAY_TMPDIR"] = tempfile.mkdtemp(prefix="ray-test-", dir="/tmp")  # short: Unix socket paths
    nodes = None
    try:
        nodes = Cluster(
            initialize_head=True,
            head_node_args={"num_cpus": 1, "node_ip_address": LOOPBACK, "include_dashboard": False},
            shutdown_at_exit=True,
        )
        nodes.add_node(num_cpus=1, node_ip_address=LOOPBACK)
        ray.init(address=nodes.address, _node_ip_address=LOOPBACK, logging_level="ERROR", log_to_driver=False)
        yield nodes
    finally:
        ray.shutdown()
        if nodes is not None:
            nodes.shutdown()
        shutil.rmtree(os.environ["RAY_TMPDIR"], ignore_errors=True)
        if previous is None:
            os.environ.pop("RAY_TMPDIR")
        else:
            os.environ["RAY_TMPDIR"] = previous


@pytest.fixture(scope="module")
def trained(cluster, tmp_path_factory):
    """One training iteration on SeifExplore-v0 with one env runner on each node."""
    out = tmp_path_factory.mktemp("rllib")
    result = train("SeifExplore-v0", timesteps=1, out=out, quiet=True, **TINY)
    return result


def _module_weights(module: torch.nn.Module) -> dict[str, np.ndarray]:
    return {key: value.detach().cpu().numpy().copy() for key, value in module.state_dict().items()}


@pytest.mark.slow
def test_cluster_has_two_loopback_nodes(cluster):
    alive = [node for node in ray.nodes() if node["Alive"]]
    assert len(alive) == 2
    assert {node["NodeManagerAddress"] for node in alive} == {LOOPBACK}
    assert ray.cluster_resources()["CPU"] == 2


@pytest.mark.slow
def test_one_iteration_writes_checkpoint_and_progress(trained):
    assert trained.iterations == 1
    assert trained.env_steps >= TINY["train_batch_size"]
    with trained.progress.open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 1 and tuple(rows[0]) == PROGRESS_COLUMNS
    assert int(rows[0]["env_steps"]) == trained.env_steps
    assert module_checkpoint(trained.checkpoint).is_dir()
    assert (trained.checkpoint.parent / "config.json").is_file()


@pytest.mark.slow
def test_env_runners_sampled_on_both_nodes(trained):
    assert len(trained.env_runner_nodes) == 2
    assert len(set(trained.env_runner_nodes)) == 2, "the two env runners should sit on the two nodes"


@pytest.mark.slow
def test_checkpoint_restores(trained):
    """The algorithm checkpoint restores (here into a driver-only algorithm) and training goes on from it."""
    config = build_config("SeifExplore-v0", **{**TINY, "num_env_runners": 0, "num_envs_per_env_runner": 1})
    algo = config.build_algo()
    try:
        algo.restore_from_path(trained.checkpoint.resolve())
        assert algo.iteration == trained.iterations
        restored = _module_weights(algo.get_module())
        saved = _module_weights(RLlibAgent(trained.checkpoint).module)
        assert restored.keys() == saved.keys()
        for key in saved:
            np.testing.assert_array_equal(restored[key], saved[key], err_msg=key)
        result = algo.train()
        assert result["num_env_steps_sampled_lifetime"] >= trained.env_steps + TINY["train_batch_size"]
    finally:
        stop_algorithm(algo)


@pytest.mark.slow
def test_training_changed_the_policy(trained):
    """The checkpoint holds trained weights, not the initial ones (same seed, same spaces)."""
    agent = RLlibAgent(trained.checkpoint)
    env = gym.make("SeifExplore-v0")
    torch.manual_seed(TINY["seed"])
    fresh = BeliefRLModule(observation_space=env.observation_space, action_space=env.action_space, model_config={})
    changed = [
        key
        for key, value in _module_weights(agent.module).items()
        if not np.array_equal(value, _module_weights(fresh)[key])
    ]
    assert "pi_mean.weight" in changed and "vf_out.weight" in changed


@pytest.mark.slow
def test_rllib_agent_acts_deterministically(trained):
    env = gym.make("SeifExplore-v0", max_episode_steps=6)
    agent = load_agent(f"rllib:{trained.checkpoint}", env)
    assert isinstance(agent, RLlibAgent)
    obs, _ = env.reset(seed=11)
    observations, actions = [], []
    done = False
    while not done:
        action, state = agent.predict(obs, episode_start=not actions, deterministic=True)
        assert state is None
        assert action.shape == (2,) and action.dtype == np.float32
        assert np.all(np.abs(action) <= 1.0)
        observations.append(obs)
        actions.append(action)
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
    assert len(actions) == 6
    # the same observations give the same actions, one by one or as a batch
    again = RLlibAgent(trained.checkpoint, env)
    np.testing.assert_array_equal(np.stack([again.predict(o)[0] for o in observations]), np.stack(actions))
    batch = {key: np.stack([o[key] for o in observations]) for key in observations[0]}
    batched, _ = again.predict(batch)
    np.testing.assert_allclose(batched, np.stack(actions), rtol=1e-6, atol=1e-6)


@pytest.mark.slow
def test_evaluate_takes_an_rllib_spec(trained):
    from agents import evaluate

    spec = f"rllib:{trained.checkpoint}"
    rows, summary = evaluate.evaluate_agents(
        [spec], episodes=1, seed=5, env_id="SeifExplore-v0", env_kwargs={"max_episode_steps": 3}
    )
    assert len(rows) == 1 and rows[0]["length"] == 3
    assert [agent["spec"] for agent in summary["agents"].values()] == [spec]


# -- without a cluster ---------------------------------------------------------------------------------
def test_make_env_builds_single_native_and_sync_envs():
    single = make_env({"env_id": "SeifExplore-v1"})
    assert isinstance(single, gym.Env) and not isinstance(single, gym.vector.VectorEnv)
    spec = gym.spec("SeifExplore-v1")
    native = make_env({"env_id": "SeifExplore-v1", "num_envs": 2, "vectorize": "native"})
    sync = make_env({"env_id": "SeifExplore-v1", "num_envs": 2, "vectorize": "sync"})
    try:
        assert native.num_envs == sync.num_envs == 2
        assert isinstance(sync, gym.vector.SyncVectorEnv)
        if spec.vector_entry_point is not None:
            assert not isinstance(native, gym.vector.SyncVectorEnv)
        assert native.single_observation_space == single.observation_space
        obs, _ = native.reset(seed=[0, 1])
        assert obs["belief_map"].shape[0] == 2
    finally:
        single.close(), native.close(), sync.close()
    with pytest.raises(TypeError, match="env_id"):
        make_env({"env_kwargs": {}})
    with pytest.raises(ValueError, match="vectorize"):
        make_env({"env_id": "SeifExplore-v1", "num_envs": 2, "vectorize": "async"})


@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        ({"env_id": "NoSuchEnv-v0"}, ValueError, "env_id"),
        ({"num_env_runners": -1}, ValueError, "num_env_runners"),
        ({"num_envs_per_env_runner": 1.5}, TypeError, "num_envs_per_env_runner"),
        ({"train_batch_size": 32, "minibatch_size": 64}, ValueError, "minibatch_size"),
        ({"lr": 0.0}, ValueError, "lr"),
        ({"vectorize": "async"}, ValueError, "vectorize"),
        ({"env_kwargs": [1]}, TypeError, "env_kwargs"),
    ],
)
def test_build_config_rejects_bad_arguments(kwargs, error, name):
    with pytest.raises(error, match=name):
        build_config(**kwargs)


def test_train_rejects_bad_arguments_before_starting_ray(tmp_path):
    with pytest.raises(ValueError, match="timesteps"):
        train("SeifExplore-v0", timesteps=0, out=tmp_path)
    with pytest.raises(TypeError, match="out"):
        train("SeifExplore-v0", timesteps=10, out=3)
    with pytest.raises(ValueError, match="torch_threads"):
        train("SeifExplore-v0", timesteps=10, out=tmp_path, torch_threads=0)
    with pytest.raises(ValueError, match="num_env_runners"):
        train("SeifExplore-v0", timesteps=10, out=tmp_path, num_env_runners=-2)
    assert not list(tmp_path.iterdir())


def test_module_and_agent_reject_bad_input(tmp_path):
    env = gym.make("SeifExplore-v0")
    with pytest.raises(TypeError, match="observation_space"):
        BeliefRLModule(observation_space=env.observation_space["pose"], action_space=env.action_space)
    with pytest.raises(TypeError, match="action_space"):
        BeliefRLModule(observation_space=env.observation_space, action_space=gym.spaces.Discrete(3))
    with pytest.raises(ValueError, match="pi_hiddens"):
        BeliefRLModule(
            observation_space=env.observation_space, action_space=env.action_space, model_config={"pi_hiddens": [0]}
        )
    with pytest.raises(FileNotFoundError, match="path"):
        RLlibAgent(tmp_path)
    with pytest.raises(TypeError, match="path"):
        RLlibAgent(42)


def test_module_reads_uint8_and_float_maps_alike():
    env = gym.make("SeifExplore-v0")
    torch.manual_seed(0)
    module = BeliefRLModule(observation_space=env.observation_space, action_space=env.action_space)
    obs, _ = env.reset(seed=2)
    as_uint8 = {key: torch.as_tensor(value)[None] for key, value in obs.items()}
    as_float = {**as_uint8, "belief_map": as_uint8["belief_map"].to(torch.float32)}
    assert as_uint8["belief_map"].dtype == torch.uint8 and int(as_uint8["belief_map"].max()) > 1
    np.testing.assert_array_equal(module.deterministic_action(as_uint8), module.deterministic_action(as_float))
    # the CNN sees the map in [0, 1]
    seen = []
    module.cnn.register_forward_pre_hook(lambda layer, args: seen.append(args[0].detach().clone()))
    module.deterministic_action(as_uint8)
    torch.testing.assert_close(seen[0], as_float["belief_map"] / 255.0)
    values = module.compute_values({"obs": as_uint8})
    assert values.shape == (1,)


@pytest.mark.slow
def test_seif_gym_and_agents_import_without_ray():
    code = (
        "import sys; import seif_gym, agents, agents.evaluate, agents.baselines; "
        "assert 'ray' not in sys.modules, sorted(m for m in sys.modules if m.startswith('ray'))"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[2])


# -- the harnesses on the cluster (agents.parallel) ----------------------------------------------------
#: Measured times: the only columns allowed to differ from a serial run's.
TIMED_ROWS = ("decision_time_ms", "us_per_step_mean", "us_per_step_median")


def _untimed(rows):
    return [{key: value for key, value in row.items() if key not in TIMED_ROWS} for row in rows]


def _alive_nodes():
    return {node["NodeID"] for node in ray.nodes() if node["Alive"]}


@pytest.mark.slow
def test_robustness_harness_on_two_nodes_equals_serial(cluster):
    arguments = (["random", "frontier"], ["uniform"], [0, 1, 2, 3], 12, ["seif-k4", "ekf"])
    serial_rows, serial_series = robustness(*arguments, env_id="SeifExplore-v1")
    executor = Executor(ray=cluster.address)
    rows, series = robustness(*arguments, env_id="SeifExplore-v1", executor=executor)
    assert len(rows) == 2 * 4 * 2 and _untimed(rows) == _untimed(serial_rows)
    for ours, theirs in zip(series, serial_series):
        for key in ours:
            if key != "step_seconds":
                np.testing.assert_array_equal(ours[key], theirs[key])
    assert executor.slots() == 2 and len(executor.placements) == 8  # one seed per task: 2 policies x 4 seeds
    assert set(executor.placements) == _alive_nodes(), "the tasks should run on both nodes"


@pytest.mark.slow
def test_evaluate_agents_on_two_nodes_equals_serial(cluster):
    kwargs = {"max_episode_steps": 15}
    serial_rows, serial_summary = evaluate_agents(["random", "revisit"], 4, 20, "SeifExplore-v1", kwargs)
    executor = Executor(ray=cluster.address)
    rows, summary = evaluate_agents(["random", "revisit"], 4, 20, "SeifExplore-v1", kwargs, executor=executor)
    assert _untimed(rows) == _untimed(serial_rows)
    assert summary["paired"] == serial_summary["paired"]
    assert len(executor.placements) == 1 + 4  # random: one task (its generator runs on); revisit: one per seed
    assert set(executor.placements) <= _alive_nodes()


@pytest.mark.slow
def test_robustness_command_with_ray_address(cluster, tmp_path):
    """``--ray ADDRESS`` from another process: it joins the cluster as a driver and leaves it running."""
    command = [sys.executable, "-m", "agents.robustness", "--agents", "frontier", "--episodes", "2", "--steps", "8"]
    command += ["--filters", "seif-k4", "--env", "SeifExplore-v1", "--out", str(tmp_path), "--quiet"]
    done = subprocess.run([*command, "--ray", cluster.address], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    config = json.loads((tmp_path / "config.json").read_text())
    assert config["executor"]["backend"] == "ray" and config["executor"]["ray"] == cluster.address
    assert sum(config["executor"]["tasks_per_node"].values()) == 2
    assert set(config["executor"]["tasks_per_node"]) <= _alive_nodes()
    assert len(_alive_nodes()) == 2  # the cluster is still up for the other tests
