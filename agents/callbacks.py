"""Training callbacks that watch the task, not the reward.

Both are named in the training config (``callback:`` of
``agents/hyperparams/ppo.yml``), so ``python -m rl_zoo3.train`` and
``python -m agents.train`` run them alike:

:class:`TaskMetricsCallback`
    TensorBoard's ``rollout/final_map_error``, ``rollout/landmarks_mapped``,
    ``rollout/landmarks_fraction`` and ``rollout/pose_rmse``: the task's metrics of the training
    episodes, read from the env's ``info`` (what a reward wrapper such as
    :class:`~agents.shaping.CoverageShaping` leaves untouched), averaged
    over the last ``stats_window_size`` episodes like SB3's ``ep_rew_mean``.
:class:`MapErrorEvalCallback`
    Every ``eval_freq`` steps, the deterministic policy on fixed validation
    seeds of the *plain* env (no reward wrapper): ``eval/final_map_error``
    and the others in TensorBoard, one row per evaluation in
    ``map_error_evaluations.csv``, and the model with the lowest mean final
    map error so far in ``best_map_error/model.zip``, with its
    ``vecnormalize.pkl`` beside it.

:class:`ResumableCheckpointCallback`
    ``agents.train``'s checkpoints: between rollouts, the model with its
    statistics and everything else a resumed run continues from
    (:func:`agents.checkpoints.save_checkpoint`), the other callbacks'
    states included (their ``state_dict``; the two above have one).

The metrics are those of ``python -m agents.evaluate`` (final map error,
landmarks mapped, pose RMSE over the episode), so a validation number here
and an evaluation there mean the same thing.
"""

from __future__ import annotations

import csv
import math
import os
import time
import warnings
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from agents.checkpoints import save_with_vecnormalize
from agents.memories import policy_memories
from agents.protocol import VALIDATION_SEED

__all__ = [
    "EVAL_COLUMNS",
    "MapErrorEvalCallback",
    "ResumableCheckpointCallback",
    "TaskMetricsCallback",
    "restore_callback_states",
    "run_folder",
]

#: Columns of ``map_error_evaluations.csv``.
EVAL_COLUMNS: tuple[str, ...] = (
    "timesteps",
    "final_map_error",
    "final_map_error_ci95",
    "landmarks_mapped",
    "landmarks_total",
    "pose_rmse",
    "best",
)


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be at least {minimum}, got {value}")
    return int(value)


def run_folder(training_env: Any) -> Path | None:
    """The folder of the training run: where the training env's ``Monitor`` writes its log.

    rl-zoo3 builds the config's callbacks before it chooses the run folder and
    tells them nothing of it; the one trace of that folder the callbacks can
    see is the ``Monitor`` log it sets up there (for single-process vector
    envs: ``DummyVecEnv``, rl-zoo3's default, and ``VecMonitor``).

    Returns
    -------
    Path or None
        ``None`` when no monitor log is reachable (e.g. ``SubprocVecEnv``).
    """
    env = training_env
    while env is not None:
        writer = getattr(env, "results_writer", None)  # VecMonitor (possibly under VecNormalize)
        if writer is not None:
            return Path(writer.file_handler.name).parent
        envs = getattr(env, "envs", None)  # DummyVecEnv: each sub-env's Monitor, under any reward wrapper
        if isinstance(envs, list) and envs and isinstance(envs[0], gym.Env):
            try:
                writer = envs[0].get_wrapper_attr("results_writer")
            except AttributeError:
                writer = None
            return Path(writer.file_handler.name).parent if writer is not None else None
        env = getattr(env, "venv", None)
    return None


