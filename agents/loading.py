"""Every way to get an agent, in one place: :func:`load_agent`, :func:`pretrained`, :func:`list_pretrained`.

An agent *spec* is a baseline name (:data:`agents.baselines.BASELINES`), the
name of a shipped policy (:data:`SHIPPED_POLICIES`), the path of a
Stable-Baselines3 / sb3-contrib ``.zip`` or ``rllib:CHECKPOINT``; on the command
lines any of them may be labelled ``LABEL=SPEC`` (:func:`agent_label`).

>>> import gymnasium as gym
>>> import agents
>>> env = gym.make("SeifExploreBudget-v2")
>>> agent = agents.pretrained("SeifExploreBudget-v2")   # the leaderboard's best shipped policy for the task
>>> observation, _ = env.reset(seed=0)
>>> action, _ = agent.predict(observation, deterministic=True)
>>> action.shape
(2,)
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import gymnasium as gym

import seif_gym  # noqa: F401  (registers the environments)
from agents.base import Agent
from agents.baselines import BASELINES, make_agent
from agents.sb3_agent import SB3Agent, sb3_algorithm

__all__ = [
    "HELD_OUT_RESULTS",
    "POLICY_DIR",
    "SHIPPED_POLICIES",
    "PretrainedInfo",
    "ShippedPolicy",
    "agent_label",
    "agent_labels",
    "check_agent_spec",
    "check_model_file",
    "list_pretrained",
    "load_agent",
    "pretrained",
]

#: Where the shipped policies lie (inside the installed package).
POLICY_DIR = Path(__file__).parent / "policies"
#: Held-out results of the shipped policies: the leaderboard's rows for them (``docs/leaderboard.json``).
HELD_OUT_RESULTS = POLICY_DIR / "held_out.json"


@dataclass(frozen=True)
class ShippedPolicy:
    """A trained policy shipped in ``agents/policies``.

    Attributes
    ----------
    path : Path
        The Stable-Baselines3 / sb3-contrib ``.zip`` (for acting: no optimizer state, no value function).
    trained_on : str
        The env id it was trained on.
    command : str
        The training command (the run's folder left out).
    chosen_for : str or None
        The env id whose validation seeds chose its checkpoint, when that is not ``trained_on``;
        ``None``: ``trained_on``.
    explorer : bool
        An exploration policy (the leaderboard runs it on every task); ``False`` for the adversary
        of the filter robustness harness.
    """

    path: Path
    trained_on: str
    command: str
    chosen_for: str | None = None
    explorer: bool = True

    @property
    def task(self) -> str:
        """The env id the policy is shipped for: :attr:`chosen_for`, else :attr:`trained_on`."""
        return self.trained_on if self.chosen_for is None else self.chosen_for


_RECURRENT = "python -m agents.train --algo ppo_lstm --env SeifExploreLoopBudget-v2 --seed S --timesteps 100000 --checkpoint-freq 25000"
_WIDE_LSTM = (
    "--hyperparams 'policy_kwargs=dict(net_arch=dict(pi=[256], vf=[256]), activation_fn=nn.Tanh, "
    "lstm_hidden_size=256, fused_lstm=True)'"
)

#: name -> every policy shipped with the package.
SHIPPED_POLICIES: dict[str, ShippedPolicy] = {
    "ppo": ShippedPolicy(
        POLICY_DIR / "ppo.zip", "SeifExplore-v0", "python -m agents.train --env SeifExplore-v0 --seed 8"
    ),
    "ppo_lstm_seif_explore_v2": ShippedPolicy(
        POLICY_DIR / "ppo_lstm_seif_explore_v2.zip",
        "SeifExplore-v2",
        f"python -m agents.train --algo ppo_lstm --env SeifExplore-v2 --seed 150 --timesteps 100000 "
        f"--checkpoint-freq 25000 {_WIDE_LSTM}",
    ),
    "ppo_lstm_loop_v2": ShippedPolicy(
        POLICY_DIR / "ppo_lstm_loop_v2.zip", "SeifExploreLoopBudget-v2", _RECURRENT, chosen_for="SeifExploreLoop-v2"
    ),
    "ppo_lstm_loop_budget_v2": ShippedPolicy(
        POLICY_DIR / "ppo_lstm_loop_budget_v2.zip", "SeifExploreLoopBudget-v2", _RECURRENT.replace(" S ", " 5 ")
    ),
    "ppo_lstm_clustered_budget_v2": ShippedPolicy(
        POLICY_DIR / "ppo_lstm_clustered_budget_v2.zip",
        "SeifExploreLoopBudget-v2",
        _RECURRENT,
        chosen_for="SeifExploreClusteredBudget-v2",
    ),
    "ppo_adversary_v1": ShippedPolicy(
        POLICY_DIR / "ppo_adversary_v1.zip",
        "SeifExplore-v1",
        "python -m agents.train --algo ppo --env SeifExplore-v1 --init-from agents/policies/ppo.zip "
        "--wrapper agents.adversary:SeifVsEkfReward",
        explorer=False,
    ),
}


@dataclass(frozen=True)
class PretrainedInfo:
    """One row of :func:`list_pretrained`.

    Attributes
    ----------
    name : str
    task : str
        The env id it is shipped for.
    algorithm : str
        ``PPO`` or ``RecurrentPPO``.
    command : str
        How it was trained.
    held_out : dict
        env id -> the leaderboard's row for it there (``final_map_error``, its ``final_map_error_ci95``,
        ``difference`` to the best baseline with its interval, ``verdict``...): empty for the adversary.
    """

    name: str
    task: str
    algorithm: str
    command: str
    held_out: Mapping[str, Mapping[str, Any]]


@cache
def _held_out_rows() -> dict[str, dict[str, dict[str, Any]]]:
    """Name -> env id -> the leaderboard's row of a shipped policy."""
    rows = json.loads(HELD_OUT_RESULTS.read_text())["rows"]
    result: dict[str, dict[str, dict[str, Any]]] = {}
    for row in rows:
        result.setdefault(str(row["agent"]), {})[str(row["env_id"])] = dict(row)
    return result


