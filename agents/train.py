r"""Train an exploration policy on a SeifExplore env: rl-zoo3's ``ExperimentManager`` on the project's config.

Usage::

    python -m agents.train --env SeifExplore-v0 --seed 8                    # the shipped policy's recipe
    python -m agents.train --env SeifExplore-v2 --timesteps 200000 --out runs/ppo_v2
    python -m agents.train --resume runs/ppo_v2                              # after a kill: go on
    python -m agents.train --env SeifExplore-v0 --init-from runs/ppo_v1/best_map_error/model.zip \\
        --hyperparams learning_rate=1e-4 --timesteps 250000

The config is ``agents/hyperparams/<algo>.yml`` (``--conf-file`` for another),
in rl-zoo3's format, read by rl-zoo3 itself: ``agents.train`` builds an
``rl_zoo3.exp_manager.ExperimentManager`` (as ``python -m rl_zoo3.train``
does), so every key of the format (schedules such as ``lin_3e-4``,
``normalize``, ``env_wrapper``, ``vec_env_wrapper``, ``callback``,
``frame_stack``, ``monitor_kwargs``, ``policy`` by dotted name, ...) means
here what it means there, and a run of either command is read by
``rl_zoo3.enjoy`` and ``rl_zoo3.record_video``. On top of rl-zoo3 it adds:

* ``--vec-env native`` (the default): the env's own vector env
  (:class:`agents.sb3_vec_env.NativeVecEnv`, all envs in compiled calls)
  when the config wraps no single env; a config with an ``env_wrapper``
  (the shipped one: the coverage shaping) runs ``dummy``;
* checkpoints every ``--checkpoint-freq`` steps *with* their normalisation
  statistics (``rl_model_<N>_steps.zip`` beside
  ``rl_model_vecnormalize_<N>_steps.pkl``; rl-zoo3's ``--save-freq`` saves
  the model alone), taken between rollouts (after an update, at the first
  rollout's end at or past each multiple: ``N`` is the step count then) and
  written whole or not at all, with a state file
  (:class:`agents.callbacks.ResumableCheckpointCallback`);
* ``--resume RUN``: continue a killed run from its newest complete
  checkpoint, with its own arguments and config (``RUN/<EnvId>/args.yml``,
  ``config.yml``), to the steps it asked for: weights, optimizer, step count
  and schedules, statistics, the envs' episodes under way, the random
  states, the validation's history and best model. A run resumed so ends
  with the weights the run would have had unkilled, bit for bit, on one CPU
  device (``docs/training``: what does not resume exactly);
* the task's callbacks (:mod:`agents.callbacks`), also when a config lacks
  them: the task's metrics in TensorBoard and validation on fixed seeds that
  keeps ``best_map_error/model.zip`` (``--eval-freq``, ``--eval-episodes``;
  rl-zoo3's own reward-based ``EvalCallback`` is off);
* ``--init-from MODEL.zip``: start from a saved model's weights *and* its
  normalisation statistics (found by :func:`agents.checkpoints.vecnormalize_path`),
  with this run's hyperparameters (fine-tuning);
* ``--mix-env ID`` (repeatable): train on a mixture of tasks. The training
  envs take the ids ``--env``, then each ``--mix-env`` in turn by rank (8 envs
  and one ``--mix-env``: four of each); the config's entry, the validation
  and the checkpoints' selection stay those of ``--env``. The ids must share
  the observation and action spaces (the budget layouts do);
* a warning when a decaying schedule (``lin_3e-4``) would turn negative at
  the last update: SB3 collects whole rollouts, so a run of ``--timesteps``
  that is not a multiple of ``n_steps * n_envs`` ends past its schedule's end
  (:func:`negative_schedule_warnings`);
* glibc's ``malloc`` kept from handing freed memory back to the kernel
  (:func:`agents.allocator.keep_freed_memory`; ``--no-keep-freed-memory``:
  off): the PPO update's tensors reuse the heap's pages instead of faulting
  in fresh ones, with the same weights;
* ``--out DIR``: the run's folder exactly (default: rl-zoo3's
  ``-f logs`` layout, ``logs/<algo>/<EnvId>_<N>``, which ``enjoy -f logs``
  finds).

A run's folder::

    <EnvId>.zip                       the final model (rl-zoo3's name)
    <EnvId>/vecnormalize.pkl          its normalisation statistics
    <EnvId>/config.yml, args.yml      the hyperparameters used and the arguments (rl-zoo3's)
    best_map_error/model.zip          the lowest mean final map error on the validation seeds ...
    best_map_error/vecnormalize.pkl   ... and its statistics
    map_error_evaluations.csv         one row per validation
    rl_model_<N>_steps.zip            checkpoints, with rl_model_vecnormalize_<N>_steps.pkl
    rl_model_state_<N>_steps.pkl      ... and what --resume needs besides (written last)
    tb/                               TensorBoard (tensorboard --logdir DIR/tb)
    train_time.json                   seconds and steps of model.learn (written last: the run finished)

Progress: a progress bar and SB3's log table; ``--quiet`` prints nothing
(errors aside).
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import json
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import yaml

import seif_gym  # noqa: F401  (registers the envs)
from agents.allocator import keep_freed_memory
from agents.cli import json_object, resolve_task, tasks_epilog
from agents.hyperparams import HYPERPARAMS_DIR
from seif_gym import LATEST_ID

#: ``before_learn(args, experiment, model)``: a hook called after the model is built, before it learns.
BeforeLearn = Callable[[argparse.Namespace, Any, Any], None]

#: The algorithms of rl-zoo3 (``rl_zoo3.ALGOS``); configs ``agents/hyperparams/<algo>.yml`` exist for ``ppo``,
#: ``ppo_lstm`` and ``sac``.
ALGOS = ("a2c", "ddpg", "dqn", "ppo", "sac", "td3", "ars", "crossq", "qrdqn", "tqc", "trpo", "ppo_lstm")
#: The values of ``--vec-env``.
VEC_ENVS = ("native", "dummy", "subproc")


def load_wrapper(spec: str | None) -> type | None:
    """The gymnasium wrapper class named ``module:Class`` (``None`` for none)."""
    if not spec:
        return None
    import importlib

    module_name, sep, class_name = spec.partition(":")
    if not sep or not module_name or not class_name:
        raise ValueError(f"--wrapper takes module:Class, got {spec!r}")
    wrapper = getattr(importlib.import_module(module_name), class_name, None)
    if wrapper is None:
        raise ValueError(f"--wrapper: module {module_name!r} has no {class_name!r}")
    return wrapper


def _parse_override(text: str) -> tuple[str, Any]:
    """``key=value`` with a YAML value (``learning_rate=1e-4``, ``env_wrapper=null``, ``normalize=dict(...)``)."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"--hyperparams takes key=value, got {text!r}")
    parsed = yaml.safe_load(value)
    if isinstance(parsed, str):  # YAML 1.1 reads "1e-4" as a string
        try:
            parsed = float(parsed)
        except ValueError:
            pass
    return key, parsed


