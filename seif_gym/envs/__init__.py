"""Gymnasium environments of seif_gym (one per file)."""

from seif_gym.envs.explore import SeifExploreEnv

__all__ = ["SeifExploreEnv"]