class TaskMetricsCallback(BaseCallback):
    """Log the task's metrics of the training episodes to TensorBoard.

    At the end of every rollout it records the means, over the last
    ``stats_window_size`` finished episodes, of ``rollout/final_map_error``
    (``info["map_error"]`` at the episode's last step, m),
    ``rollout/landmarks_mapped``, ``rollout/landmarks_fraction`` (mapped /
    total) and ``rollout/pose_rmse`` (RMS of ``info["pose_error"]`` over the
    episode's steps, m). The values come from the env's ``info``, so a reward
    wrapper changes none of them.

    Parameters
    ----------
    stats_window_size : int, default 100
        Episodes averaged (SB3's window for ``ep_rew_mean``).
    verbose : int, default 0
    """

    def __init__(self, stats_window_size: int = 100, verbose: int = 0) -> None:
        super().__init__(verbose=verbose)
        self.stats_window_size = _check_int("stats_window_size", stats_window_size, 1)
        self.episodes: deque[dict[str, float]] = deque(maxlen=self.stats_window_size)
        self._squared = np.zeros(0)
        self._steps = np.zeros(0, dtype=np.int64)
        self._restored: dict[str, Any] | None = None  # load_state_dict's, taken when training starts

    def _init_callback(self) -> None:
        n_envs = self.training_env.num_envs
        self._squared = np.zeros(n_envs)
        self._steps = np.zeros(n_envs, dtype=np.int64)
        restored, self._restored = self._restored, None
        if restored is not None and len(restored["steps"]) == n_envs:  # a resumed run's episodes under way
            self._squared, self._steps = np.array(restored["squared"]), np.array(restored["steps"], dtype=np.int64)

    def state_dict(self) -> dict[str, Any]:
        """The episodes averaged and the sums of the episodes under way (saved with each checkpoint)."""
        return {"episodes": list(self.episodes), "squared": self._squared.copy(), "steps": self._steps.copy()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Take :meth:`state_dict`'s ``state`` (a resumed run): the window now, the sums when training starts."""
        self.episodes.clear()
        self.episodes.extend(dict(episode) for episode in state["episodes"])
        self._restored = dict(state)

    def _on_step(self) -> bool:
        infos: Sequence[Mapping[str, Any]] = self.locals["infos"]
        dones = self.locals["dones"]
        for i, info in enumerate(infos):
            if "pose_error" in info:
                self._squared[i] += float(info["pose_error"]) ** 2
                self._steps[i] += 1
            if dones[i] and "map_error" in info:
                total = int(info.get("landmarks_total", 0))
                self.episodes.append(
                    {
                        "final_map_error": float(info["map_error"]),
                        "landmarks_mapped": float(info.get("landmarks_mapped", math.nan)),
                        "landmarks_fraction": float(info.get("landmarks_mapped", math.nan)) / total
                        if total
                        else math.nan,
                        "pose_rmse": math.sqrt(self._squared[i] / self._steps[i]) if self._steps[i] else math.nan,
                    }
                )
            if dones[i]:
                self._squared[i], self._steps[i] = 0.0, 0
        return True

    def _on_rollout_end(self) -> None:
        if not self.episodes:
            return
        for key in self.episodes[0]:
            self.logger.record(f"rollout/{key}", float(np.nanmean([episode[key] for episode in self.episodes])))


class _NormalizedPolicy:
    """``model.predict`` behind the agents' interface, after the training env's observation normalisation.

    :func:`agents.evaluate.run_episode` drives it, so validation episodes are
    run and scored exactly as evaluation episodes are.
    """

    def __init__(self, model: Any, deterministic: bool, env: gym.Env) -> None:
        self.model = model
        self.deterministic = deterministic
        self.vec_normalize = model.get_vec_normalize_env()
        # a policy trained with entries of its own (agents.memories) computes them itself on the plain env
        self.memories = policy_memories(model.observation_space, env)

    def reset(self) -> None:
        if self.memories is not None:
            self.memories.reset()

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, Any]:
        if self.memories is not None:
            observation = self.memories.observe(observation, episode_start)
        if self.vec_normalize is not None:
            # the training statistics as they are now (normalize_obs neither updates nor needs a batch)
            observation = self.vec_normalize.normalize_obs(observation)
        action, state = self.model.predict(
            observation, state=state, episode_start=episode_start, deterministic=self.deterministic
        )
        if self.memories is not None:
            action = self.memories.act(action)  # a residual's sum with the planner's action
        return action, state


