"""Train an exploration policy on a SeifExplore env with stable-baselines3.

Usage::

    python -m agents.train --algo ppo --env SeifExplore-v1 --timesteps 2000000 --out runs/ppo
    python -m agents.train --env SeifExplore-v1 --wrapper agents.adversary:SeifVsEkfReward --out runs/adversary

Hyperparameters come from ``agents/hyperparams/<algo>.yml`` (rl-zoo3's
format: one entry per env id with ``n_envs``, ``normalize``,
``policy_kwargs`` and the algorithm's keyword arguments); ``--env-kwargs``
(JSON) and ``--hyperparams key=value`` override them. ``--wrapper module:Class``
(with ``--wrapper-kwargs`` JSON) wraps every env, for training and evaluation
(e.g. the adversarial reward of :mod:`agents.adversary`). The run writes to
``--out``:

=========================  =====================================================
``model.zip``              the final model
``vecnormalize.pkl``       reward/observation normalisation statistics (if used)
``best/best_model.zip``    the best model of the ``EvalCallback``
``checkpoints/``           periodic checkpoints
``tb/``                    TensorBoard logs (``tensorboard --logdir OUT/tb``)
``config.json``            the exact hyperparameters, env kwargs and seed used
=========================  =====================================================
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import yaml

import seif_gym  # noqa: F401  (registers the envs)

HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"
ALGOS = ("ppo", "sac")

#: Keys of a hyperparameter entry that are not keyword arguments of the algorithm.
_RUN_KEYS = ("n_envs", "n_timesteps", "policy", "normalize", "env_kwargs", "policy_kwargs")


@dataclass(frozen=True)
class TrainConfig:
    """Everything one training run needs, resolved from YAML and the command line."""

    algo: str
    env_id: str
    timesteps: int
    out: Path
    seed: int = 0
    n_envs: int = 8
    policy: str = "MultiInputPolicy"
    normalize: dict[str, Any] = field(default_factory=dict)
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    algo_kwargs: dict[str, Any] = field(default_factory=dict)
    eval_freq: int = 50_000
    eval_episodes: int = 10
    checkpoint_freq: int = 250_000
    vec_env: str = "native"
    init_from: str | None = None
    progress_bar: bool = True
    wrapper: str | None = None
    wrapper_kwargs: dict[str, Any] = field(default_factory=dict)


def _literal(text: Any) -> Any:
    """Evaluate rl-zoo3's Python-literal strings (``dict(...)``, ``nn.ReLU``) safely."""
    if not isinstance(text, str):
        return text
    import torch.nn as nn

    from agents.networks import BeliefExtractor

    names = {"dict": dict, "nn": nn, "True": True, "False": False, "BeliefExtractor": BeliefExtractor}
    return eval(text, {"__builtins__": {}}, names)  # noqa: S307


def load_hyperparams(algo: str, env_id: str) -> dict[str, Any]:
    """The YAML entry of ``env_id`` in ``hyperparams/<algo>.yml``."""
    path = HYPERPARAMS_DIR / f"{algo}.yml"
    if not path.exists():
        raise ValueError(f"no hyperparameters for algo {algo!r} ({path} missing)")
    entries = yaml.safe_load(path.read_text())
    if env_id not in entries:
        raise ValueError(f"{path.name} has no entry for env {env_id!r}; entries: {sorted(entries)}")
    return dict(entries[env_id])


def load_wrapper(spec: str | None):
    """The gymnasium wrapper class named ``module:Class`` (``None`` for none)."""
    if not spec:
        return None
    import importlib

    module_name, sep, class_name = spec.partition(":")
    if not sep or not module_name or not class_name:
        raise ValueError(f"--wrapper takes module:Class, got {spec!r}")
    wrapper = getattr(importlib.import_module(module_name), class_name, None)
    if wrapper is None:
        raise ValueError(f"module {module_name!r} has no {class_name!r}")
    return wrapper


