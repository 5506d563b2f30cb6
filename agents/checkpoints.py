"""Where a saved model's ``VecNormalize`` statistics live, and saving the two together.

A model trained with ``normalize`` acts on normalised observations, so a
checkpoint is only usable with the statistics of the same moment. Three
layouts are in use, and :func:`vecnormalize_path` knows all three:

==========================================  ==============================================
model                                       statistics
==========================================  ==============================================
``DIR/PREFIX_<N>_steps.zip``                ``DIR/PREFIX_vecnormalize_<N>_steps.pkl``
                                            (SB3's ``CheckpointCallback``, as ``agents.train``
                                            writes checkpoints)
``DIR/model.zip`` (any name not a           ``DIR/vecnormalize.pkl`` (:func:`save_with_vecnormalize`:
checkpoint's)                               the best model of :class:`~agents.callbacks.MapErrorEvalCallback`,
                                            or any model saved the same way)
``RUN/<EnvId>.zip``                         ``RUN/<EnvId>/vecnormalize.pkl`` (rl-zoo3's final model)
==========================================  ==============================================

A checkpoint's name never falls back to another file: statistics of a later
moment would be applied silently. rl-zoo3's own ``best_model.zip`` and
``rl_model_<N>_steps.zip`` (``--save-freq``) have no statistics of their own
(rl-zoo3 keeps one ``vecnormalize.pkl`` per run, overwritten at the end), so
none is found for them.

>>> from pathlib import Path
>>> vecnormalize_path(Path("/nonexistent/rl_model_1000_steps.zip")) is None
True
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import pickle
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seif_gym._atomic import atomic_write, remove_temporaries

__all__ = [
    "CHECKPOINT_PREFIX",
    "Checkpoint",
    "atomic_write",
    "behaviour_fingerprint",
    "checkpoint_files",
    "load_vecnormalize_stats",
    "newest_complete_checkpoint",
    "read_checkpoint",
    "remove_temporaries",
    "restore_training_state",
    "save_checkpoint",
    "save_with_vecnormalize",
    "training_state",
    "vecnormalize_path",
]

#: The entries of a model's ``data`` that decide what its policy computes (besides the weights).
_POLICY_DATA = ("policy_class", "policy_kwargs", "observation_space", "action_space")

#: SB3's ``CheckpointCallback`` names: ``{prefix}_{steps}_steps.zip`` and ``{prefix}_vecnormalize_{steps}_steps.pkl``.
_CHECKPOINT = re.compile(r"(?P<prefix>.+)_(?P<steps>\d+)_steps")


def _as_path(model_path: str | os.PathLike, name: str = "model_path") -> Path:
    if not isinstance(model_path, (str, os.PathLike)):
        raise TypeError(f"{name} must be a path, got {type(model_path).__name__}")
    path = Path(model_path)
    if path.suffix != ".zip":
        raise ValueError(f"{name} must name a model's .zip, got {str(path)!r}")
    return path


def vecnormalize_path(model_path: str | os.PathLike) -> Path | None:
    """The ``VecNormalize`` statistics saved with the model at ``model_path``, or ``None``.

    Parameters
    ----------
    model_path : str or PathLike
        A saved SB3 model (``.zip``).

    Returns
    -------
    Path or None
        The statistics' ``.pkl`` by the rules of this module's table, if that file exists.

    Raises
    ------
    TypeError
        If ``model_path`` is not a path.
    ValueError
        If ``model_path`` does not end in ``.zip``.
    """
    path = _as_path(model_path)
    match = _CHECKPOINT.fullmatch(path.stem)
    if match is not None:
        candidates = [path.with_name(f"{match['prefix']}_vecnormalize_{match['steps']}_steps.pkl")]
    else:
        candidates = [path.with_name("vecnormalize.pkl"), path.parent / path.stem / "vecnormalize.pkl"]
    return next((candidate for candidate in candidates if candidate.is_file()), None)


def save_with_vecnormalize(model: Any, model_path: str | os.PathLike) -> tuple[Path, Path | None]:
    """Save ``model`` at ``model_path``, and its ``VecNormalize`` where :func:`vecnormalize_path` finds it.

    Parameters
    ----------
    model : stable_baselines3.common.base_class.BaseAlgorithm
        A model; its ``get_vec_normalize_env()`` (if any) is saved beside it.
    model_path : str or PathLike
        Where the model goes (``.zip``). A checkpoint name (``PREFIX_<N>_steps.zip``) gets
        ``PREFIX_vecnormalize_<N>_steps.pkl``; any other name ``vecnormalize.pkl`` in its folder
        (so give each such model a folder of its own). Each file is written whole or not at all
        (:func:`atomic_write`): a save killed midway leaves the previous file in place.

    Returns
    -------
    model_path : Path
    stats_path : Path or None
        ``None`` when the model trains without ``VecNormalize``.

    Raises
    ------
    TypeError
        If ``model_path`` is not a path or ``model`` is not an SB3 model.
    ValueError
        If ``model_path`` does not end in ``.zip``.
    """
    path = _as_path(model_path)
    if not callable(getattr(model, "save", None)) or not callable(getattr(model, "get_vec_normalize_env", None)):
        raise TypeError(f"model must be an SB3 model, got {type(model).__name__}")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda temporary: model.save(temporary))
    vec_normalize = model.get_vec_normalize_env()
    if vec_normalize is None:
        return path, None
    match = _CHECKPOINT.fullmatch(path.stem)
    name = f"{match['prefix']}_vecnormalize_{match['steps']}_steps.pkl" if match else "vecnormalize.pkl"
    stats_path = path.with_name(name)
    atomic_write(stats_path, lambda temporary: vec_normalize.save(str(temporary)))
    return path, stats_path


def load_vecnormalize_stats(stats_path: str | os.PathLike) -> Any:
    """The ``VecNormalize`` pickled at ``stats_path``, without an env (its ``obs_rms``, ``ret_rms``, flags).

    ``VecNormalize.load`` needs a venv to wrap; copying the running statistics into an
    existing ``VecNormalize`` (``--init-from``) needs only the object.

    Raises
    ------
    TypeError
        If ``stats_path`` is not a path.
    FileNotFoundError
        If it does not exist.
    """
    if not isinstance(stats_path, (str, os.PathLike)):
        raise TypeError(f"stats_path must be a path, got {type(stats_path).__name__}")
    with open(stats_path, "rb") as handle:
        return pickle.load(handle)  # noqa: S301 (our own training output, as VecNormalize.load)


#: Fields of a gymnasium space that are state, not definition: its generator, and the strings a ``Box``
#: (gymnasium >= 1.3) caches once it has been printed.
_NOT_DEFINITION = frozenset({"_np_random", "low_repr", "high_repr"})


def _definition(value: Any) -> Any:
    """``value`` as JSON: arrays by dtype, shape and bytes, spaces by their fields less :data:`_NOT_DEFINITION`."""
    if isinstance(value, np.ndarray):
        return [str(value.dtype), list(value.shape), value.tobytes().hex()]
    if isinstance(value, dict):
        return {str(key): _definition(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_definition(item) for item in value]
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    if hasattr(value, "__dict__") and type(value).__module__.startswith("gymnasium.spaces"):
        fields = {key: item for key, item in vars(value).items() if key not in _NOT_DEFINITION}
        return {"type": type(value).__qualname__, "fields": _definition(fields)}
    return repr(value)


def _space_definition(entry: Any) -> Any:
    """A space saved in a model's ``data`` (SB3's JSON of it) as its definition without random state.

    SB3 pickles the whole space, generator and caches included: the generator
    moves when the space is seeded or sampled, and gymnasium 1.3 on caches a
    ``Box``'s bounds as text once it is printed, so two saves of one policy
    would digest differently.
    """
    if not isinstance(entry, dict) or ":serialized:" not in entry:
        return entry
    import base64

    return _definition(pickle.loads(base64.b64decode(entry[":serialized:"])))  # noqa: S301  (SB3 loads it too)


def behaviour_fingerprint(model_path: str | os.PathLike) -> str:
    """A digest of everything that decides the actions of the model at ``model_path`` when it is evaluated.

    Two saves of one policy differ byte for byte when the training state saved
    beside it differs (step count, last observation, episode buffer, optimizer),
    so the digest is taken over what the policy computes with: the tensors of
    ``policy.pth`` (names, dtypes, shapes, values), the policy's class, keyword
    arguments and spaces from the model's ``data``, and the observation
    normalisation of the statistics :func:`vecnormalize_path` finds (``obs_rms``,
    ``clip_obs``, ``epsilon``, the normalised keys) when they normalise
    observations at all. Statistics that normalise only the reward, and no
    statistics, digest the same: evaluation never normalises rewards.

    Parameters
    ----------
    model_path : str or PathLike
        The model to digest; its statistics are found beside it.

    Returns
    -------
    str
        A SHA-256 hex digest. Equal digests mean the same deterministic actions on
        the same observations: the callback's best model is often the run's final
        model or its last checkpoint saved again, and ``research.select`` scores such
        a candidate once.

    Raises
    ------
    TypeError
        If ``model_path`` is not a path.
    ValueError
        If it does not end in ``.zip`` or is not a saved SB3 model.
    """
    path = _as_path(model_path)
    import torch

    digest = hashlib.sha256()
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
            weights = torch.load(io.BytesIO(archive.read("policy.pth")), map_location="cpu", weights_only=True)
    except (OSError, KeyError, zipfile.BadZipFile, ValueError) as error:
        raise ValueError(f"model_path: {str(path)!r} is not a saved SB3 model ({error})") from error
    for key in _POLICY_DATA:
        value = data.get(key)
        if key.endswith("_space"):  # the space's definition, not its random generator's state (pickled with it)
            value = _space_definition(value)
        elif isinstance(value, dict) and ":serialized:" in value:
            # the pickled reference alone: SB3's readable fields print objects with their addresses in memory,
            # which differ from one process to the next
            value = value[":serialized:"]
        digest.update(json.dumps([key, value], sort_keys=True).encode())
    for name in sorted(weights):
        tensor = weights[name].detach().cpu().contiguous()
        digest.update(f"{name}|{tensor.dtype}|{tuple(tensor.shape)}|".encode())
        digest.update(tensor.flatten().view(torch.uint8).numpy().tobytes())  # the raw bytes, whatever the dtype
    stats_path = vecnormalize_path(path)
    # a pickled VecNormalize without its venv: read its fields from __dict__ (getattr recurses into the venv)
    stats = None if stats_path is None else vars(load_vecnormalize_stats(stats_path))
    if stats is not None and stats.get("norm_obs"):
        digest.update(repr(("obs", stats.get("clip_obs"), stats.get("epsilon"), stats.get("norm_obs_keys"))).encode())
        obs_rms = stats["obs_rms"]
        keyed: dict[str, Any] = obs_rms if isinstance(obs_rms, dict) else {"": obs_rms}  # Dict or Box spaces
        for key in sorted(keyed):
            moments = keyed[key]
            digest.update(f"{key}|".encode())
            digest.update(np.asarray(moments.mean, dtype=np.float64).tobytes())
            digest.update(np.asarray(moments.var, dtype=np.float64).tobytes())
    else:
        digest.update(b"no observation normalisation")
    return digest.hexdigest()


# -- resumable checkpoints ---------------------------------------------------------------------------
#: The prefix of ``agents.train``'s checkpoints (rl-zoo3's name: ``enjoy --load-checkpoint N`` finds them).
CHECKPOINT_PREFIX = "rl_model"
#: The version of the state files' layout.
STATE_FORMAT = 1
#: The entries of a saved model's ``data`` that are training state, not hyperparameters: restored on resume.
_TRAINING_STATE = (
    "num_timesteps",
    "_episode_num",
    "_n_updates",
    "_n_calls",
    "_last_obs",
    "_last_episode_starts",
    "_last_original_obs",
    "ep_info_buffer",
    "ep_success_buffer",
    "_current_progress_remaining",
)
#: Attributes of a model that SB3 leaves out of its ``.zip`` and a resume needs (sb3-contrib's RecurrentPPO).
_MODEL_EXTRAS = ("_last_lstm_states",)


def checkpoint_files(folder: str | os.PathLike, steps: int, prefix: str = CHECKPOINT_PREFIX) -> dict[str, Path]:
    """The files of checkpoint ``steps`` in ``folder``: ``model``, ``vecnormalize``, ``replay_buffer``, ``state``.

    ``PREFIX_<N>_steps.zip``, ``PREFIX_vecnormalize_<N>_steps.pkl`` and
    ``PREFIX_replay_buffer_<N>_steps.pkl`` are SB3's ``CheckpointCallback`` names;
    ``PREFIX_state_<N>_steps.pkl`` holds what a resume needs besides (:func:`save_checkpoint`).
    """
    folder = Path(folder)
    return {
        "model": folder / f"{prefix}_{steps}_steps.zip",
        "vecnormalize": folder / f"{prefix}_vecnormalize_{steps}_steps.pkl",
        "replay_buffer": folder / f"{prefix}_replay_buffer_{steps}_steps.pkl",
        "state": folder / f"{prefix}_state_{steps}_steps.pkl",
    }


@dataclass(frozen=True)
class Checkpoint:
    """A complete checkpoint: its step count, files and state (:func:`read_checkpoint`)."""

    steps: int
    model: Path
    vecnormalize: Path | None
    replay_buffer: Path | None
    state: dict[str, Any]


def _file_record(path: Path) -> dict[str, Any]:
    """Size and SHA-256 of ``path``, as the state file records each file of its checkpoint."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return {"size": path.stat().st_size, "sha256": digest.hexdigest()}