def _positive_or_off(text: str) -> int:
    value = int(text)
    if value == 0 or value < -1:
        raise argparse.ArgumentTypeError(f"expected a positive number of steps or -1 (off), got {text}")
    return value


def _task(text: str) -> str:
    """``--env`` / ``--mix-env``: a family becomes its newest env id; anything else is checked by :func:`prepare`."""
    try:
        return resolve_task(text)
    except ValueError:  # gym's "module:EnvId", or an unknown id that prepare refuses with its option's name
        return text


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``python -m agents.train``."""
    parser = argparse.ArgumentParser(
        prog="python -m agents.train",
        description=__doc__,
        epilog=tasks_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--algo", choices=ALGOS, default="ppo")
    parser.add_argument("--env", type=_task, default=LATEST_ID, metavar="TASK",
                        help="a registered env id or family (default %(default)s)")  # fmt: skip
    parser.add_argument(
        "--conf-file",
        default=None,
        help="config in rl-zoo3's format: a .yml/.py path or a module name (default: agents/hyperparams/<algo>.yml)",
    )
    parser.add_argument(
        "--env-kwargs",
        type=json_object,
        default=None,
        help='JSON object passed to gym.make (over the entry\'s env_kwargs), e.g. \'{"layout": "loop"}\'',
    )
    parser.add_argument(
        "-n",
        "--timesteps",
        "--n-timesteps",
        dest="timesteps",
        type=int,
        default=None,
        help="default: n_timesteps of the config's entry",
    )
    parser.add_argument("--out", default=None, help="the run's folder (default: rl-zoo3's layout under --log-folder)")
    parser.add_argument(
        "-f", "--log-folder", default="logs", help="rl-zoo3's log folder: runs go to LOG_FOLDER/ALGO/ENV_N"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--mix-env",
        action="append",
        type=_task,
        default=[],
        metavar="ID",
        help="another registered env id for a share of the training envs (repeatable): ranks cycle through "
        "--env and these; validation stays on --env",
    )
    parser.add_argument("--n-envs", type=int, default=None, help="overrides the entry's n_envs")
    parser.add_argument(
        "--vec-env",
        choices=VEC_ENVS,
        default="native",
        help="native: the env's own vector env (all envs in compiled calls; the default), "
        "dummy: single envs one after another in this process, subproc: one process each; "
        "a config or --wrapper that wraps single envs turns native into dummy",
    )
    parser.add_argument(
        "--hyperparams",
        nargs="*",
        type=_parse_override,
        default=[],
        action="extend",
        help="overrides of the entry, key=value with YAML values: learning_rate=1e-4 env_wrapper=null "
        "(may be repeated)",
    )
    parser.add_argument(
        "--eval-freq",
        type=_positive_or_off,
        default=None,
        help="steps between validations (default: the config's MapErrorEvalCallback, else 50000; -1: off)",
    )
    parser.add_argument(
        "--eval-episodes", type=int, default=None, help="validation seeds (default: the config's, else 10)"
    )
    parser.add_argument(
        "--checkpoint-freq",
        type=_positive_or_off,
        default=250_000,
        help="steps between checkpoints with their statistics (-1: none)",
    )
    parser.add_argument(
        "--init-from",
        default=None,
        help="a saved .zip whose weights and normalisation statistics start this run (fine-tuning)",
    )
    parser.add_argument(
        "--wrapper",
        default=None,
        help="module:Class of a gymnasium wrapper for every training env, in place of the "
        "config's env_wrapper (e.g. agents.adversary:SeifVsEkfReward)",
    )
    parser.add_argument(
        "--wrapper-kwargs", type=json_object, default=None, help="JSON object of the wrapper's arguments"
    )
    parser.add_argument("--device", default="cpu", help="torch device (rl-zoo3's default is auto)")
    parser.add_argument(
        "--keep-freed-memory",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="glibc's malloc keeps freed memory for reuse instead of faulting in fresh pages, its peak "
        "memory held to the end (agents.allocator; default on)",
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="RUN",
        help="continue the killed run in the folder RUN from its newest complete checkpoint, with its own "
        "arguments and config (only --quiet, --no-progress-bar and --[no-]keep-freed-memory go with it)",
    )
    parser.add_argument("--quiet", action="store_true", help="print nothing: no progress bar, no log table")
    parser.add_argument("--no-progress-bar", action="store_true", help="no progress bar (the log table stays)")
    return parser


# -- --resume ----------------------------------------------------------------------------------------
#: The options that may go with ``--resume``: they change what is printed or how memory is held, not what is trained.
RESUME_HARMLESS = ("resume", "quiet", "no_progress_bar", "keep_freed_memory")


class ResumeError(ValueError):
    """``--resume`` cannot continue the folder it names (not a run, no complete checkpoint, other options given)."""


class RunFinished(Exception):
    """``--resume`` of a run that finished: nothing to do."""


@dataclass(frozen=True)
class _Resume:
    """What a resumed run continues from: the checkpoint, the run's config entry, its monitor logs as they were."""

    checkpoint: Any  # agents.checkpoints.Checkpoint
    config: dict[str, Any]
    monitor_logs: dict[str, bytes]
    skipped: list[str]