class MapErrorEvalCallback(BaseCallback):
    """Evaluate on fixed validation seeds of the plain env; keep the model with the lowest final map error.

    Every ``eval_freq`` training steps (and once at the end of training),
    the policy runs one episode from ``env.reset(seed=s)`` for each seed
    ``s`` in ``first_seed, …, first_seed + n_episodes − 1`` of an env made
    without any wrapper of the training env (the task, not the shaped
    reward), scored by :func:`agents.evaluate.run_episode`. Recorded:
    TensorBoard ``eval/final_map_error``, ``eval/final_map_error_ci95``
    (half-width of Student's t interval), ``eval/landmarks_mapped``,
    ``eval/pose_rmse`` and ``eval/best_final_map_error``; a row of
    :data:`EVAL_COLUMNS` in ``SAVE_PATH/map_error_evaluations.csv``; and, when
    the mean final map error is the lowest so far,
    ``SAVE_PATH/best_map_error/model.zip`` with ``vecnormalize.pkl`` beside
    it (:func:`agents.checkpoints.save_with_vecnormalize`).

    Parameters
    ----------
    eval_freq : int, default 50000
        Training steps (all envs together) between evaluations.
    n_episodes : int, default 10
        Validation episodes per evaluation.
    first_seed : int, default :data:`agents.protocol.VALIDATION_SEED`
        The first validation seed (the protocol's splits: :mod:`agents.protocol`).
    save_path : str, optional
        Folder of the outputs; default: the run's folder (:func:`run_folder`;
        ``agents.train`` sets it). Where neither is known (rl-zoo3 with
        ``--vec-env subproc``, or its Optuna trials, which log nothing), the
        callback warns once and validates and logs without writing files.
    env_id : str, optional
        The env to validate on; default: the training env's id.
    env_kwargs : dict, optional
        Its keyword arguments; default: those of the training env (with its
        ``max_episode_steps``).
    deterministic : bool, default True
    verbose : int, default 1
        1 prints one line per evaluation.

    Raises
    ------
    TypeError
        If a count is not an int, ``save_path`` not a path, ``env_id`` not a string, ``env_kwargs``
        not a mapping or ``deterministic`` not a bool.
    ValueError
        If ``eval_freq`` or ``n_episodes`` is below 1, or ``first_seed`` below 0.
    """

    def __init__(
        self,
        eval_freq: int = 50_000,
        n_episodes: int = 10,
        first_seed: int = VALIDATION_SEED,
        save_path: str | os.PathLike | None = None,
        env_id: str | None = None,
        env_kwargs: Mapping[str, Any] | None = None,
        deterministic: bool = True,
        verbose: int = 1,
    ) -> None:
        super().__init__(verbose=verbose)
        self.eval_freq = _check_int("eval_freq", eval_freq, 1)
        self.n_episodes = _check_int("n_episodes", n_episodes, 1)
        self.first_seed = _check_int("first_seed", first_seed, 0)
        if save_path is not None and not isinstance(save_path, (str, os.PathLike)):
            raise TypeError(f"save_path must be a path, got {type(save_path).__name__}")
        if env_id is not None and not isinstance(env_id, str):
            raise TypeError(f"env_id must be a str, got {type(env_id).__name__}")
        if env_kwargs is not None and not isinstance(env_kwargs, Mapping):
            raise TypeError(f"env_kwargs must be a mapping, got {type(env_kwargs).__name__}")
        if not isinstance(deterministic, bool):
            raise TypeError(f"deterministic must be a bool, got {type(deterministic).__name__}")
        self.save_path = Path(save_path) if save_path is not None else None
        self.env_id = env_id
        self.env_kwargs = dict(env_kwargs) if env_kwargs is not None else None
        self.deterministic = deterministic
        self.best_map_error = math.inf
        self.best_timesteps: int | None = None
        self.evaluations: list[dict[str, float | int]] = []
        self._next_eval = self.eval_freq
        self._last_eval: int | None = None
        self._env: gym.Env | None = None
        self._restored: dict[str, Any] | None = None  # load_state_dict's, taken when training starts

    @property
    def seeds(self) -> list[int]:
        """The validation seeds, the same at every evaluation."""
        return list(range(self.first_seed, self.first_seed + self.n_episodes))

    @property
    def best_model_path(self) -> Path:
        """Where the best model is (or will be) saved."""
        if self.save_path is None:
            raise ValueError("MapErrorEvalCallback has no save_path (none given and no run folder found)")
        return self.save_path / "best_map_error" / "model.zip"

    def _init_callback(self) -> None:
        if self.save_path is None:
            self.save_path = run_folder(self.training_env)
        if self.save_path is None:
            warnings.warn(
                "MapErrorEvalCallback: no save_path and no monitor log of the training env shows the run's folder; "
                "validating without saving the best model (give the callback a save_path to keep it)",
                stacklevel=2,
            )
        else:
            self.save_path.mkdir(parents=True, exist_ok=True)
        if self.env_id is None or self.env_kwargs is None:
            spec = self.training_env.get_attr("spec", [0])[0]
            if spec is None:
                raise ValueError(
                    "MapErrorEvalCallback: env_id and env_kwargs are needed (the training env has no spec)"
                )
            if self.env_id is None:
                self.env_id = spec.id
            if self.env_kwargs is None:
                # the training env's own arguments; rendering is no part of the task
                self.env_kwargs = {k: v for k, v in spec.kwargs.items() if k != "render_mode"}
                self.env_kwargs.setdefault("max_episode_steps", spec.max_episode_steps)
        self._next_eval = self.num_timesteps + self.eval_freq
        restored, self._restored = self._restored, None
        if restored is not None:
            self._next_eval = int(restored["next_eval"])
            if self.save_path is not None:
                self._restore_files(restored)

    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs of the validation so far (saved with each checkpoint).

        Keys: ``best_map_error``, ``best_timesteps``, ``evaluations`` (the rows written), ``next_eval``
        and ``last_eval`` (the step counts of the next and the last validation), and ``best_model`` and
        ``best_vecnormalize``: the bytes of the best model's files as they are now (``None`` for none),
        because a later best replaces them before a resume could look back.
        """
        files: dict[str, bytes | None] = {"best_model": None, "best_vecnormalize": None}
        if self.save_path is not None and self.best_model_path.is_file():
            files["best_model"] = self.best_model_path.read_bytes()
            stats = self.best_model_path.with_name("vecnormalize.pkl")
            files["best_vecnormalize"] = stats.read_bytes() if stats.is_file() else None
        return {
            "best_map_error": self.best_map_error,
            "best_timesteps": self.best_timesteps,
            "evaluations": [dict(row) for row in self.evaluations],
            "next_eval": self._next_eval,
            "last_eval": self._last_eval,
            **files,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Take :meth:`state_dict`'s ``state`` (a resumed run).

        The best score, the rows and the last validation's step count now; when training starts, the
        next validation's step count, the best model's files (``best_map_error/``, as they were at the
        checkpoint) and ``map_error_evaluations.csv`` (its rows up to the checkpoint).
        """
        self.best_map_error = float(state["best_map_error"])
        self.best_timesteps = state["best_timesteps"]
        self.evaluations = [dict(row) for row in state["evaluations"]]
        self._last_eval = state["last_eval"]
        self._restored = dict(state)

    def _restore_files(self, state: Mapping[str, Any]) -> None:
        """The best model's files and the CSV of the rows as :meth:`state_dict` saw them."""
        from agents.checkpoints import atomic_write
        from seif_gym._atomic import atomic_write_bytes

        assert self.save_path is not None
        for path, content in (
            (self.best_model_path, state["best_model"]),
            (self.best_model_path.with_name("vecnormalize.pkl"), state["best_vecnormalize"]),
        ):
            if content is None:
                path.unlink(missing_ok=True)  # a best found after the checkpoint: the resumed run finds it again
            elif not path.is_file() or path.read_bytes() != content:
                path.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_bytes(path, content)

        def write(temporary: Path) -> None:
            with open(temporary, "w", newline="") as handle:
                writer = csv.DictWriter(handle, fieldnames=EVAL_COLUMNS)
                writer.writeheader()
                writer.writerows(self.evaluations)

        atomic_write(self.save_path / "map_error_evaluations.csv", write)

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next_eval:
            self.evaluate()
            while self._next_eval <= self.num_timesteps:
                self._next_eval += self.eval_freq
        return True

    def _on_training_end(self) -> None:
        # rl-zoo3 calls the first callback's on_training_end a second time: evaluate each moment once
        if self._last_eval != self.num_timesteps:
            self.evaluate()
        if self._env is not None:
            self._env.close()
            self._env = None

    def evaluate(self) -> dict[str, float | int]:
        """Run the validation episodes now; log, write and keep the best.

        Returns
        -------
        dict
            The row written, keys :data:`EVAL_COLUMNS`.

        Raises
        ------
        ValueError
            If the env to validate on is not known yet (before training starts, without ``env_id``).
        """
        from agents.evaluate import make_evaluation_env, run_episode  # the evaluation's own env, loop and metrics

        self.num_timesteps = int(self.model.num_timesteps)  # also when called outside a step
        if self._env is None:
            if self.env_id is None:
                raise ValueError("MapErrorEvalCallback: env_id is not known before training starts")
            self._env = make_evaluation_env(self.env_id, self.env_kwargs or {})
        policy = _NormalizedPolicy(self.model, self.deterministic, self._env)
        # run_episode asks only for predict (and reset, if there is one) of its agent
        rows = [run_episode(policy, self._env, seed)[0] for seed in self.seeds]  # type: ignore[arg-type]
        errors = np.array([row["final_map_error"] for row in rows])
        ci95 = _t_half_width(errors)
        row: dict[str, float | int] = {
            "timesteps": int(self.num_timesteps),
            "final_map_error": float(errors.mean()),
            "final_map_error_ci95": ci95,
            "landmarks_mapped": float(np.mean([r["landmarks_mapped"] for r in rows])),
            "landmarks_total": float(np.mean([r["landmarks_total"] for r in rows])),
            "pose_rmse": float(np.mean([r["pose_rmse"] for r in rows])),
            "best": int(errors.mean() < self.best_map_error),
        }
        if row["best"]:
            self.best_map_error = float(errors.mean())
            self.best_timesteps = int(self.num_timesteps)
        self.evaluations.append(row)
        self._last_eval = self.num_timesteps
        if self.save_path is not None:
            if row["best"]:
                save_with_vecnormalize(self.model, self.best_model_path)
            self._write_row(row)
        for key in ("final_map_error", "final_map_error_ci95", "landmarks_mapped", "pose_rmse"):
            self.logger.record(f"eval/{key}", row[key])
        self.logger.record("eval/best_final_map_error", self.best_map_error)
        self.logger.dump(self.num_timesteps)
        if self.verbose >= 1:
            print(
                f"validation at {self.num_timesteps} steps ({self.n_episodes} seeds from {self.first_seed}): "
                f"final map error {row['final_map_error']:.3f} ± {ci95:.3f} m, "
                f"{row['landmarks_mapped']:.1f}/{row['landmarks_total']:.0f} landmarks, "
                f"pose RMSE {row['pose_rmse']:.3f} m"
                + (" (best so far)" if row["best"] else f" (best {self.best_map_error:.3f} m at {self.best_timesteps})")
            )
        return row

    def _write_row(self, row: Mapping[str, float | int]) -> None:
        assert self.save_path is not None
        path = self.save_path / "map_error_evaluations.csv"
        new = not path.exists() or len(self.evaluations) == 1
        with open(path, "w" if new else "a", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=EVAL_COLUMNS)
            if new:
                writer.writeheader()
            writer.writerow(row)


