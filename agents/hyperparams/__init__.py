"""Training configs in rl-zoo3's format, one ``<algo>.yml`` per algorithm.

Each is also importable by module name (``agents.hyperparams.ppo``), for
``python -m rl_zoo3.train --conf-file agents.hyperparams.ppo`` from any folder
(rl-zoo3 imports a module config and reads its ``hyperparams``).

>>> from agents.hyperparams import load
>>> load("ppo")["SeifExplore-v0"]["policy"]
'agents.networks.BeliefPolicy'
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

__all__ = ["HYPERPARAMS_DIR", "config_path", "load"]

#: The folder of the configs.
HYPERPARAMS_DIR = Path(__file__).resolve().parent


def config_path(algo: str) -> Path:
    """The config file of ``algo`` (``HYPERPARAMS_DIR/<algo>.yml``).

    Raises
    ------
    TypeError
        If ``algo`` is not a str.
    ValueError
        If there is no config for ``algo``.
    """
    if not isinstance(algo, str):
        raise TypeError(f"algo must be a str, got {type(algo).__name__}")
    path = HYPERPARAMS_DIR / f"{algo}.yml"
    if not path.is_file():
        known = sorted(p.stem for p in HYPERPARAMS_DIR.glob("*.yml"))
        raise ValueError(f"no config for algo {algo!r} in {HYPERPARAMS_DIR}; configs: {known}")
    return path


def load(algo: str) -> dict[str, Any]:
    """The entries of ``algo``'s config, freshly read (rl-zoo3 edits the entry it uses in place)."""
    return yaml.safe_load(config_path(algo).read_text())