class _RunFileLoader(yaml.SafeLoader):
    """YAML's safe loader that also reads rl-zoo3's ``args.yml`` and ``config.yml`` (``OrderedDict`` tags) as dicts."""


def _ordered_dict(loader: yaml.SafeLoader, node: yaml.Node) -> dict[Any, Any]:
    (pairs,) = loader.construct_sequence(node, deep=True)
    return dict(pairs)


_RunFileLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict", _ordered_dict)


def _read_run_file(path: Path) -> dict[str, Any]:
    try:
        content = yaml.load(path.read_text(), Loader=_RunFileLoader)  # noqa: S506 (a safe loader, with one tag more)
    except (OSError, yaml.YAMLError) as error:
        raise ResumeError(f"--resume: {path} does not read ({error})".replace("\n", " ")) from error
    if not isinstance(content, dict):
        raise ResumeError(f"--resume: {path} is not a mapping")
    return content


def _run_arguments_file(folder: Path) -> Path:
    """``RUN/<EnvId>/args.yml`` of the run in ``folder``."""
    found = sorted(folder.glob("*/args.yml")) if folder.is_dir() else []
    if len(found) != 1:
        raise ResumeError(f"--resume: {folder} is not a training run (no <EnvId>/args.yml of agents.train in it)")
    return found[0]


def resume_arguments(args: argparse.Namespace) -> argparse.Namespace:
    """The arguments of the run that ``args.resume`` names, as its ``<EnvId>/args.yml`` recorded them.

    The run's own arguments, with ``--out`` its folder as it is now and ``--quiet``,
    ``--no-progress-bar`` and ``--[no-]keep-freed-memory`` (:data:`RESUME_HARMLESS`) from ``args``.

    Raises
    ------
    ResumeError
        If the folder holds no run of ``agents.train``.
    RunFinished
        If the run finished (its ``train_time.json`` is written last).
    """
    folder = Path(args.resume)
    saved = _read_run_file(_run_arguments_file(folder))
    defaults = vars(build_parser().parse_args([]))
    if not {"checkpoint_freq", "vec_env"} <= saved.keys():
        raise ResumeError(f"--resume: {folder} was not trained by agents.train (its args.yml lacks its options)")
    finished = folder / "train_time.json"
    if finished.is_file():
        try:
            steps = json.loads(finished.read_text()).get("timesteps")
        except (OSError, ValueError, AttributeError):
            steps = None
        raise RunFinished(
            f"{folder} is finished ({steps} steps, final model {folder / (str(saved.get('env')) + '.zip')}): "
            "nothing to resume"
        )
    values = {key: saved[key] for key in defaults if key in saved}
    overrides = values.get("hyperparams") or {}
    values["hyperparams"] = list(overrides.items()) if isinstance(overrides, dict) else list(overrides)
    values.update({key: getattr(args, key) for key in RESUME_HARMLESS if hasattr(args, key)})
    values.update(resume=str(folder), out=str(folder))
    return argparse.Namespace(**{**defaults, **values})


