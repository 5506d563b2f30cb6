"""Ship a chosen model into ``agents/policies``: the weights, their statistics and the recipe's record.

Usage::

    python -m research.ship RUN/selected/model.zip NAME --config RUN/<EnvId>/config.yml

writes

==============================  =================================================================
``agents/policies/NAME.zip``    the model, its optimizer's moments emptied (see below)
``NAME/vecnormalize.pkl``       the model's ``VecNormalize`` statistics, where
                                :func:`agents.checkpoints.vecnormalize_path` finds them
``NAME/config.yml``             ``--config``: rl-zoo3's record of the hyperparameters that trained it
``NAME/command.txt``            rl-zoo3's record of the command line, where it lies beside ``--config``
                                (the steps, seed and ``--mix-env`` that ``config.yml`` does not hold)
``NAME/selection.json``         the model folder's ``selection.json`` if it has one
                                (``research.select``: what was chosen from what, on which seeds)
==============================  =================================================================

An SB3 ``.zip`` carries the Adam optimizer's state with the weights; its
first and second moments are twice the weights' size and only matter for
going on training. Shipping keeps the optimizer's parameter groups (so
``--init-from`` still loads the model; its Adam restarts from zero moments)
and empties the moments: a recurrent policy of the benchmark is 4.7 MB
instead of 14. Acting is unchanged (the test loads both and compares actions).

A name already shipped is refused unless ``--force``; nothing is written
until every input has been read, and a failure midway leaves
``agents/policies`` as it was. Registering the policy for the leaderboard
(``agents.benchmark.SHIPPED_POLICIES``) stays a reviewed edit of the code.
"""

from __future__ import annotations

import argparse
import io
import os
import re
import shutil
import sys
import tempfile
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from agents.checkpoints import vecnormalize_path
from agents.loading import POLICY_DIR

__all__ = [
    "OPTIMIZER_ENTRY",
    "POLICY_ENTRY",
    "CRITIC_PREFIXES",
    "empty_optimizer_moments",
    "for_acting",
    "main",
    "ship",
]

#: The member of an SB3 ``.zip`` that holds the optimizer's ``state_dict``.
OPTIMIZER_ENTRY = "policy.optimizer.pth"
#: The member of an SB3 ``.zip`` that holds the policy's ``state_dict``.
POLICY_ENTRY = "policy.pth"
#: ``state_dict`` keys of an actor-critic policy that only the value function reads (SB3's
#: ``MultiInputPolicy`` with separate extractors, sb3-contrib's recurrent policy with a critic LSTM).
CRITIC_PREFIXES = ("vf_features_extractor.", "mlp_extractor.value_net.", "value_net.", "lstm_critic.")
_NAME = re.compile(r"[a-z][a-z0-9_]*")


def _rewrite_state(model_zip: bytes, entry: str, change: Callable[[dict[str, Any]], None]) -> bytes:
    """``model_zip`` with the torch ``state_dict`` of member ``entry`` changed in place by ``change``.

    Every other member is copied as it is (with its own ``ZipInfo``).

    Raises
    ------
    TypeError
        If ``model_zip`` is not bytes.
    ValueError
        If it is not a zip archive holding ``entry``.
    """
    import torch

    if not isinstance(model_zip, (bytes, bytearray)):
        raise TypeError(f"model_zip must be bytes, got {type(model_zip).__name__}")
    try:
        source = zipfile.ZipFile(io.BytesIO(model_zip))
    except zipfile.BadZipFile:
        raise ValueError("model_zip: not a zip archive") from None
    with source:
        if entry not in source.namelist():
            raise ValueError(f"model_zip: no {entry} (not an SB3 model)")
        out = io.BytesIO()
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as target:
            for item in source.infolist():
                data = source.read(item.filename)
                if item.filename == entry:
                    state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
                    change(state)
                    buffer = io.BytesIO()
                    torch.save(state, buffer)
                    data = buffer.getvalue()
                target.writestr(item, data)
    return out.getvalue()


def empty_optimizer_moments(model_zip: bytes) -> bytes:
    """The SB3 model archive ``model_zip`` with its optimizer's per-parameter state emptied.

    Parameters
    ----------
    model_zip : bytes
        The bytes of a saved SB3 model (``model.save``).

    Returns
    -------
    bytes
        The same archive, member for member, except ``policy.optimizer.pth``, whose
        ``state`` (Adam's step counts and moments) is ``{}``; its ``param_groups`` stay.

    Raises
    ------
    TypeError
        If ``model_zip`` is not bytes.
    ValueError
        If it is not a zip archive holding ``policy.optimizer.pth``.
    """

    def empty(state: dict[str, Any]) -> None:
        state["state"] = {}

    return _rewrite_state(model_zip, OPTIMIZER_ENTRY, empty)


def for_acting(model_zip: bytes) -> bytes:
    """``model_zip`` as a policy that acts: optimizer moments emptied and the value function zeroed.

    Acting (``predict``) reads the actor alone: the features extractor of the policy, the policy
    network, the action net and, for a recurrent policy, the actor's LSTM. The value function's
    tensors (:data:`CRITIC_PREFIXES`, but those that share their storage with the actor's) keep their
    shapes, so Stable-Baselines3 still loads the file, but hold zeros, which compress to nothing: the
    file acts exactly as the original and is no starting point for further training (its value
    function and optimizer restart from zero).

    Raises
    ------
    TypeError, ValueError
        As :func:`empty_optimizer_moments`; ``ValueError`` if no tensor of the value function is found.
    """
    import torch

    def zero_critic(state: dict[str, Any]) -> None:
        # a tensor the actor shares (the extractors may share layers) stays as it is
        actor = {v.untyped_storage().data_ptr() for k, v in state.items() if not k.startswith(CRITIC_PREFIXES)}
        critic = [
            k for k, v in state.items() if k.startswith(CRITIC_PREFIXES) and v.untyped_storage().data_ptr() not in actor
        ]
        if not critic:
            raise ValueError("model_zip: no value-function tensors (not an actor-critic policy)")
        for key in critic:
            state[key] = torch.zeros_like(state[key])

    return _rewrite_state(empty_optimizer_moments(model_zip), POLICY_ENTRY, zero_critic)


