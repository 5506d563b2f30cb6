"""Feature extractors for SB3 policies on SeifExplore observations."""

from __future__ import annotations

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn


class BeliefExtractor(BaseFeaturesExtractor):
    """A small CNN for ``belief_map`` and an MLP for the vector entries.

    The belief map is an egocentric raster (``C x H x W``; ``uint8`` in the
    env, which SB3's preprocessing, ``normalize_images=True``, hands over as
    floats in [0, 1]); two strided convolutions keep its geometry (where the unswept area and
    the walls are relative to the heading), which a flattening MLP would
    have to learn from scratch. ``pose``, ``landmarks`` and
    ``landmarks_mask`` are flattened and concatenated.

    Parameters
    ----------
    observation_space : gymnasium.spaces.Dict
        The env's observation space.
    map_features : int
        Width of the belief-map embedding.
    """

    def __init__(self, observation_space: gym.spaces.Dict, map_features: int = 128) -> None:
        channels, height, width = observation_space["belief_map"].shape
        vector_keys = [key for key in observation_space.spaces if key != "belief_map"]
        vector_size = sum(int(torch.tensor(observation_space[key].shape).prod()) for key in vector_keys)
        super().__init__(observation_space, features_dim=map_features + vector_size)
        self.vector_keys = vector_keys
        self.cnn = nn.Sequential(
            nn.Conv2d(channels, 16, kernel_size=4, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(16, 32, kernel_size=4, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(32, 32, kernel_size=3, stride=2, padding=1),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            flat = self.cnn(torch.zeros(1, channels, height, width)).shape[1]
        self.map_head = nn.Sequential(nn.Linear(flat, map_features), nn.ReLU())

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        belief = self.map_head(self.cnn(observations["belief_map"]))
        vectors = [observations[key].flatten(start_dim=1) for key in self.vector_keys]
        return torch.cat([belief, *vectors], dim=1)