def _plan_resume(args: argparse.Namespace) -> _Resume:
    """The checkpoint, config and logs that the resumed run ``args`` (:func:`resume_arguments`) continues from.

    Raises
    ------
    ResumeError
        If the run has no complete checkpoint or its ``config.yml`` is missing.
    """
    from agents.checkpoints import newest_complete_checkpoint, remove_temporaries

    folder = Path(args.resume)
    config_path = _run_arguments_file(folder).with_name("config.yml")
    if not config_path.is_file():
        raise ResumeError(f"--resume: {folder} has no {config_path.relative_to(folder)} (its config)")
    config = _read_run_file(config_path)
    checkpoint, skipped = newest_complete_checkpoint(folder)
    if checkpoint is None:
        why = f" ({'; '.join(skipped)})" if skipped else ""
        raise ResumeError(f"--resume: {folder} has no complete checkpoint to resume from{why}")
    remove_temporaries(folder)  # what atomic writes left when the run was killed
    logs = {path.name: path.read_bytes() for path in folder.glob("*monitor.csv")}  # before the envs empty them
    return _Resume(checkpoint, config, logs, skipped)


def _given_options(argv: Sequence[str] | None) -> set[str]:
    """The destinations of the options written on the command line ``argv`` (defaults left out)."""
    parser = build_parser()
    for action in parser._actions:
        action.default = argparse.SUPPRESS
    return set(vars(parser.parse_args(argv)))


def _config_for(args: argparse.Namespace) -> str:
    if args.conf_file is not None:
        return str(args.conf_file)
    path = HYPERPARAMS_DIR / f"{args.algo}.yml"
    if not path.is_file():
        raise ValueError(f"no config for --algo {args.algo} ({path} missing); pass --conf-file")
    return str(path)


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The command line's changes of the config's entry, as rl-zoo3's ``--hyperparams`` dict."""
    overrides = dict(args.hyperparams or [])
    if args.n_envs is not None:
        if args.n_envs < 1:
            raise ValueError(f"--n-envs must be at least 1, got {args.n_envs}")
        overrides["n_envs"] = args.n_envs
    if args.wrapper_kwargs is not None and not args.wrapper:
        raise ValueError("--wrapper-kwargs needs --wrapper")
    if args.wrapper:
        load_wrapper(args.wrapper)  # fail before any env is built
        module_name, _, class_name = args.wrapper.partition(":")
        overrides["env_wrapper"] = [{f"{module_name}.{class_name}": dict(args.wrapper_kwargs or {})}]
    return overrides


@contextlib.contextmanager
def _maybe_silent(quiet: bool) -> Iterator[None]:
    """Swallow stdout when ``quiet``: rl-zoo3 prints its steps (config, folders) whatever its verbosity."""
    if quiet:
        with contextlib.redirect_stdout(io.StringIO()):
            yield
    else:
        yield