def _wrapped_env(env_id: str, wrapper: str, wrapper_kwargs: dict[str, Any], **env_kwargs: Any) -> gym.Env:
    """``wrapper(gym.make(env_id, **env_kwargs), **wrapper_kwargs)``; module level, so subprocess envs can pickle it."""
    return load_wrapper(wrapper)(gym.make(env_id, **env_kwargs), **wrapper_kwargs)


def _parse_override(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"--hyperparams takes key=value, got {text!r}")
    parsed = yaml.safe_load(value)
    if isinstance(parsed, str):  # YAML 1.1 reads "1e-4" as a string
        try:
            parsed = float(parsed)
        except ValueError:
            pass
    return key, parsed


def resolve_config(args: argparse.Namespace) -> TrainConfig:
    """Merge the YAML entry and the command-line arguments into a :class:`TrainConfig`."""
    params = load_hyperparams(args.algo, args.env)
    for key, value in args.hyperparams or []:
        params[key] = value
    env_kwargs = dict(params.get("env_kwargs") or {})
    env_kwargs.update(json.loads(args.env_kwargs) if args.env_kwargs else {})
    normalize = _literal(params.get("normalize", False))
    if normalize is True:
        normalize = {}
    return TrainConfig(
        algo=args.algo,
        env_id=args.env,
        timesteps=int(args.timesteps if args.timesteps is not None else params.get("n_timesteps", 1e6)),
        out=Path(args.out),
        seed=args.seed,
        n_envs=int(args.n_envs or params.get("n_envs", 8)),
        policy=params.get("policy", "MultiInputPolicy"),
        normalize=normalize or {},
        policy_kwargs=_literal(params.get("policy_kwargs", {})) or {},
        env_kwargs=env_kwargs,
        algo_kwargs={k: v for k, v in params.items() if k not in _RUN_KEYS},
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        checkpoint_freq=args.checkpoint_freq,
        vec_env=args.vec_env,
        progress_bar=not args.no_progress_bar,
        wrapper=args.wrapper,
        wrapper_kwargs=json.loads(args.wrapper_kwargs) if args.wrapper_kwargs else {},
        init_from=args.init_from,
    )