def save_checkpoint(
    model: Any,
    folder: str | os.PathLike,
    steps: int,
    state: dict[str, Any],
    replay_buffer: bool = False,
    prefix: str = CHECKPOINT_PREFIX,
) -> Checkpoint:
    """Save ``model`` as checkpoint ``steps`` of ``folder``, with its statistics, replay buffer and ``state``.

    The model (``.zip``: weights, optimizer state, step count and SB3's other training state), its
    ``VecNormalize`` (if any), its replay buffer (if ``replay_buffer``; the older checkpoints' buffers are
    deleted once this one is complete, so one buffer stays on disk) and last the state file, which
    records every other file's size and SHA-256: each file is written whole or not at all
    (:func:`atomic_write`), and the state file, written last, marks the checkpoint complete.

    Parameters
    ----------
    model : stable_baselines3.common.base_class.BaseAlgorithm
    folder : str or PathLike
    steps : int
        The checkpoint's step count (``model.num_timesteps``).
    state : dict
        Picklable state of the training around the model (:func:`training_state`, callbacks' states).
    replay_buffer : bool, default False
        Save the model's replay buffer too (off-policy algorithms).
    prefix : str, default :data:`CHECKPOINT_PREFIX`

    Returns
    -------
    Checkpoint

    Raises
    ------
    TypeError
        If ``model`` is not an SB3 model or ``state`` not a dict.
    ValueError
        If ``steps`` is negative, or ``replay_buffer`` is asked of a model without one.
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise ValueError(f"steps must be an int of at least 0, got {steps!r}")
    if not isinstance(state, dict):
        raise TypeError(f"state must be a dict, got {type(state).__name__}")
    if replay_buffer and getattr(model, "replay_buffer", None) is None:
        raise ValueError("replay_buffer: the model has no replay buffer")
    files = checkpoint_files(folder, int(steps), prefix)
    model_path, stats_path = save_with_vecnormalize(model, files["model"])
    buffer_path = None
    if replay_buffer:
        buffer_path = atomic_write(files["replay_buffer"], lambda temporary: model.save_replay_buffer(temporary))
    written = [path for path in (model_path, stats_path, buffer_path) if path is not None]
    record = dict(state, format=STATE_FORMAT, steps=int(steps), files={p.name: _file_record(p) for p in written})
    atomic_write(files["state"], lambda temporary: temporary.write_bytes(pickle.dumps(record, pickle.HIGHEST_PROTOCOL)))
    if replay_buffer:  # one buffer on disk: the newest complete checkpoint's
        for other in Path(folder).glob(f"{prefix}_replay_buffer_*_steps.pkl"):
            match = re.fullmatch(rf"{re.escape(prefix)}_replay_buffer_(\d+)_steps\.pkl", other.name)
            if match is not None and int(match[1]) < steps:
                other.unlink(missing_ok=True)
    return Checkpoint(int(steps), model_path, stats_path, buffer_path, record)


def read_checkpoint(folder: str | os.PathLike, steps: int, prefix: str = CHECKPOINT_PREFIX) -> Checkpoint:
    """Checkpoint ``steps`` of ``folder``, checked complete: its state file reads, and every file it records is there.

    Raises
    ------
    ValueError
        If the checkpoint is incomplete (killed while it was written, or a file changed since), saying why.
    """
    files = checkpoint_files(folder, steps, prefix)
    try:
        with open(files["state"], "rb") as handle:
            state = pickle.load(handle)  # noqa: S301 (this training's own output, as VecNormalize.load)
    except FileNotFoundError:
        raise ValueError(
            f"checkpoint {steps}: no {files['state'].name} (written last: the checkpoint never completed, or predates resumable checkpoints)"
        ) from None
    except Exception as error:  # a truncated or damaged pickle raises anything
        raise ValueError(f"checkpoint {steps}: {files['state'].name} does not read ({type(error).__name__})") from error
    if not isinstance(state, dict) or state.get("format") != STATE_FORMAT or state.get("steps") != steps:
        raise ValueError(f"checkpoint {steps}: {files['state'].name} is not a state file of format {STATE_FORMAT}")
    records = state.get("files", {})
    if files["model"].name not in records:
        raise ValueError(f"checkpoint {steps}: its state file records no model")
    for name, record in records.items():
        path = Path(folder) / name
        if not path.is_file():
            raise ValueError(f"checkpoint {steps}: {name} is missing")
        if path.stat().st_size != record["size"] or _file_record(path) != record:
            raise ValueError(f"checkpoint {steps}: {name} is not the file saved with it (truncated or changed)")
    present = {key: (path if path.name in records else None) for key, path in files.items()}
    return Checkpoint(steps, files["model"], present["vecnormalize"], present["replay_buffer"], state)


def newest_complete_checkpoint(
    folder: str | os.PathLike, prefix: str = CHECKPOINT_PREFIX
) -> tuple[Checkpoint | None, list[str]]:
    """The newest complete checkpoint of ``folder`` (:func:`read_checkpoint`), and why each newer one was passed over.

    Returns
    -------
    checkpoint : Checkpoint or None
        ``None`` when no checkpoint is complete.
    skipped : list of str
        One reason per newer checkpoint found incomplete, newest first.
    """
    pattern = re.compile(rf"{re.escape(prefix)}_(?:state_)?(\d+)_steps\.(?:zip|pkl)")
    found = {int(m[1]) for p in Path(folder).glob(f"{prefix}_*_steps.*") if (m := pattern.fullmatch(p.name))}
    skipped: list[str] = []
    for steps in sorted(found, reverse=True):
        try:
            return read_checkpoint(folder, steps, prefix), skipped
        except ValueError as error:
            skipped.append(str(error))
    return None, skipped


# -- what a checkpoint keeps besides the model ---------------------------------------------------------
def capture_rng() -> dict[str, Any]:
    """The global random states training draws from: Python's ``random``, NumPy's legacy ``np.random``, torch's.

    SB3 samples actions with torch's global generator and shuffles PPO's minibatches (and samples replay
    buffers) with ``np.random``.
    """
    import random

    import torch

    state: dict[str, Any] = {
        "python": random.getstate(),
        "numpy": np.random.get_state(),  # noqa: NPY002 (SB3's own draws use the legacy global state)
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["torch_cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_rng(state: dict[str, Any]) -> None:
    """Set the global random states :func:`capture_rng` took."""
    import random

    import torch

    random.setstate(state["python"])
    np.random.set_state(state["numpy"])  # noqa: NPY002
    torch.set_rng_state(state["torch"])
    if "torch_cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["torch_cuda"])


class _EnvPickler(pickle.Pickler):
    """Pickles a vector env's state with each monitor log's writer by its file's name (an open file pickles not)."""

    def __init__(self, file: Any, writer_type: type) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.writer_type = writer_type

    def persistent_id(self, obj: Any) -> Any:
        if isinstance(obj, self.writer_type):
            return ("results_writer", Path(getattr(obj, "file_handler").name).name)  # noqa: B009 (any writer type)
        return None