def _experiment_class() -> type:
    """:class:`SeifExperiment`, defined on first use: rl-zoo3 (and optuna with it) is imported only to train."""
    from rl_zoo3 import ALGOS as ZOO_ALGOS
    from rl_zoo3.exp_manager import ExperimentManager
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
    from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecMonitor

    from agents.callbacks import MapErrorEvalCallback, ResumableCheckpointCallback, TaskMetricsCallback

    class SeifExperiment(ExperimentManager):
        """rl-zoo3's ``ExperimentManager`` with the native vector env, paired checkpoints and the task's callbacks.

        Parameters
        ----------
        args : argparse.Namespace
            :func:`build_parser`'s arguments.
        """

        callbacks: list[Any]  # set by ExperimentManager.__init__
        env_kwargs: dict[str, Any]  # set by ExperimentManager.__init__, settled by _preprocess_hyperparams

        def __init__(self, args: argparse.Namespace, resume: _Resume | None = None) -> None:
            self.options = args
            self.resume = resume  # --resume: the checkpoint, config and logs the run continues from
            self.native = args.vec_env == "native"
            # what rl-zoo3 writes to args.yml and its enjoy/record_video read back (env_kwargs)
            zoo_args = argparse.Namespace(**{k: v for k, v in vars(args).items() if k not in ("hyperparams",)})
            zoo_args.env_kwargs = args.env_kwargs
            zoo_args.hyperparams = _overrides(args)
            zoo_args.conf_file = _config_for(args)
            super().__init__(
                zoo_args,
                args.algo,
                args.env,
                args.log_folder,
                tensorboard_log="",
                n_timesteps=args.timesteps if args.timesteps is not None else -1,
                eval_freq=-1,  # rl-zoo3's reward-based evaluation: the task's validation replaces it
                save_freq=-1,  # rl-zoo3's checkpoints leave the statistics out: ours keep them beside
                hyperparams=zoo_args.hyperparams,
                env_kwargs=args.env_kwargs,
                seed=args.seed,
                log_interval=-1,  # SB3's default (rl-zoo3's constructor default, 0, is not valid for learn)
                verbose=0 if args.quiet else 1,
                vec_env_type="subproc" if args.vec_env == "subproc" else "dummy",
                device=args.device,
                config=zoo_args.conf_file,
                show_progress=not (args.quiet or args.no_progress_bar),
            )
            if args.out is not None:
                self.save_path = str(Path(args.out))
                self.params_path = os.path.join(self.save_path, self.env_name)
            self.tensorboard_log = os.path.join(self.save_path, "tb")

        def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
            """The config's entry with the overrides; a resumed run's own, as its ``config.yml`` recorded them."""
            if self.resume is None:
                return super().read_hyperparameters()
            hyperparams = copy.deepcopy(self.resume.config)
            if "env_kwargs" in hyperparams and self.env_kwargs and self._eval_env_kwargs_args is None:
                self.eval_env_kwargs = hyperparams["env_kwargs"]  # as rl-zoo3 does
            return hyperparams, dict(sorted(hyperparams.items()))

        def save_trained_model(self, model: BaseAlgorithm) -> None:
            """rl-zoo3's final model, replay buffer and statistics, each file written whole or not at all."""
            from agents.checkpoints import atomic_write

            print(f"Saving to {self.save_path}")
            atomic_write(Path(self.save_path) / f"{self.env_name}.zip", lambda temporary: model.save(temporary))
            if hasattr(model, "save_replay_buffer") and self.save_replay_buffer:
                path = Path(self.save_path) / "replay_buffer.pkl"
                atomic_write(path, lambda temporary: model.save_replay_buffer(temporary))
            vec_normalize = model.get_vec_normalize_env()
            if self.normalize and vec_normalize is not None:
                path = Path(self.params_path) / "vecnormalize.pkl"
                atomic_write(path, lambda temporary: vec_normalize.save(str(temporary)))

        def _save_config(self, saved_hyperparams: dict[str, Any]) -> None:
            if self.resume is None:  # a resumed run keeps the config, arguments and command it was started with
                super()._save_config(saved_hyperparams)

        def _preprocess_hyperparams(
            self, hyperparams: dict[str, Any]
        ) -> tuple[dict[str, Any], Callable[..., Any] | None, list[Any], Callable[..., Any] | None]:
            from agents.evaluate import without_exact_nees

            processed = super()._preprocess_hyperparams(hyperparams)
            # every env of the run (training, validation, kickstart) without info["pose_nees"]: nothing in
            # training reads it, and its exact marginal factorises Omega every step
            # (agents.evaluate.make_evaluation_env); the entry's or --env-kwargs' own value wins. After
            # rl-zoo3 has settled env_kwargs (command line over entry) and recorded them in config.yml.
            self.env_kwargs = without_exact_nees(self.env_kwargs)
            return processed

        # -- envs ------------------------------------------------------------------------------------
        def uses_native(self) -> bool:
            """Whether the training envs are the native vector env (no single-env wrapper or mixture in the way)."""
            return self.native and self.env_wrapper is None and not self.options.mix_env

        def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
            if self.options.mix_env and not eval_env:
                return self._mixed_envs(n_envs, no_log=no_log)
            if not self.uses_native():
                return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)
            from agents.sb3_vec_env import NativeVecEnv

            env_kwargs = self.eval_env_kwargs if eval_env else self.env_kwargs
            env: VecEnv = NativeVecEnv(self.env_name.gym_id, n_envs, seed=self.seed, env_kwargs=env_kwargs)
            # the log rl-zoo3's Monitor would write, in the run's folder (agents.callbacks.run_folder reads it)
            log = None if eval_env or no_log else os.path.join(self.save_path, "monitor.csv")
            env = VecMonitor(env, filename=log, info_keywords=tuple(self.monitor_kwargs.get("info_keywords", ())))
            return self._wrap_vector_env(env, eval_env)

        def _wrap_vector_env(self, env: VecEnv, eval_env: bool) -> VecEnv:
            """The config's vector-env wrapper, normalisation and frame stack, as rl-zoo3 applies them."""
            if self.vec_env_wrapper is not None:
                env = self.vec_env_wrapper(env)
            env = self._maybe_normalize(env, eval_env)
            if self.frame_stack is not None:
                env = VecFrameStack(env, self.frame_stack)
            return env

        def _mixed_envs(self, n_envs: int, no_log: bool) -> VecEnv:
            """The training envs of ``--mix-env``: rank ``r`` runs ``ids[r % len(ids)]``, ``ids = [--env, *mix]``.

            Each single env is built as rl-zoo3 builds its own (``make_vec_env``: the
            monitor, then the config's ``env_wrapper``, the action space seeded with
            ``seed + rank`` and the vector env with ``seed``), then the config's
            vector-env wrapper, normalisation and frame stack.
            """
            from stable_baselines3.common.monitor import Monitor

            ids = [self.env_name.gym_id, *self.options.mix_env]  # checked by prepare (mixture_ids)
            specs = [gym.spec(env_id) for env_id in ids]
            log_dir = None if no_log else self.save_path
            env_kwargs, wrapper, seed = dict(self.env_kwargs), self.env_wrapper, self.seed
            monitor_kwargs, vec_env_kwargs = dict(self.monitor_kwargs), dict(self.vec_env_kwargs)

            def make(rank: int) -> Any:
                def thunk() -> gym.Env:
                    env = specs[rank % len(specs)].make(**env_kwargs)
                    log = None if log_dir is None else os.path.join(log_dir, str(rank))
                    env = Monitor(env, filename=log, **monitor_kwargs)
                    if wrapper is not None:
                        env = wrapper(env)
                    env.action_space.seed(seed + rank)
                    return env

                return thunk

            env: VecEnv = self.vec_env_class([make(rank) for rank in range(n_envs)], **vec_env_kwargs)
            env.seed(seed)
            return self._wrap_vector_env(env, eval_env=False)

        # -- callbacks -------------------------------------------------------------------------------
        def create_callbacks(self) -> None:
            super().create_callbacks()  # the progress bar
            options = self.options
            checkpoints = None
            if options.checkpoint_freq > 0:
                checkpoints = ResumableCheckpointCallback(
                    save_freq=options.checkpoint_freq,
                    save_path=self.save_path,
                    name_prefix="rl_model",  # rl-zoo3's name: enjoy --load-checkpoint N finds it
                    save_replay_buffer=issubclass(ZOO_ALGOS[self.algo], OffPolicyAlgorithm),
                    verbose=0 if options.quiet else 1,
                )
                if self.resume is not None:
                    checkpoints.seconds_before = float(self.resume.checkpoint.state.get("seconds", 0.0))
                self.callbacks.append(checkpoints)
            evaluations = [c for c in self.callbacks if isinstance(c, MapErrorEvalCallback)]
            if options.eval_freq == -1:
                self.callbacks = [c for c in self.callbacks if not isinstance(c, MapErrorEvalCallback)]
                evaluations = []
            elif not evaluations:
                evaluations = [MapErrorEvalCallback()]
                self.callbacks.append(evaluations[0])
            for callback in evaluations:
                # validation on the plain env of this run's id and arguments, results in this run's folder
                callback.save_path = Path(self.save_path)
                callback.env_id = self.env_name.gym_id
                callback.env_kwargs = dict(self.env_kwargs)
                if options.eval_freq is not None:
                    callback.eval_freq = options.eval_freq
                if options.eval_episodes is not None:
                    if options.eval_episodes < 1:
                        raise ValueError(f"--eval-episodes must be at least 1, got {options.eval_episodes}")
                    callback.n_episodes = options.eval_episodes
                if options.quiet:
                    callback.verbose = 0
            if not any(isinstance(c, TaskMetricsCallback) for c in self.callbacks):
                self.callbacks.append(TaskMetricsCallback())
            if checkpoints is not None:
                checkpoints.callbacks = self.callbacks  # their states go with each checkpoint

        # -- resuming --------------------------------------------------------------------------------
        def resume_training(self, model: BaseAlgorithm) -> str:
            """Load the checkpoint of ``--resume`` into ``model`` and the callbacks (the random states: :meth:`learn`).

            Returns
            -------
            str
                What became of the envs (:func:`agents.checkpoints.restore_training_state`).
            """
            from agents.callbacks import restore_callback_states
            from agents.checkpoints import restore_training_state

            assert self.resume is not None
            note = restore_training_state(model, self.resume.checkpoint, self.resume.monitor_logs)
            restore_callback_states(self.callbacks, self.resume.checkpoint.state.get("callbacks", {}))
            return note

        def learn(self, model: BaseAlgorithm) -> None:
            """rl-zoo3's ``learn``; a resumed run continues its step count to ``n_timesteps`` from the saved random states."""
            if self.resume is None:
                super().learn(model)
                return
            from agents.checkpoints import restore_rng

            kwargs: dict[str, Any] = {"reset_num_timesteps": False}  # the step count, and the schedules, go on
            if self.log_interval > -1:
                kwargs["log_interval"] = self.log_interval
            elif self.log_interval < -1:
                kwargs["log_interval"] = None
            if self.callbacks:
                kwargs["callback"] = self.callbacks
            restore_rng(self.resume.checkpoint.state["rng"])  # last: nothing may draw between here and the rollout
            try:
                model.learn(max(self.n_timesteps - model.num_timesteps, 0), **kwargs)
            except KeyboardInterrupt:  # as rl-zoo3: the model is saved
                pass
            finally:
                if self.callbacks:
                    self.callbacks[0].on_training_end()
                try:
                    assert model.env is not None
                    model.env.close()
                except EOFError:
                    pass

        # -- fine-tuning -----------------------------------------------------------------------------
        def init_from(self, model: Any, path: str | os.PathLike) -> Path | None:
            """Load the weights of the model at ``path`` into ``model`` and its statistics into the training env.

            Returns
            -------
            Path or None
                The statistics loaded (``None``: none saved with that model).

            Raises
            ------
            FileNotFoundError
                If there is no model at ``path``.
            ValueError
                If the saved statistics normalise observations and this run does not, or the reverse
                (the weights would read differently scaled inputs).
            """
            from agents.checkpoints import load_vecnormalize_stats, vecnormalize_path

            path = Path(path)
            if not path.is_file():
                raise FileNotFoundError(f"--init-from: no model at {path}")
            model.set_parameters(str(path), exact_match=True, device=self.device)
            stats_path = vecnormalize_path(path)
            vec_normalize = model.get_vec_normalize_env()
            if stats_path is None:
                if vec_normalize is not None and vec_normalize.norm_obs:
                    raise ValueError(
                        f"--init-from: this run normalises observations, but {path} has no statistics beside it"
                    )
                return None
            saved = load_vecnormalize_stats(stats_path)
            this_norm_obs = vec_normalize is not None and vec_normalize.norm_obs
            if bool(saved.norm_obs) != this_norm_obs:
                raise ValueError(
                    f"--init-from: {stats_path} {'normalises' if saved.norm_obs else 'does not normalise'} "
                    "observations, "
                    f"this run {'does' if this_norm_obs else 'does not'}"
                )
            if vec_normalize is not None:
                if vec_normalize.norm_obs:
                    vec_normalize.obs_rms = copy.deepcopy(saved.obs_rms)
                vec_normalize.ret_rms = copy.deepcopy(saved.ret_rms)
            return stats_path

    return SeifExperiment