def list_pretrained() -> list[PretrainedInfo]:
    """Every shipped policy: name, task, algorithm, training command and held-out results."""
    rows = _held_out_rows()
    return [
        PretrainedInfo(name, policy.task, sb3_algorithm(policy.path).__name__, policy.command, rows.get(name, {}))
        for name, policy in SHIPPED_POLICIES.items()
    ]


def _best_for(env_id: str) -> str | None:
    """The shipped explorer of lowest held-out final map error on ``env_id`` (the leaderboard's choice)."""
    candidates = [
        (task_rows[env_id]["final_map_error"], name)
        for name, task_rows in _held_out_rows().items()
        if env_id in task_rows and name in SHIPPED_POLICIES and SHIPPED_POLICIES[name].explorer
    ]
    return min(candidates)[1] if candidates else None


def pretrained(task_or_name: str) -> Agent:
    """A shipped policy, ready to act on its registered env through ``predict`` alone.

    Parameters
    ----------
    task_or_name : str
        A registered env id of the leaderboard (the best shipped policy for that task, by the
        leaderboard's held-out final map error) or the name of a shipped policy
        (:func:`list_pretrained`).

    Returns
    -------
    Agent
        An :class:`~agents.sb3_agent.SB3Agent`: any entry the policy computes itself (the budget's
        clock) and a recurrent policy's state are kept inside it when ``predict`` is called without
        ``state``; call ``reset()`` (or pass ``episode_start``) when a new episode starts.

    Raises
    ------
    TypeError
        If ``task_or_name`` is not a string.
    ValueError
        If it is neither a shipped policy nor a task with a shipped policy.
    """
    if not isinstance(task_or_name, str):
        raise TypeError(f"task_or_name must be a str, got {type(task_or_name).__name__}")
    name = task_or_name if task_or_name in SHIPPED_POLICIES else _best_for(task_or_name.split(":")[-1])
    if name is None:
        tasks = sorted({env_id for rows in _held_out_rows().values() for env_id in rows})
        raise ValueError(
            f"task_or_name: {task_or_name!r} is neither a shipped policy ({', '.join(SHIPPED_POLICIES)}) "
            f"nor a task with one ({', '.join(tasks)})"
        )
    policy = SHIPPED_POLICIES[name]
    env_id = policy.task if name == task_or_name else task_or_name
    return SB3Agent(policy.path, env_factory=lambda: gym.make(env_id))


def load_agent(
    spec: str,
    env: Any,
    *,
    seed: int | None = None,
    env_factory: Callable[[], gym.Env] | None = None,
) -> Agent:
    """The agent of ``spec``, built for ``env``: the one way every command turns a name into an agent.

    Parameters
    ----------
    spec : str
        A baseline name, a shipped policy's name, the path of an SB3 / sb3-contrib ``.zip`` or
        ``rllib:CHECKPOINT`` (a ``LABEL=`` prefix is taken off by :func:`agent_label` first).
    env : gymnasium.Env
        The env the agent acts in (the baselines read its geometry, ``info_gain`` plans with its filter).
    seed : int, optional
        Seed of the ``random`` baseline.
    env_factory : callable, optional
        Builds an env of the task, for a saved model's ``VecNormalize`` statistics and its own entries;
        default: ``env`` itself.

    Raises
    ------
    ValueError
        An unknown spec (:func:`check_agent_spec`); FileNotFoundError: a missing ``.zip``.
    """
    check_agent_spec(spec)
    if spec in SHIPPED_POLICIES:
        spec = str(SHIPPED_POLICIES[spec].path)
    if _is_model_path(spec):
        return SB3Agent(spec, env, env_factory=env_factory)
    if spec.startswith("rllib:"):  # an RLlib checkpoint (needs the optional ray extra)
        from agents.rllib_agent import RLlibAgent

        return RLlibAgent(spec[len("rllib:") :], env)
    return make_agent(spec, env, **({"seed": seed} if spec == "random" else {}))