class _EnvUnpickler(pickle.Unpickler):
    """Reads :class:`_EnvPickler`'s output with each writer replaced by the live env's writer of that log."""

    def __init__(self, file: Any, writers: dict[str, Any]) -> None:
        super().__init__(file)
        self.writers = writers

    def persistent_load(self, pid: Any) -> Any:
        kind, name = pid
        if kind != "results_writer" or name not in self.writers:
            raise pickle.UnpicklingError(f"the saved envs write the monitor log {name}, which this run's envs do not")
        return self.writers[name]


def _vec_env_layers(venv: Any) -> list[Any]:
    """The vector env and the ones it wraps, outermost first (``VecNormalize``, ``VecMonitor``, ..., the base)."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    layers = [venv]
    while isinstance(layers[-1], VecEnvWrapper):
        layers.append(layers[-1].venv)
    return layers


def results_writers(venv: Any) -> dict[str, Any]:
    """The monitor logs' writers of a vector env, by file name: ``VecMonitor``'s, and each single env's ``Monitor``."""
    from stable_baselines3.common.monitor import ResultsWriter

    writers: dict[str, Any] = {}
    stack, seen = [venv], set()
    while stack:
        obj = stack.pop()
        if id(obj) in seen or not hasattr(obj, "__dict__"):
            continue
        seen.add(id(obj))
        attributes = vars(obj)
        writer = attributes.get("results_writer")
        if isinstance(writer, ResultsWriter):
            writers[Path(writer.file_handler.name).name] = writer
        stack.extend(attributes[key] for key in ("venv", "env") if key in attributes)
        envs = attributes.get("envs")
        if isinstance(envs, list):
            stack.extend(envs)
    return writers