def train(config: TrainConfig):
    """Train and save; returns the trained model."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    algo_class = {"ppo": PPO, "sac": SAC}[config.algo]
    out = config.out
    out.mkdir(parents=True, exist_ok=True)
    vec_cls = SubprocVecEnv if config.vec_env == "subproc" and config.n_envs > 1 else DummyVecEnv
    # "seif_gym:<id>" makes worker processes (forkserver/spawn) import seif_gym, which registers the id
    env_id = config.env_id if ":" in config.env_id else f"seif_gym:{config.env_id}"
    if config.wrapper:
        # the reward wrapper (e.g. agents.adversary:SeifVsEkfReward) goes *inside* SB3's Monitor, so that the
        # logged episode returns and the EvalCallback's best model use the wrapped reward (make_vec_env's
        # wrapper_class would sit outside the Monitor, which would then log the env's own reward)
        load_wrapper(config.wrapper)  # fail early
        env_id = functools.partial(_wrapped_env, env_id, config.wrapper, dict(config.wrapper_kwargs))
    if config.vec_env == "native" and not config.wrapper:
        # the native vector env (gym.make_vec: N envs in compiled calls) behind SB3's VecEnv interface
        from stable_baselines3.common.vec_env import VecMonitor

        from agents.sb3_vec_env import NativeVecEnv

        env = VecMonitor(NativeVecEnv(env_id, config.n_envs, seed=config.seed, env_kwargs=config.env_kwargs))
        # the same wrappers around the evaluation env, so that EvalCallback can copy the normalisation
        eval_env = VecMonitor(NativeVecEnv(env_id, 1, seed=config.seed + 10_000, env_kwargs=config.env_kwargs))
    else:  # a reward wrapper needs single envs
        env = make_vec_env(env_id, n_envs=config.n_envs, seed=config.seed, vec_env_cls=vec_cls,
                           env_kwargs=config.env_kwargs)  # fmt: skip
        eval_env = make_vec_env(env_id, n_envs=1, seed=config.seed + 10_000, env_kwargs=config.env_kwargs)
    if config.normalize:
        env = VecNormalize(env, **config.normalize)
        eval_env = VecNormalize(eval_env, training=False, norm_reward=False, **{k: v for k, v in config.normalize.items() if k != "norm_reward"})
    (out / "config.json").write_text(
        json.dumps(
            {
                "algo": config.algo,
                "env_id": config.env_id,
                "timesteps": config.timesteps,
                "seed": config.seed,
                "n_envs": config.n_envs,
                "policy": config.policy,
                "normalize": config.normalize,
                "policy_kwargs": repr(config.policy_kwargs),
                "env_kwargs": config.env_kwargs,
                "algo_kwargs": config.algo_kwargs,
                "wrapper": config.wrapper,
                "wrapper_kwargs": config.wrapper_kwargs,
            },
            indent=2,
        )
    )
    model = algo_class(
        config.policy,
        env,
        seed=config.seed,
        verbose=0,
        tensorboard_log=str(out / "tb"),
        policy_kwargs=config.policy_kwargs,
        device="cpu",
        **config.algo_kwargs,
    )
    if config.init_from:
        # continue from a saved model's weights, with this run's hyperparameters
        model.set_parameters(config.init_from, exact_match=True, device="cpu")
    callbacks = [
        CheckpointCallback(
            save_freq=max(config.checkpoint_freq // config.n_envs, 1),
            save_path=str(out / "checkpoints"),
            name_prefix="model",
            save_vecnormalize=True,
        ),
        EvalCallback(
            eval_env,
            best_model_save_path=str(out / "best"),
            log_path=str(out / "eval"),
            eval_freq=max(config.eval_freq // config.n_envs, 1),
            n_eval_episodes=config.eval_episodes,
            deterministic=True,
        ),
    ]
    started = time.perf_counter()
    model.learn(total_timesteps=config.timesteps, callback=callbacks, progress_bar=config.progress_bar)
    elapsed = time.perf_counter() - started
    model.save(out / "model.zip")
    if isinstance(env, VecNormalize):
        env.save(str(out / "vecnormalize.pkl"))
    (out / "train_time.json").write_text(json.dumps({"seconds": elapsed, "timesteps": config.timesteps}))
    print(f"trained {config.timesteps} steps in {elapsed:.0f} s ({config.timesteps / elapsed:.0f} steps/s); saved {out / 'model.zip'}")
    env.close()
    eval_env.close()
    return model


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=ALGOS, default="ppo")
    parser.add_argument("--env", default="SeifExplore-v1", help="a registered env id")
    parser.add_argument("--env-kwargs", default=None, help='JSON dict passed to gym.make, e.g. \'{"layout": "loop"}\'')
    parser.add_argument("--timesteps", type=int, default=None, help="default: n_timesteps of the YAML entry")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n-envs", type=int, default=None)
    parser.add_argument("--vec-env", choices=("native", "subproc", "dummy"), default="native",
                        help="native: gym.make_vec's vector env (all envs in compiled calls; the default), "
                             "dummy: single envs one after another in this process, subproc: one process each; "
                             "with --wrapper, native falls back to dummy")
    parser.add_argument("--hyperparams", nargs="*", type=_parse_override, help="overrides, e.g. learning_rate=1e-4")
    parser.add_argument("--eval-freq", type=int, default=50_000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--checkpoint-freq", type=int, default=250_000)
    parser.add_argument("--no-progress-bar", action="store_true")
    parser.add_argument("--init-from", default=None, help="a saved .zip whose weights start this run (fine-tuning)")
    parser.add_argument("--wrapper", default=None,
                        help="module:Class of a gymnasium wrapper applied to every env (training and evaluation), "
                        "e.g. agents.adversary:SeifVsEkfReward")
    parser.add_argument("--wrapper-kwargs", default=None, help="JSON dict of the wrapper's keyword arguments")
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    if args.env.split(":")[-1] not in gym.registry:
        raise SystemExit(f"unknown env {args.env!r}")
    train(resolve_config(args))


if __name__ == "__main__":
    main()