def mixture_ids(env_id: str, mix: Sequence[str], env_kwargs: dict[str, Any] | None = None) -> list[str]:
    """The ids of a ``--mix-env`` training, in rank order: ``[env_id, *mix]``.

    Each is made once (with ``env_kwargs``) to compare its spaces with ``env_id``'s.

    Raises
    ------
    ValueError
        If an id of ``mix`` is not registered, or its observation or action space differs from
        ``env_id``'s (one policy reads them all).
    """
    ids = [env_id, *mix]
    for other in mix:
        if other.split(":")[-1] not in gym.registry:
            raise ValueError(f"--mix-env: unknown env {other!r}")
    if mix:
        spaces = []
        for each in ids:
            env = gym.make(each, **(env_kwargs or {}))
            spaces.append((env.observation_space, env.action_space))
            env.close()
        for other, space in zip(mix, spaces[1:], strict=True):
            if space != spaces[0]:
                raise ValueError(f"--mix-env: {other!r} has other observation or action spaces than --env {env_id!r}")
    return ids


def prepare(args: argparse.Namespace, before_learn: BeforeLearn | None = None) -> tuple[Any, Any]:
    """The experiment and its model, ready to learn (config read, envs and callbacks built, ``--init-from`` applied).

    Parameters
    ----------
    args : argparse.Namespace
        The arguments of :func:`build_parser`.
    before_learn : callable, optional
        ``before_learn(args, experiment, model)``, called last (after ``--init-from``): a hook for code
        that changes the starting weights, such as the research log's kickstarting (``research/``).

    Returns
    -------
    experiment : SeifExperiment
    model : stable_baselines3.common.base_class.BaseAlgorithm

    With ``--resume RUN`` the arguments are the run's (:func:`resume_arguments`), its checkpoint is
    loaded into the model, the envs and the callbacks (the random states when it learns), and neither
    its ``--init-from`` nor ``before_learn`` applies: the run goes on from its checkpoint.

    Raises
    ------
    ValueError
        If ``--env`` or a ``--mix-env`` is not registered, their spaces differ (:func:`mixture_ids`), or
        the config or an override is not one rl-zoo3 takes.
    FileNotFoundError
        If ``--conf-file`` or ``--init-from`` does not exist.
    ResumeError
        If ``--resume`` names no run of ``agents.train``, or one without a complete checkpoint.
    RunFinished
        If ``--resume`` names a run that finished.
    """
    from stable_baselines3.common.utils import set_random_seed

    resume = None
    if args.resume:
        args = resume_arguments(args)
        resume = _plan_resume(args)
    if args.env.split(":")[-1] not in gym.registry:
        raise ValueError(f"--env: unknown env {args.env!r}")
    mixture_ids(args.env, args.mix_env, args.env_kwargs)
    set_random_seed(args.seed)  # as rl_zoo3.train does before building the experiment
    experiment = _experiment_class()(args, resume)
    with _maybe_silent(args.quiet):
        model, _ = experiment.setup_experiment()
    if args.vec_env == "native" and not experiment.uses_native() and not args.quiet:
        print(
            "agents.train: the config wraps single envs (env_wrapper), so the envs run in a DummyVecEnv",
            file=sys.stderr,
        )
    if resume is not None:  # the checkpoint's weights, not --init-from's, and no hook: the run goes on
        envs = experiment.resume_training(model)
        if not args.quiet:
            skipped = "".join(f"; passed over: {why}" for why in resume.skipped)
            print(
                f"agents.train: resuming {args.resume} at {model.num_timesteps} of {experiment.n_timesteps} steps "
                f"from {resume.checkpoint.model.name} (envs: "
                f"{'their episodes go on' if envs == 'restored' else 'new episodes, ' + envs}){skipped}",
                file=sys.stderr,
            )
        return experiment, model
    if args.init_from:
        stats = experiment.init_from(model, args.init_from)
        if not args.quiet:
            print(
                f"agents.train: weights from {args.init_from}, statistics from {stats or '(none saved)'}",
                file=sys.stderr,
            )
    if before_learn is not None:
        before_learn(args, experiment, model)
    if not args.quiet:
        for line in negative_schedule_warnings(model, experiment.n_timesteps):
            print(f"agents.train: {line}", file=sys.stderr)
    return experiment, model