def capture_env_state(venv: Any) -> bytes:
    """The state of a training vector env, pickled: every layer's attributes, the single envs and their wrappers.

    Everything an env carries between steps is kept: the episodes under way
    (world, filter, random generators, step counts), reward wrappers' memories,
    the monitors' running episode sums and ``VecNormalize``'s statistics and
    running returns. The monitors' open log files are kept by name and stay
    those of the env the state is loaded into (:func:`restore_env_state`).

    Raises
    ------
    ValueError
        If the envs run in other processes (``SubprocVecEnv``) or something in them does not pickle.
    """
    from stable_baselines3.common.monitor import ResultsWriter
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecEnvWrapper

    layers = _vec_env_layers(venv)
    if isinstance(layers[-1], SubprocVecEnv):
        raise ValueError("the envs run in other processes (SubprocVecEnv), whose state this process cannot read")
    saved = []
    for layer in layers:
        attributes = vars(layer)
        if isinstance(layer, VecEnvWrapper):
            attributes = {k: v for k, v in attributes.items() if k not in ("venv", "class_attributes")}
        saved.append(attributes)
    buffer = io.BytesIO()
    try:
        _EnvPickler(buffer, ResultsWriter).dump(
            {"types": [type(layer).__qualname__ for layer in layers], "layers": saved}
        )
    except Exception as error:  # whatever an env holds that pickle refuses
        raise ValueError(f"the envs' state does not pickle ({type(error).__name__}: {error})") from error
    return buffer.getvalue()


