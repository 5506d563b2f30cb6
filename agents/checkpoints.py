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
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["behaviour_fingerprint", "load_vecnormalize_stats", "save_with_vecnormalize", "vecnormalize_path"]

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
        (so give each such model a folder of its own).

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
    model.save(path)
    vec_normalize = model.get_vec_normalize_env()
    if vec_normalize is None:
        return path, None
    match = _CHECKPOINT.fullmatch(path.stem)
    name = f"{match['prefix']}_vecnormalize_{match['steps']}_steps.pkl" if match else "vecnormalize.pkl"
    stats_path = path.with_name(name)
    vec_normalize.save(str(stats_path))
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