class ResumableCheckpointCallback(BaseCallback):
    """Checkpoints a run resumes from: between rollouts, every ``save_freq`` steps and at the end of training.

    A checkpoint is taken when a rollout starts (after the previous rollout's
    update) once the step count has reached the next multiple of
    ``save_freq``, and when training ends if it has: the moment between two
    updates, when no rollout is half collected, so that a run resumed from it
    takes the same steps as one that went on. Each is
    :func:`agents.checkpoints.save_checkpoint`: ``PREFIX_<N>_steps.zip`` (weights,
    optimizer, step count), its ``VecNormalize`` statistics, the replay buffer
    (``save_replay_buffer``), and a state file with the global random states,
    the envs' episodes under way (:func:`agents.checkpoints.training_state`), the
    seconds trained, and the ``state_dict()`` of each callback of ``callbacks``
    that has one (by position and class), written last: a checkpoint is
    complete once its state file is there.

    Parameters
    ----------
    save_freq : int
        Steps (all envs together) between checkpoints.
    save_path : str or PathLike
        The run's folder.
    name_prefix : str, default ``"rl_model"``
    callbacks : sequence of BaseCallback, optional
        The run's other callbacks, whose states go with each checkpoint (the list is read at each save).
    save_replay_buffer : bool, default False
    verbose : int, default 0
        1 warns once when the envs' state cannot be kept (a resumed run would start new episodes),
        2 also prints a line per checkpoint.

    Raises
    ------
    TypeError
        If ``save_freq`` is not an int or ``save_path`` not a path.
    ValueError
        If ``save_freq`` is below 1.
    """

    def __init__(
        self,
        save_freq: int,
        save_path: str | os.PathLike,
        name_prefix: str = "rl_model",
        callbacks: Sequence[BaseCallback] = (),
        save_replay_buffer: bool = False,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose=verbose)
        self.save_freq = _check_int("save_freq", save_freq, 1)
        if not isinstance(save_path, (str, os.PathLike)):
            raise TypeError(f"save_path must be a path, got {type(save_path).__name__}")
        self.save_path = Path(save_path)
        self.name_prefix = name_prefix
        self.callbacks = callbacks
        self.save_replay_buffer = bool(save_replay_buffer)
        #: seconds trained before this session (a resumed run's), added to this session's in each checkpoint
        self.seconds_before = 0.0
        self._started = time.perf_counter()
        self._next_save = self.save_freq
        self._last_saved: int | None = None

    def _init_callback(self) -> None:
        self.save_path.mkdir(parents=True, exist_ok=True)
        self._next_save = (int(self.model.num_timesteps) // self.save_freq + 1) * self.save_freq

    def _on_training_start(self) -> None:
        self._started = time.perf_counter()

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        if self.model.num_timesteps >= self._next_save:
            self.save()

    def _on_training_end(self) -> None:
        # rl-zoo3 calls the first callback's on_training_end a second time: save each moment once
        if self.model.num_timesteps >= self._next_save and self._last_saved != self.model.num_timesteps:
            self.save()

    def callback_states(self) -> dict[str, Any]:
        """The ``state_dict()`` of each callback of ``callbacks`` that has one, keyed ``"<position>:<class>"``."""
        return {
            f"{i}:{type(callback).__qualname__}": getattr(callback, "state_dict")()  # noqa: B009 (optional method)
            for i, callback in enumerate(self.callbacks)
            if callback is not self and callable(getattr(callback, "state_dict", None))
        }

    def save(self) -> Path:
        """Save a checkpoint now; the model's path."""
        from agents.checkpoints import save_checkpoint, training_state

        steps = int(self.model.num_timesteps)
        state = training_state(self.model, self.save_path)
        if state["env_note"] is not None and self._last_saved is None and self.verbose >= 1:
            warnings.warn(
                f"checkpoints: a resumed run will start new episodes, not continue these: {state['env_note']}",
                stacklevel=2,
            )
        state["callbacks"] = self.callback_states()
        state["seconds"] = self.seconds_before + time.perf_counter() - self._started
        checkpoint = save_checkpoint(
            self.model, self.save_path, steps, state, replay_buffer=self.save_replay_buffer, prefix=self.name_prefix
        )
        self._last_saved = steps
        self._next_save = (steps // self.save_freq + 1) * self.save_freq
        if self.verbose >= 2:
            print(f"checkpoint at {steps} steps: {checkpoint.model}")
        return checkpoint.model


def restore_callback_states(callbacks: Sequence[BaseCallback], states: Mapping[str, Any]) -> list[str]:
    """Give each callback of ``callbacks`` its state of :meth:`ResumableCheckpointCallback.callback_states`.

    Returns
    -------
    list of str
        The keys of ``states`` no callback took (the run's callbacks differ from the checkpoint's).
    """
    taken = set()
    for i, callback in enumerate(callbacks):
        key = f"{i}:{type(callback).__qualname__}"
        if key in states and callable(getattr(callback, "load_state_dict", None)):
            getattr(callback, "load_state_dict")(states[key])  # noqa: B009 (optional method)
            taken.add(key)
    return sorted(set(states) - taken)


def _t_half_width(values: np.ndarray, confidence: float = 0.95) -> float:
    """Half-width of Student's t interval of the mean (``nan`` for one value)."""
    if values.size < 2:
        return math.nan
    from scipy import stats

    return float(stats.t.ppf(0.5 + confidence / 2, values.size - 1) * values.std(ddof=1) / math.sqrt(values.size))