def restore_env_state(venv: Any, blob: bytes) -> None:
    """Load :func:`capture_env_state`'s ``blob`` into ``venv``, an env built as the one it was taken from.

    Each layer keeps its identity (the model's references stay valid) and takes the saved attributes;
    the monitors keep writing to ``venv``'s own log files.

    Raises
    ------
    ValueError
        If ``venv``'s layers are not those of the saved env, or the saved monitors' logs are not ``venv``'s.
    """
    layers = _vec_env_layers(venv)
    try:
        state = _EnvUnpickler(io.BytesIO(blob), results_writers(venv)).load()
    except pickle.UnpicklingError as error:
        raise ValueError(str(error)) from error
    types = [type(layer).__qualname__ for layer in layers]
    if state["types"] != types:
        raise ValueError(f"the saved envs are {' > '.join(state['types'])}, this run's {' > '.join(types)}")
    for layer, attributes in zip(layers, state["layers"], strict=True):
        layer.__dict__.update(attributes)


def monitor_sizes(folder: str | os.PathLike) -> dict[str, int]:
    """The byte size of each monitor log (``*monitor.csv``) in ``folder``: how far the logs had got at a checkpoint."""
    return {path.name: path.stat().st_size for path in Path(folder).glob("*monitor.csv")}


def restore_monitor_logs(venv: Any, logs: dict[str, bytes], sizes: dict[str, int]) -> list[str]:
    """Put back the monitor logs' rows up to a checkpoint into the logs ``venv``'s monitors just opened (and emptied).

    Parameters
    ----------
    venv : VecEnv
        The training env, built afresh (its monitors opened their logs for writing, which emptied them).
    logs : dict
        Each log's content before the env was built, by file name.
    sizes : dict
        Each log's size at the checkpoint (:func:`monitor_sizes`): the rows written after it are dropped
        (the resumed run writes them again).

    Returns
    -------
    list of str
        The logs restored.
    """
    restored = []
    for name, writer in results_writers(venv).items():
        if name in logs and name in sizes:
            handle = writer.file_handler
            handle.seek(0)
            handle.truncate()
            handle.write(logs[name][: sizes[name]].decode())
            handle.flush()
            restored.append(name)
    return restored


