"""Run inside the fresh virtualenv by ``test_release.py``: what an installed ``seif-gym`` does.

Usage: ``python probe.py [where] [tasks] [pretrained]`` (default: all three, in one process, so that
torch is imported once). Prints one JSON object on stdout, section name -> its result; each section
catches its own errors, so one failure does not hide the others. The test makes the assertions. Copied next to the fresh venv before it runs, so that no folder of the checkout is on
``sys.path`` through the script's own directory.
"""

from __future__ import annotations

import json
import sys
import traceback
from typing import Any


def _error() -> str:
    return traceback.format_exc(limit=-3).strip()


def where() -> dict[str, Any]:
    """Where the packages come from, what is on sys.path, whether the lab or an editable finder came along."""
    import agents
    import seif_gym

    try:
        import research  # noqa: F401

        research_error = None
    except ImportError as error:
        research_error = f"{type(error).__name__}: {error}"
    return {
        "seif_gym": seif_gym.__file__,
        "agents": agents.__file__,
        "version": seif_gym.__version__,
        "research_error": research_error,
        "sys_path": sys.path,
        "meta_path": [repr(finder) for finder in sys.meta_path],
        "editable_modules": sorted(name for name in sys.modules if "__editable__" in name),
    }


def tasks() -> dict[str, Any]:
    """``gym.make``, one ``reset`` and one ``step`` of every registered task: id -> error (``None``: fine)."""
    import gymnasium as gym

    import seif_gym

    result: dict[str, str | None] = {}
    for env_id in seif_gym.VARIANTS:
        try:
            env = gym.make(env_id)
            observation, _ = env.reset(seed=0)
            if not env.observation_space.contains(observation):
                raise AssertionError("reset's observation is not in the observation space")
            env.action_space.seed(0)
            observation, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            if not env.observation_space.contains(observation):
                raise AssertionError("step's observation is not in the observation space")
            env.close()
            result[env_id] = None
        except Exception:
            result[env_id] = _error()
    return result


def pretrained() -> dict[str, Any]:
    """One full episode of ``agents.pretrained(task)`` through ``predict`` alone, for every task with a policy."""
    import gymnasium as gym

    import agents

    task_ids = sorted({env_id for row in agents.list_pretrained() for env_id in row.held_out})
    result: dict[str, dict[str, Any]] = {}
    for env_id in task_ids:
        steps, outside = 0, 0
        try:
            env = gym.make(env_id)
            agent = agents.pretrained(env_id)
            observation, _ = env.reset(seed=0)
            done = False
            while not done:
                action, _ = agent.predict(observation, deterministic=True)
                outside += not env.action_space.contains(action)
                observation, _, terminated, truncated, _ = env.step(action)
                steps += 1
                done = terminated or truncated
            env.close()
            result[env_id] = {"steps": steps, "outside": outside, "error": None}
        except Exception:
            result[env_id] = {"steps": steps, "outside": outside, "error": _error()}
    return result


if __name__ == "__main__":
    probes = {"where": where, "tasks": tasks, "pretrained": pretrained}
    names = sys.argv[1:] or list(probes)
    if unknown := [name for name in names if name not in probes]:
        raise SystemExit(f"unknown probes {unknown}: use {', '.join(probes)}")
    print(json.dumps({name: probes[name]() for name in names}))
