r"""Train PPO on ``SeifExplore`` with RLlib (new API stack): ``python -m agents.rllib_train``.

.. code-block:: bash

    python -m agents.rllib_train --env SeifExplore-v2 --timesteps 200000 --out runs/rllib \
        [--num-env-runners 2] [--num-envs-per-env-runner 8] [--address auto|HOST:PORT] [--seed 0] [--quiet]

Needs the optional ``ray`` extra (``pip install -e ".[train,ray]"``).

The policy is :class:`agents.rllib_agent.BeliefRLModule` (a small CNN on the
belief map divided by 255, an MLP on the vector entries, concatenated; tanh
MLP heads for a diagonal Gaussian policy and the value). Each env runner steps
``--num-envs-per-env-runner`` envs at once: through the env id's native vector
env (``gym.make_vec(id, vectorization_mode="vector_entry_point")``,
``seif_gym.envs.vector``) where the id registers one, else a
``SyncVectorEnv`` (``--vectorize sync`` forces the latter).

Without ``--address`` a local Ray instance is started for the run and
stopped after it; every Ray process of it binds to 127.0.0.1. With
``--address auto`` (or ``HOST:PORT``) the run joins a running cluster (see
``docs/training/ray.md``: ``ray start --head`` on one machine, ``ray start
--address=HEAD:6379`` on the others; every node needs this project installed
with the ``ray`` extra, as the env runners build the envs there).

Written to ``--out``:

``checkpoint/``
    The algorithm checkpoint (RLlib's ``Algorithm.save_to_path``), rewritten
    every ``--checkpoint-every`` iterations and after the last;
    ``Algorithm.from_checkpoint`` resumes it and ``RLlibAgent`` /
    ``python -m agents.evaluate --agents rllib:OUT/checkpoint`` evaluates it.
``progress.csv``
    One row per training iteration, columns :data:`PROGRESS_COLUMNS` (the
    last two: the remote env runners healthy after the iteration, and how
    many times one was restarted so far).
``config.json``
    The command's arguments and the algorithm's configuration (as JSON as
    far as it goes; anything else as its ``repr``).

A line per iteration is printed (nothing with ``--quiet``).

From Python: :func:`train` (it can also join a Ray instance that is already
initialised, and leaves it running then).
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import math
import os
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym

from agents.cli import json_object
from seif_gym import LATEST_ID

__all__ = [
    "PROGRESS_COLUMNS",
    "RLLIB_ENV_NAME",
    "TrainResult",
    "build_config",
    "main",
    "make_env",
    "stop_algorithm",
    "train",
]

#: Columns of ``progress.csv``.
PROGRESS_COLUMNS: tuple[str, ...] = (
    "iteration",
    "env_steps",
    "episodes",
    "episode_return_mean",
    "episode_len_mean",
    "entropy",
    "vf_explained_var",
    "iteration_s",
    "steps_per_s",
    "time_s",
    "healthy_env_runners",
    "env_runner_restarts",
)

#: Name under which :func:`make_env` is registered with Ray Tune's env registry.
RLLIB_ENV_NAME = "seif_gym"
#: Environment variables set (if unset) before a local Ray instance starts: loopback only, no auth token file.
LOCAL_RAY_ENV: dict[str, str] = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}


# -- the env -----------------------------------------------------------------------------------------
def make_env(config: Mapping[str, Any]) -> gym.Env | gym.vector.VectorEnv:
    """Build the env of an RLlib env runner (RLlib calls this on every runner, local or remote).

    Parameters
    ----------
    config : mapping
        RLlib's ``EnvContext``: ``env_id`` (a registered ``SeifExplore`` id),
        ``env_kwargs`` (a dict for ``gym.make``), ``vectorize``
        (``"native"`` or ``"sync"``); RLlib adds ``num_envs`` when it asks
        for a vector env.

    Returns
    -------
    gymnasium.Env or gymnasium.vector.VectorEnv
        A single env without ``num_envs``, else ``num_envs`` of them in one
        vector env: the id's native one (``vector_entry_point``) if it has
        one and ``vectorize == "native"``, else a ``SyncVectorEnv``.
    """
    import seif_gym  # noqa: F401  (registers the ids in this process: a remote runner has not imported it)

    if not isinstance(config, Mapping):
        raise TypeError(f"config must be a mapping, got {type(config).__name__}")
    env_id = config.get("env_id")
    if not isinstance(env_id, str):
        raise TypeError(f"config['env_id'] must be an env id (a str), got {env_id!r}")
    env_kwargs = dict(config.get("env_kwargs") or {})
    num_envs = config.get("num_envs")
    if num_envs is None:
        return gym.make(env_id, **env_kwargs)
    vectorize = config.get("vectorize", "native")
    if vectorize not in ("native", "sync"):
        raise ValueError(f"config['vectorize'] must be 'native' or 'sync', got {vectorize!r}")
    native = vectorize == "native" and gym.spec(env_id).vector_entry_point is not None
    mode = "vector_entry_point" if native else "sync"
    return gym.make_vec(env_id, num_envs=int(num_envs), vectorization_mode=mode, **env_kwargs)


# -- the algorithm -------------------------------------------------------------------------------------
def build_config(
    env_id: str = LATEST_ID,
    *,
    env_kwargs: Mapping[str, Any] | None = None,
    num_env_runners: int = 1,
    num_envs_per_env_runner: int = 8,
    vectorize: str = "native",
    train_batch_size: int = 4096,
    minibatch_size: int = 1024,
    num_epochs: int = 5,
    lr: float = 3e-4,
    gamma: float = 0.995,
    lambda_: float = 0.95,
    entropy_coeff: float = 0.001,
    model_config: Mapping[str, Any] | None = None,
    seed: int = 0,
) -> Any:
    """The ``PPOConfig`` of a run (RLlib's new API stack, :class:`~agents.rllib_agent.BeliefRLModule`).

    Parameters
    ----------
    env_id : str
        A registered ``SeifExplore`` id.
    env_kwargs : mapping, optional
        Passed to ``gym.make`` / ``gym.make_vec``.
    num_env_runners : int
        Remote env runners (0: sample in the driver process).
    num_envs_per_env_runner : int
        Envs each runner steps at once (one vector env).
    vectorize : {"native", "sync"}
        See :func:`make_env`.
    train_batch_size, minibatch_size, num_epochs : int
        Env steps per iteration, per SGD minibatch, and passes over each batch.
    lr, gamma, lambda_, entropy_coeff : float
        PPO's learning rate, discount, GAE lambda and entropy coefficient.
    model_config : mapping, optional
        :class:`~agents.rllib_agent.BeliefRLModule`'s ``model_config``.
    seed : int
        Seeds the env runners' env resets and the network's initialisation.

    Returns
    -------
    ray.rllib.algorithms.ppo.PPOConfig
        With ``restart_failed_env_runners``: an env runner that dies (its
        process killed, its node lost) is restarted and rejoins the sampling.

    Raises
    ------
    ValueError, TypeError
        An argument out of range or of the wrong type (named in the message).
    """
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec
    from ray.tune.registry import register_env

    import seif_gym  # noqa: F401
    from agents.rllib_agent import BeliefRLModule

    if not isinstance(env_id, str) or env_id not in gym.registry:
        raise ValueError(f"env_id must be a registered env id, got {env_id!r}")
    if env_kwargs is not None and not isinstance(env_kwargs, Mapping):
        raise TypeError(f"env_kwargs must be a mapping, got {type(env_kwargs).__name__}")
    if vectorize not in ("native", "sync"):
        raise ValueError(f"vectorize must be 'native' or 'sync', got {vectorize!r}")
    for name, value, low in (
        ("num_env_runners", num_env_runners, 0),
        ("num_envs_per_env_runner", num_envs_per_env_runner, 1),
        ("train_batch_size", train_batch_size, 1),
        ("minibatch_size", minibatch_size, 1),
        ("num_epochs", num_epochs, 1),
        ("seed", seed, 0),
    ):
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"{name} must be an int, got {value!r}")
        if value < low:
            raise ValueError(f"{name} must be >= {low}, got {value}")
    if minibatch_size > train_batch_size:
        raise ValueError(f"minibatch_size ({minibatch_size}) must not exceed train_batch_size ({train_batch_size})")
    for name, number in (("lr", lr), ("gamma", gamma), ("lambda_", lambda_), ("entropy_coeff", entropy_coeff)):
        if isinstance(number, bool) or not isinstance(number, (int, float)) or not math.isfinite(number):
            raise TypeError(f"{name} must be a finite number, got {number!r}")
    if lr <= 0:
        raise ValueError(f"lr must be > 0, got {lr}")
    if not 0 < gamma <= 1 or not 0 <= lambda_ <= 1:
        raise ValueError(f"gamma must be in (0, 1] and lambda_ in [0, 1], got {gamma}, {lambda_}")
    if entropy_coeff < 0:
        raise ValueError(f"entropy_coeff must be >= 0, got {entropy_coeff}")
    if model_config is not None and not isinstance(model_config, Mapping):
        raise TypeError(f"model_config must be a mapping, got {type(model_config).__name__}")

    # each runner's share of a batch, in steps per env: the batch is collected in one round
    fragment = max(1, math.ceil(train_batch_size / (max(num_env_runners, 1) * num_envs_per_env_runner)))
    # by name: remote runners look the creator up in the cluster's registry
    register_env(RLLIB_ENV_NAME, make_env)
    return (
        PPOConfig()
        .environment(
            env=RLLIB_ENV_NAME,
            env_config={"env_id": env_id, "env_kwargs": dict(env_kwargs or {}), "vectorize": vectorize},
        )
        .env_runners(
            num_env_runners=num_env_runners,
            num_envs_per_env_runner=num_envs_per_env_runner,
            gym_env_vectorize_mode="vector_entry_point",
            rollout_fragment_length=fragment,
        )
        .learners(num_learners=0)
        .training(
            train_batch_size_per_learner=train_batch_size,
            minibatch_size=minibatch_size,
            num_epochs=num_epochs,
            lr=lr,
            gamma=gamma,
            lambda_=lambda_,
            clip_param=0.2,
            vf_clip_param=float("inf"),
            entropy_coeff=entropy_coeff,
            grad_clip=0.5,
            use_kl_loss=False,
        )
        .rl_module(rl_module_spec=RLModuleSpec(module_class=BeliefRLModule, model_config=dict(model_config or {})))
        # an env runner whose process or node dies is started again by Ray (the actor's max_restarts) and brought
        # back in by RLlib at the next iteration with the learner's weights; the others sample meanwhile
        .fault_tolerance(restart_failed_env_runners=True)
        .debugging(seed=seed, log_level="ERROR")
    )


# -- training ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrainResult:
    """What :func:`train` did.

    Attributes
    ----------
    checkpoint : Path
        The algorithm checkpoint (``OUT/checkpoint``).
    iterations : int
        Training iterations run.
    env_steps : int
        Env steps sampled.
    progress : Path
        ``OUT/progress.csv``.
    env_runner_nodes : tuple of str
        The Ray node id of each remote env runner (empty without remote
        runners): where the sampling ran.
    """

    checkpoint: Path
    iterations: int
    env_steps: int
    progress: Path
    env_runner_nodes: tuple[str, ...] = ()


def _get(result: Mapping[str, Any], *keys: str, default: float = math.nan) -> Any:
    """``result[k0][k1]...`` or ``default`` where a key is missing."""
    value: Any = result
    for key in keys:
        if not isinstance(value, Mapping) or key not in value:
            return default
        value = value[key]
    return value


def _row(
    iteration: int, result: Mapping[str, Any], previous_steps: int, iteration_s: float, started: float
) -> dict[str, Any]:
    """One ``progress.csv`` row from an RLlib result dict (episode statistics are RLlib's running means)."""
    steps = int(_get(result, "num_env_steps_sampled_lifetime", default=0) or 0)
    return {
        "iteration": iteration,
        "env_steps": steps,
        "episodes": int(_get(result, "env_runners", "num_episodes_lifetime", default=0) or 0),
        "episode_return_mean": _get(result, "env_runners", "episode_return_mean"),
        "episode_len_mean": _get(result, "env_runners", "episode_len_mean"),
        "entropy": _get(result, "learners", "default_policy", "entropy"),
        "vf_explained_var": _get(result, "learners", "default_policy", "vf_explained_var"),
        "iteration_s": iteration_s,
        "steps_per_s": (steps - previous_steps) / iteration_s if iteration_s > 0 else math.nan,
        "time_s": time.perf_counter() - started,
        "healthy_env_runners": int(_get(result, "fault_tolerance", "num_healthy_workers", default=0) or 0),
        "env_runner_restarts": int(_get(result, "fault_tolerance", "num_remote_worker_restarts", default=0) or 0),
    }


def _fmt(value: float, width: int, digits: int) -> str:
    """``value`` right-aligned, ``-`` where RLlib had nothing (no episode ended in the iteration)."""
    return (
        f"{value:{width}.{digits}f}" if isinstance(value, (int, float)) and math.isfinite(value) else "-".rjust(width)
    )


def _jsonable(value: Any) -> Any:
    """``value`` as JSON where it can be, else its ``repr``."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else repr(value)
    return repr(value)


def stop_algorithm(algo: Any) -> None:
    """``algo.stop()``, and remove the empty directory RLlib's ``Trainable`` made for it under ``~/ray_results``."""
    logdir = getattr(algo, "logdir", None)
    algo.stop()
    if logdir and os.path.isdir(logdir) and not os.listdir(logdir):
        os.rmdir(logdir)


def _init_ray(address: str | None, num_cpus: int | None, quiet: bool) -> bool:
    """Connect to Ray (start a loopback-only local instance without ``address``); ``True`` if started here."""
    if address is None:
        for key, value in LOCAL_RAY_ENV.items():
            os.environ.setdefault(key, value)
    import ray

    if ray.is_initialized():
        return False
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": not quiet, "logging_level": "ERROR"}
    if address is None:
        # address="local": a new instance even where `ray start` has recorded a cluster in /tmp/ray
        ray.init(address="local", num_cpus=num_cpus, _node_ip_address="127.0.0.1", **kwargs)
    else:
        ray.init(address=address, **kwargs)
    return True


def train(
    env_id: str = LATEST_ID,
    *,
    timesteps: int,
    out: str | os.PathLike,
    address: str | None = None,
    num_cpus: int | None = None,
    checkpoint_every: int = 10,
    torch_threads: int | None = 1,
    quiet: bool = False,
    argv: Sequence[str] | None = None,
    **config_kwargs: Any,
) -> TrainResult:
    """Train until ``timesteps`` env steps are sampled; checkpoint and log to ``out``.

    Parameters
    ----------
    env_id : str
        A registered ``SeifExplore`` id.
    timesteps : int
        Env steps to sample (the last iteration completes, so a little more).
    out : str or Path
        Output directory (created).
    address : str or None
        A Ray cluster to join (``"auto"`` or ``HOST:PORT``); ``None`` starts
        a local instance on 127.0.0.1 and stops it at the end. If Ray is
        already initialised in this process, that instance is used and left
        running.
    num_cpus : int or None
        CPUs of the local instance (``None``: all); ignored with ``address``.
    checkpoint_every : int
        Rewrite the checkpoint every this many iterations (and after the last).
    torch_threads : int or None
        Torch's intra-op threads in this process, where the learner runs,
        during the run (``None``: torch's default, one per core). One thread
        by default: a learner sharing its cores with the env runners loses
        more to contention than it gains (``docs/performance_notes.md``);
        raise it on a driver with idle cores.
    quiet : bool
        Print nothing.
    argv : sequence of str, optional
        The command line, recorded in ``config.json``.
    **config_kwargs
        Keyword arguments of :func:`build_config`.

    Returns
    -------
    TrainResult

    Raises
    ------
    TypeError
        If ``out`` is not a path.
    ValueError
        If a count is not a positive int, ``address`` is empty, or :func:`build_config` refuses
        its arguments (all before Ray starts).
    """
    if isinstance(timesteps, bool) or not isinstance(timesteps, int) or timesteps < 1:
        raise ValueError(f"timesteps must be a positive int, got {timesteps!r}")
    if isinstance(checkpoint_every, bool) or not isinstance(checkpoint_every, int) or checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be a positive int, got {checkpoint_every!r}")
    if not isinstance(out, (str, os.PathLike)):
        raise TypeError(f"out must be a str or path, got {type(out).__name__}")
    if address is not None and (not isinstance(address, str) or not address):
        raise ValueError(f"address must be 'auto', HOST:PORT or None, got {address!r}")
    if num_cpus is not None and (isinstance(num_cpus, bool) or not isinstance(num_cpus, int) or num_cpus < 1):
        raise ValueError(f"num_cpus must be a positive int or None, got {num_cpus!r}")
    if torch_threads is not None and (
        isinstance(torch_threads, bool) or not isinstance(torch_threads, int) or torch_threads < 1
    ):
        raise ValueError(f"torch_threads must be a positive int or None, got {torch_threads!r}")
    config = build_config(env_id, **config_kwargs)  # validates before anything starts
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / "checkpoint"
    progress = out / "progress.csv"
    (out / "config.json").write_text(
        json.dumps(
            {
                "argv": list(argv) if argv is not None else None,
                "env_id": env_id,
                "timesteps": timesteps,
                "address": address,
                "torch_threads": torch_threads,
                "build_config": _jsonable(config_kwargs),
                "algorithm": _jsonable(config.to_dict()),
            },
            indent=2,
        )
    )

    import ray
    import torch

    if quiet:
        logging.getLogger("ray").setLevel(logging.ERROR)
        logging.getLogger("ray.rllib").setLevel(logging.ERROR)
    threads = torch.get_num_threads()
    if torch_threads is not None:
        torch.set_num_threads(torch_threads)
    started_ray = False
    algo = None
    try:
        started_ray = _init_ray(address, num_cpus, quiet)
        algo = config.build_algo()
        nodes = tuple(
            algo.env_runner_group.foreach_env_runner(
                lambda runner: ray.get_runtime_context().get_node_id(), local_env_runner=False
            )
            if config.num_env_runners > 0
            else ()
        )
        if not quiet:
            where = f"{len(nodes)} env runners on {len(set(nodes))} node(s)" if nodes else "sampling in this process"
            print(f"{env_id}: {where}, {config.num_envs_per_env_runner} envs each", flush=True)
        started = time.perf_counter()
        iteration, steps = 0, 0
        with progress.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=PROGRESS_COLUMNS)
            writer.writeheader()
            while steps < timesteps:
                tick = time.perf_counter()
                result = algo.train()
                iteration += 1
                row = _row(iteration, result, steps, time.perf_counter() - tick, started)
                steps = row["env_steps"]
                writer.writerow(row)
                handle.flush()
                if iteration % checkpoint_every == 0:
                    algo.save_to_path(checkpoint.resolve())
                if not quiet:
                    print(
                        f"iter {iteration:4d}  steps {steps:>9d}/{timesteps}  "
                        f"return {_fmt(row['episode_return_mean'], 8, 3)}  len {_fmt(row['episode_len_mean'], 6, 1)}  "
                        f"{row['steps_per_s']:6.0f} steps/s  {row['time_s']:7.1f} s",
                        flush=True,
                    )
        algo.save_to_path(checkpoint.resolve())
        if not quiet:
            print(f"checkpoint: {checkpoint}", flush=True)
        return TrainResult(
            checkpoint=checkpoint, iterations=iteration, env_steps=steps, progress=progress, env_runner_nodes=nodes
        )
    finally:
        if algo is not None:
            stop_algorithm(algo)
        if started_ray:
            ray.shutdown()
        torch.set_num_threads(threads)


# -- command line --------------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m agents.rllib_train", description="Train PPO on a SeifExplore env with RLlib (new API stack)."
    )
    parser.add_argument("--env", default=LATEST_ID, help="registered env id (default %(default)s)")
    parser.add_argument("--env-kwargs", type=json_object, default="{}", help="JSON object passed to gym.make")
    parser.add_argument("--timesteps", type=int, required=True, help="env steps to sample")
    parser.add_argument("--out", required=True, help="output directory (checkpoint, progress.csv, config.json)")
    parser.add_argument("--num-env-runners", type=int, default=1, help="remote env runners (0: sample in the driver)")
    parser.add_argument("--num-envs-per-env-runner", type=int, default=8, help="envs per runner (one vector env)")
    parser.add_argument(
        "--vectorize",
        choices=("native", "sync"),
        default="native",
        help="native: the id's compiled vector env where it has one; sync: SyncVectorEnv",
    )
    parser.add_argument("--address", default=None, help="join a Ray cluster: 'auto' or HOST:PORT (default: local)")
    parser.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")
    parser.add_argument("--train-batch-size", type=int, default=4096, help="env steps per iteration")
    parser.add_argument("--minibatch-size", type=int, default=1024)
    parser.add_argument("--num-epochs", type=int, default=5)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--gamma", type=float, default=0.995)
    parser.add_argument("--entropy-coeff", type=float, default=0.001)
    parser.add_argument(
        "--model-config", type=json_object, default="{}", help="JSON object: BeliefRLModule's model_config"
    )
    parser.add_argument("--checkpoint-every", type=int, default=10, help="iterations between checkpoints")
    parser.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="torch threads of the learner in this process (default 1; 0: torch's default)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quiet", action="store_true", help="print nothing")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = _parser().parse_args(argv)
    result = train(
        args.env,
        timesteps=args.timesteps,
        out=args.out,
        address=args.address,
        num_cpus=args.num_cpus,
        checkpoint_every=args.checkpoint_every,
        torch_threads=args.torch_threads or None,
        quiet=args.quiet,
        argv=sys.argv if argv is None else list(argv),
        env_kwargs=args.env_kwargs,
        num_env_runners=args.num_env_runners,
        num_envs_per_env_runner=args.num_envs_per_env_runner,
        vectorize=args.vectorize,
        train_batch_size=args.train_batch_size,
        minibatch_size=args.minibatch_size,
        num_epochs=args.num_epochs,
        lr=args.lr,
        gamma=args.gamma,
        entropy_coeff=args.entropy_coeff,
        model_config=args.model_config,
        seed=args.seed,
    )
    if not args.quiet:
        print(
            f"{result.iterations} iterations, {result.env_steps} env steps; evaluate with "
            f"python -m agents.evaluate --agents rllib:{result.checkpoint}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