def training_state(model: Any, folder: str | os.PathLike) -> dict[str, Any]:
    """What a resume needs besides the model's ``.zip``, its statistics and replay buffer, as a picklable dict.

    Keys: ``rng`` (:func:`capture_rng`), ``action_space_rng`` (the state of the model's action space's
    generator, which off-policy warm-up samples from), ``model`` (attributes SB3 leaves out of its
    ``.zip``: RecurrentPPO's LSTM states), ``env`` (:func:`capture_env_state`, ``None`` when it cannot
    be taken) with ``env_note`` (why not), and ``monitor_sizes`` (:func:`monitor_sizes` of ``folder``).
    """
    generator = getattr(model.action_space, "_np_random", None)
    state: dict[str, Any] = {
        "rng": capture_rng(),
        "action_space_rng": None if generator is None else generator.bit_generator.state,
        "model": {key: getattr(model, key) for key in _MODEL_EXTRAS if getattr(model, key, None) is not None},
        "env": None,
        "env_note": None,
        "monitor_sizes": monitor_sizes(folder),
    }
    try:
        state["env"] = capture_env_state(model.get_env())
    except ValueError as error:
        state["env_note"] = str(error)
    return state


def restore_training_state(model: Any, checkpoint: Checkpoint, monitor_logs: dict[str, bytes] | None = None) -> str:
    """Load a checkpoint into ``model``, built with the run's configuration and envs: all but the global random states.

    Restored: the weights and optimizer states (and SB3's other torch variables, such as SAC's entropy
    coefficient), the step count and SB3's training state from the ``.zip`` (last observation,
    episode starts, episode buffers, update count), the replay buffer, the ``VecNormalize``
    statistics, the action space's generator, RecurrentPPO's LSTM states, and the envs' episodes under
    way (:func:`restore_env_state`) with the monitor logs up to the checkpoint. When the envs' state
    was not saved (or does not fit), the envs start new episodes instead. The global random states
    (:func:`restore_rng` of ``checkpoint.state["rng"]``) are the caller's to set, right before learning.

    Returns
    -------
    str
        What became of the envs: ``"restored"``, or why they start new episodes.

    Raises
    ------
    ValueError
        If the checkpoint holds another algorithm or policy, or another number of envs.
    """
    from stable_baselines3.common.save_util import load_from_zip_file, recursive_setattr

    data, params, variables = load_from_zip_file(checkpoint.model, device=model.device)
    if data is None or params is None:
        raise ValueError(f"{checkpoint.model} holds no model")
    saved_policy = data.get("policy_class")
    if saved_policy is not None and saved_policy is not type(model.policy):
        raise ValueError(
            f"{checkpoint.model} holds a {saved_policy.__name__}, this run a {type(model.policy).__name__}"
        )
    if data.get("n_envs", model.n_envs) != model.n_envs:
        raise ValueError(f"{checkpoint.model} trained {data['n_envs']} envs, this run has {model.n_envs}")
    model.set_parameters(params, exact_match=True, device=model.device)
    for name, value in (variables or {}).items():
        if value is not None:
            recursive_setattr(model, f"{name}.data", value.data)
    for key in _TRAINING_STATE:
        if key in data:
            setattr(model, key, data[key])
    state = checkpoint.state
    if state.get("action_space_rng") is not None:
        model.action_space.np_random.bit_generator.state = state["action_space_rng"]
    if checkpoint.replay_buffer is not None:
        model.load_replay_buffer(checkpoint.replay_buffer)
    vec_normalize = model.get_vec_normalize_env()
    if checkpoint.vecnormalize is not None and vec_normalize is not None:
        saved = vars(load_vecnormalize_stats(checkpoint.vecnormalize))  # no venv: its fields, not its getattr
        for key in ("obs_rms", "ret_rms"):
            if key in saved:
                setattr(vec_normalize, key, saved[key])
    note = state.get("env_note") or "no state of the envs was saved"
    if state.get("env") is not None:
        try:
            restore_env_state(model.get_env(), state["env"])
            note = "restored"
        except ValueError as error:
            note = str(error)
    if note == "restored":  # the episodes go on: so do the recurrent states
        for key, value in state.get("model", {}).items():
            setattr(model, key, value)
    else:  # the envs start afresh: SB3 resets them when learning starts
        model._last_obs = None
    if monitor_logs:
        restore_monitor_logs(model.get_env(), monitor_logs, state.get("monitor_sizes", {}))
    return note