def _last_update_step(total_timesteps: int, rollout_steps: int) -> int:
    """The step count at an on-policy run's last update: ``total_timesteps`` rounded up to whole rollouts."""
    if total_timesteps < 1 or rollout_steps < 1:
        raise ValueError(f"total_timesteps and rollout_steps must be positive, got {total_timesteps}, {rollout_steps}")
    return -(-total_timesteps // rollout_steps) * rollout_steps


def last_update_progress(total_timesteps: int, rollout_steps: int) -> float:
    """SB3's ``progress_remaining`` at an on-policy run's last update.

    SB3 collects whole rollouts of ``rollout_steps`` (``n_steps * n_envs``) until
    ``total_timesteps`` is reached, and updates after each at
    ``1 - num_timesteps / total_timesteps``: with ``T = total_timesteps`` and
    ``R = rollout_steps``, the last update is at ``1 - R * ceil(T / R) / T``,
    below zero when ``T`` is not a multiple of ``R``.

    Raises
    ------
    ValueError
        If either count is not positive.
    """
    return 1.0 - _last_update_step(total_timesteps, rollout_steps) / total_timesteps


def negative_schedule_warnings(model: Any, total_timesteps: int) -> list[str]:
    """What an on-policy model's schedules would reach below zero at its last update.

    rl-zoo3's ``lin_<x>`` schedule is ``progress_remaining * x``, unclamped: a
    run whose steps overshoot ``total_timesteps`` (100 000 steps in rollouts of
    4096 end at 102 400) makes its last update with a negative learning rate (a
    step up the loss) or clip range. One line per such schedule, with the fix.
    """
    n_steps, n_envs = getattr(model, "n_steps", None), getattr(model, "n_envs", None)
    if not isinstance(n_steps, int) or not isinstance(n_envs, int):
        return []  # off-policy: progress advances step by step and ends at zero
    rollout_steps = n_steps * n_envs
    progress = last_update_progress(total_timesteps, rollout_steps)
    lines = []
    for name, schedule in (("learning_rate", model.lr_schedule), ("clip_range", getattr(model, "clip_range", None))):
        value = float(schedule(progress)) if callable(schedule) else 0.0
        if value < 0.0:
            lines.append(
                f"{name} is {value:.3g} at the last update (progress {progress:.4f}): "
                f"pass --timesteps as a multiple of n_steps * n_envs = {rollout_steps} "
                f"(e.g. {_last_update_step(total_timesteps, rollout_steps)})"
            )
    return lines


def train(args: argparse.Namespace, before_learn: BeforeLearn | None = None) -> Path:
    """Train and save the run of ``args``.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments of :func:`build_parser`.
    before_learn : callable, optional
        As :func:`prepare`.

    Returns
    -------
    Path
        The run's folder.

    Raises
    ------
    ValueError, FileNotFoundError
        As :func:`prepare`, before anything is trained.
    """
    return _learn_and_save(args, *prepare(args, before_learn))


def _learn_and_save(args: argparse.Namespace, experiment: Any, model: Any) -> Path:
    """:func:`train` after :func:`prepare`: learn, save the model and the wall time, report.

    ``train_time.json``, written last, marks the run finished; a resumed run's seconds count those
    trained up to its checkpoint too, and it records the step count it was resumed from.
    """
    from agents.checkpoints import atomic_write

    resume = getattr(experiment, "resume", None)
    started = time.perf_counter()
    experiment.learn(model)
    elapsed = time.perf_counter() - started
    with _maybe_silent(args.quiet):
        experiment.save_trained_model(model)
    folder = Path(experiment.save_path)
    record: dict[str, Any] = {"seconds": elapsed, "timesteps": int(model.num_timesteps)}
    if resume is not None:
        record["seconds"] += float(resume.checkpoint.state.get("seconds", 0.0))
        record["resumed_from"] = int(resume.checkpoint.steps)
    atomic_write(folder / "train_time.json", lambda temporary: temporary.write_text(json.dumps(record)))
    if not args.quiet:
        print(
            f"trained {model.num_timesteps} steps in {elapsed:.0f} s ({model.num_timesteps / elapsed:.0f} steps/s); "
            f"run folder {folder}"
        )
    return folder


def run(args: argparse.Namespace, before_learn: BeforeLearn | None = None) -> int:
    """Prepare (``before_learn`` as :func:`prepare`), learn and save the run of ``args``; the exit status.

    A ``ValueError`` or ``FileNotFoundError`` raised while preparing (a bad argument or config) becomes a
    one-line exit message; an error during training keeps its traceback.
    """
    if args.keep_freed_memory:
        keep_freed_memory()  # before torch allocates: the update's tensors then reuse the heap's pages
    try:
        experiment, model = prepare(args, before_learn)
    except ResumeError as error:  # --resume of what cannot be resumed: one line, exit 2 (a usage error)
        print(f"agents.train: {error}", file=sys.stderr)
        return 2
    except RunFinished as finished:
        print(f"agents.train: --resume: {finished}", file=sys.stderr)
        return 0
    except (ValueError, FileNotFoundError) as error:  # a bad argument or config: one line, no traceback
        raise SystemExit(f"agents.train: {error}") from error
    # an error during training (numpy's LinAlgError is a ValueError too) keeps its traceback
    _learn_and_save(args, experiment, model)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: :func:`run` on ``argv`` parsed by :func:`build_parser`.

    ``--resume RUN`` takes the run's own arguments: any other option but those of
    :data:`RESUME_HARMLESS` is refused (exit status 2).
    """
    args = build_parser().parse_args(argv)
    if args.resume is not None:
        others = sorted(_given_options(argv) - set(RESUME_HARMLESS))
        if others:
            names = ", ".join("--" + name.replace("_", "-") for name in others)
            print(
                f"agents.train: --resume continues {args.resume} with its own arguments; drop {names} "
                "(only --quiet, --no-progress-bar and --[no-]keep-freed-memory go with it)",
                file=sys.stderr,
            )
            return 2
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