def _check_path(value: object, name: str) -> Path:
    if not isinstance(value, (str, os.PathLike)):
        raise TypeError(f"{name} must be a path, got {type(value).__name__}")
    path = Path(value)
    if not path.is_file():
        raise ValueError(f"{name}: no file {str(path)!r}")
    return path


def ship(
    model: str | os.PathLike,
    name: str,
    *,
    config: str | os.PathLike,
    policy_dir: str | os.PathLike = POLICY_DIR,
    force: bool = False,
) -> Path:
    """Copy ``model`` into ``policy_dir`` as ``name``; returns the shipped ``.zip``'s path.

    Parameters
    ----------
    model : str or PathLike
        A saved SB3 model (``.zip``) with its ``VecNormalize`` statistics beside it
        (:func:`agents.checkpoints.vecnormalize_path`), e.g. ``RUN/selected/model.zip``.
    name : str
        The policy's name: lower case letters, digits and ``_``, starting with a letter.
    config : str or PathLike
        The recipe's configuration (rl-zoo3's ``RUN/<EnvId>/config.yml``), copied as it is, with the
        ``command.txt`` beside it if there is one.
    policy_dir : str or PathLike
        Where shipped policies live (``agents/policies``).
    force : bool
        Replace a policy of the same name.

    Raises
    ------
    TypeError
        If an argument has the wrong type.
    ValueError
        If ``name`` is not a valid name or is shipped already (without ``force``), if
        ``model`` or ``config`` is missing, if ``model`` has no statistics or is not an SB3 model.
    """
    if not isinstance(name, str):
        raise TypeError(f"name must be a str, got {type(name).__name__}")
    if not _NAME.fullmatch(name):
        raise ValueError(f"name: {name!r} is not lower case letters, digits and '_' starting with a letter")
    if not isinstance(force, bool):
        raise TypeError(f"force must be a bool, got {type(force).__name__}")
    model_path = _check_path(model, "model")
    if model_path.suffix != ".zip":
        raise ValueError(f"model must name a model's .zip, got {str(model_path)!r}")
    config_path = _check_path(config, "config")
    if not isinstance(policy_dir, (str, os.PathLike)):
        raise TypeError(f"policy_dir must be a path, got {type(policy_dir).__name__}")
    policy_dir = Path(policy_dir)
    if not policy_dir.is_dir():
        raise ValueError(f"policy_dir: no folder {str(policy_dir)!r}")
    target_zip, target_dir = policy_dir / f"{name}.zip", policy_dir / name
    if not force and (target_zip.exists() or target_dir.exists()):
        raise ValueError(f"name: {name!r} is shipped already in {str(policy_dir)!r} (force=True replaces it)")
    stats_path = vecnormalize_path(model_path)
    if stats_path is None:
        raise ValueError(f"model: no VecNormalize statistics beside {str(model_path)!r}")
    # Read and transform everything before the first write, in a staging folder beside the target.
    weights = empty_optimizer_moments(model_path.read_bytes())
    selection = model_path.with_name("selection.json")
    command = config_path.with_name("command.txt")
    staging = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=policy_dir))
    try:
        (staging / name).mkdir()
        shutil.copyfile(stats_path, staging / name / "vecnormalize.pkl")
        shutil.copyfile(config_path, staging / name / "config.yml")
        if selection.is_file():
            shutil.copyfile(selection, staging / name / "selection.json")
        if command.is_file():
            shutil.copyfile(command, staging / name / "command.txt")
        (staging / f"{name}.zip").write_bytes(weights)
        # a replaced policy is set aside, not deleted, until both new parts are in place
        old = staging / "replaced"
        old.mkdir()
        moved = [(target, old / target.name) for target in (target_dir, target_zip) if target.exists()]
        try:
            for target, kept in moved:
                os.replace(target, kept)
            os.replace(staging / name, target_dir)
            os.replace(staging / f"{name}.zip", target_zip)
        except BaseException:
            for target in (target_dir, target_zip):
                if target.is_dir():
                    shutil.rmtree(target)
                elif target.exists():
                    target.unlink()
            for target, kept in moved:
                if kept.exists():
                    os.replace(kept, target)
            raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target_zip


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = argparse.ArgumentParser(
        prog="python -m research.ship",
        description="Copy a chosen model, its statistics and its recipe's config into agents/policies.",
    )
    parser.add_argument("model", help="the chosen model (.zip), e.g. RUN/selected/model.zip")
    parser.add_argument("name", help="the shipped policy's name (agents/policies/NAME.zip)")
    parser.add_argument("--config", required=True, help="the recipe's rl-zoo3 config.yml (RUN/<EnvId>/config.yml)")
    parser.add_argument("--policy-dir", default=str(POLICY_DIR), help="where to ship (default agents/policies)")
    parser.add_argument("--force", action="store_true", help="replace a policy of the same name")
    args = parser.parse_args(argv)
    try:
        shipped = ship(args.model, args.name, config=args.config, policy_dir=args.policy_dir, force=args.force)
    except (TypeError, ValueError) as error:
        parser.error(str(error))
    print(f"shipped {shipped} ({shipped.stat().st_size / 1e6:.1f} MB) and {shipped.with_suffix('')}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