def _is_model_path(spec: str) -> bool:
    return spec.endswith(".zip")


def agent_label(spec: str) -> tuple[str, str]:
    """``(label, target)`` of an agent spec.

    Parameters
    ----------
    spec : str
        ``LABEL=TARGET``, the path of an SB3 ``.zip`` (labelled by its stem,
        or by its folder's name for ``model.zip`` and ``best_model.zip``), or
        a baseline name / ``rllib:CHECKPOINT`` (labelled by itself).

    Returns
    -------
    label : str
    target : str
        What :func:`load_agent` builds.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"spec must be a non-empty agent spec, got {spec!r}")
    if "=" in spec:
        label, _, target = spec.partition("=")
        return label.strip(), target.strip()
    if _is_model_path(spec):
        path = Path(spec)
        folder = path.parent.name
        return (folder if path.stem in ("model", "best_model") and folder else path.stem), spec
    return spec, spec


def agent_labels(specs: Sequence[str]) -> list[tuple[str, str]]:
    """:func:`agent_label` of every spec, repeated labels made distinct (``frontier#2``)."""
    seen: list[str] = []
    result: list[tuple[str, str]] = []
    for spec in specs:
        label, target = agent_label(spec)
        base, k = label, 2
        while label in seen:
            label, k = f"{base}#{k}", k + 1
        seen.append(label)
        result.append((label, target))
    return result


def check_agent_spec(spec: str, *, open_model: bool = False) -> None:
    """Raise unless ``spec`` (a :func:`agent_label` target) names an agent :func:`load_agent` can build.

    Parameters
    ----------
    spec : str
        A baseline, a shipped policy, the path of an SB3 ``.zip`` or ``rllib:CHECKPOINT``.
    open_model : bool
        Also open a saved model (a ``.zip`` or a shipped policy's, :func:`check_model_file`) and
        check that an RLlib checkpoint's folder exists: what a command does before any episode runs.

    Raises
    ------
    FileNotFoundError
        If an SB3 ``.zip`` (or, with ``open_model``, an RLlib checkpoint) does not exist.
    ValueError
        If ``spec`` is neither a baseline, a shipped policy, a ``.zip`` nor ``rllib:CHECKPOINT``, or
        (``open_model``) the model's file is not a saved model.
    """
    if _is_model_path(spec):
        if not Path(spec).exists():
            raise FileNotFoundError(f"no model at {spec}")
        if open_model:
            check_model_file(spec)
    elif spec in SHIPPED_POLICIES:
        if open_model:
            check_model_file(SHIPPED_POLICIES[spec].path)
    elif spec.startswith("rllib:"):
        if open_model and not Path(spec[len("rllib:") :]).exists():
            raise FileNotFoundError(f"no RLlib checkpoint at {spec[len('rllib:') :]}")
    elif spec not in BASELINES:
        raise ValueError(
            f"unknown agent {spec!r}: use a baseline ({', '.join(BASELINES)}), a shipped policy "
            f"({', '.join(SHIPPED_POLICIES)}), the path of an SB3 .zip or rllib:CHECKPOINT"
        )


def check_model_file(path: str | os.PathLike) -> None:
    """Raise unless ``path`` is a whole saved Stable-Baselines3 / sb3-contrib model (PPO, RecurrentPPO, SAC).

    Opens the ``.zip``, checks every entry against its CRC, and reads the algorithm it holds
    (:func:`agents.sb3_agent.sb3_algorithm`), without loading the weights.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If ``path`` is not a file, not a zip archive (a text file renamed ``.zip``), a truncated or
        damaged one, or a zip without a model's entries; the message names the file and what is wrong.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no model at {path}")
    if not path.is_file():
        raise ValueError(f"{path}: not a file (a saved model is the .zip Stable-Baselines3 writes)")
    try:
        with zipfile.ZipFile(path) as archive:
            damaged = archive.testzip()
            names = set(archive.namelist())
    except zipfile.BadZipFile as error:
        raise ValueError(f"{path}: not a zip archive, or a truncated one ({error}); a saved model is the .zip "
                         "Stable-Baselines3 writes") from None  # fmt: skip
    except (OSError, EOFError, zlib.error, NotImplementedError) as error:
        raise ValueError(f"{path}: a damaged zip archive ({error})") from None
    if damaged is not None:
        raise ValueError(f"{path}: a damaged zip archive (its entry {damaged!r} fails its CRC check)")
    missing = sorted({"data", "policy.pth"} - names)
    if missing:
        raise ValueError(
            f"{path}: a zip archive but not a saved Stable-Baselines3 model (no {', '.join(missing)} in it)"
        )
    sb3_algorithm(path)
