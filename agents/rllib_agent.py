"""RLlib policies for ``SeifExplore``: the network (:class:`BeliefRLModule`) and the agent (:class:`RLlibAgent`).

Needs the optional ``ray`` extra (``pip install -e ".[ray]"``); nothing in
``seif_gym`` or in the rest of ``agents`` imports this module unless asked to
(:func:`agents.loading.load_agent` imports it for ``rllib:CHECKPOINT``).

:class:`BeliefRLModule` is a ``TorchRLModule`` for RLlib's new API stack that
reads the ``Dict`` observation as what it is, like the project's SB3 policy
(:class:`agents.networks.BeliefExtractor`):

* ``belief_map`` (``uint8``, ``C x H x W``) is divided by 255 and goes
  through three strided convolutions and a dense layer (the raster keeps its
  geometry: where the unswept area and the walls lie relative to the
  heading);
* the vector entries (``landmarks``, ``landmarks_mask``, ``pose``, in this
  order: sorted by key) are flattened, concatenated and go through a small
  MLP;
* the two embeddings are concatenated (the shared encoder); separate tanh
  MLPs give the policy (the mean of a diagonal Gaussian, with a
  state-independent log standard deviation) and the value.

Its ``model_config`` keys (all optional): ``map_features`` (128),
``vector_hiddens`` ([64]), ``pi_hiddens`` ([256, 256]), ``vf_hiddens``
([256, 256]), ``log_std_init`` (0.0).

:class:`RLlibAgent` loads the module from a checkpoint written by
``python -m agents.rllib_train`` (an algorithm checkpoint, or the module's own
directory inside it) and acts deterministically (the Gaussian's mean, clipped
to ``[-1, 1]``) behind the common :class:`~agents.base.Agent` interface,
so ``python -m agents.evaluate --agents rllib:runs/rllib/checkpoint`` compares
it with the baselines.

>>> import gymnasium as gym, seif_gym  # doctest: +SKIP
>>> agent = RLlibAgent("runs/rllib/checkpoint")  # doctest: +SKIP
>>> env = gym.make("SeifExplore-v2")  # doctest: +SKIP
>>> obs, _ = env.reset(seed=0)  # doctest: +SKIP
>>> action, _ = agent.predict(obs, deterministic=True)  # doctest: +SKIP
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from ray.rllib.core.columns import Columns
from ray.rllib.core.rl_module.apis import ValueFunctionAPI
from ray.rllib.core.rl_module.rl_module import RLModule
from ray.rllib.core.rl_module.torch import TorchRLModule
from torch import nn

from agents.base import Agent
from agents.networks import belief_map_encoder

__all__ = ["AGENT_PREFIX", "DEFAULT_MODEL_CONFIG", "MAP_KEY", "BeliefRLModule", "RLlibAgent", "module_checkpoint"]

#: Key of the image entry of the observation.
MAP_KEY = "belief_map"
#: Prefix of an agent spec naming an RLlib checkpoint: ``"rllib:PATH"``.
AGENT_PREFIX = "rllib:"
#: Defaults of :class:`BeliefRLModule`'s ``model_config``.
DEFAULT_MODEL_CONFIG: dict[str, Any] = {
    "map_features": 128,
    "vector_hiddens": [64],
    "pi_hiddens": [256, 256],
    "vf_hiddens": [256, 256],
    "log_std_init": 0.0,
}
#: Where an algorithm checkpoint keeps the (single) policy's module.
_MODULE_SUBDIR = Path("learner_group") / "learner" / "rl_module" / "default_policy"


def _mlp(sizes: Sequence[int], activation: type[nn.Module]) -> nn.Sequential:
    """Dense layers ``sizes[0] -> sizes[1] -> ...``, each followed by ``activation``."""
    layers: list[nn.Module] = []
    for fan_in, fan_out in itertools.pairwise(sizes):
        layers += [nn.Linear(fan_in, fan_out), activation()]
    return nn.Sequential(*layers)


def _check_widths(name: str, value: Any) -> list[int]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise TypeError(f"model_config[{name!r}] must be a list of positive ints, got {value!r}")
    widths = list(value)
    if any(isinstance(w, bool) or not isinstance(w, (int, np.integer)) or w < 1 for w in widths):
        raise ValueError(f"model_config[{name!r}] must be a list of positive ints, got {value!r}")
    return [int(w) for w in widths]


class BeliefRLModule(TorchRLModule, ValueFunctionAPI):
    """PPO network for the ``SeifExplore`` observation: a CNN on the belief map, an MLP on the vectors.

    Built by RLlib from an ``RLModuleSpec(module_class=BeliefRLModule,
    model_config={...})``; the keyword arguments are RLlib's
    (``observation_space``, ``action_space``, ``inference_only``,
    ``learner_only``, ``model_config``).

    Raises
    ------
    TypeError
        ``observation_space`` is not a ``Dict`` with a ``belief_map`` image
        entry and ``Box`` vector entries, or ``action_space`` is not a
        ``Box``; a ``model_config`` entry has the wrong type.
    ValueError
        A ``model_config`` entry is out of range.
    """

    def setup(self) -> None:
        """Build the encoder, the policy and value heads (RLlib calls this from ``__init__``)."""
        space = self.observation_space
        if not isinstance(space, gym.spaces.Dict) or MAP_KEY not in space.spaces:
            raise TypeError(f"observation_space must be a Dict with a {MAP_KEY!r} entry, got {space}")
        image = space[MAP_KEY]
        if not isinstance(image, gym.spaces.Box) or len(image.shape) != 3:
            raise TypeError(f"observation_space[{MAP_KEY!r}] must be a Box of shape (C, H, W), got {image}")
        self.vector_keys = sorted(key for key in space.spaces if key != MAP_KEY)
        for key in self.vector_keys:
            if not isinstance(space[key], gym.spaces.Box):
                raise TypeError(f"observation_space[{key!r}] must be a Box, got {space[key]}")
        if not isinstance(self.action_space, gym.spaces.Box) or len(self.action_space.shape) != 1:
            raise TypeError(f"action_space must be a 1-D Box, got {self.action_space}")

        # other keys are RLlib's own (PPO adds ``vf_share_layers``): not read here
        given: Mapping[str, Any] = self.model_config if isinstance(self.model_config, Mapping) else {}
        config = {key: given.get(key, default) for key, default in DEFAULT_MODEL_CONFIG.items()}
        map_features = config["map_features"]
        if isinstance(map_features, bool) or not isinstance(map_features, (int, np.integer)):
            raise TypeError(f"model_config['map_features'] must be a positive int, got {map_features!r}")
        if map_features < 1:
            raise ValueError(f"model_config['map_features'] must be a positive int, got {map_features!r}")
        vector_hiddens = _check_widths("vector_hiddens", config["vector_hiddens"])
        pi_hiddens = _check_widths("pi_hiddens", config["pi_hiddens"])
        vf_hiddens = _check_widths("vf_hiddens", config["vf_hiddens"])
        log_std_init = config["log_std_init"]
        if (
            isinstance(log_std_init, bool)
            or not isinstance(log_std_init, (int, float))
            or not math.isfinite(log_std_init)
        ):
            raise TypeError(f"model_config['log_std_init'] must be a finite number, got {log_std_init!r}")

        channels, height, width = image.shape
        self.cnn, self.map_head = belief_map_encoder(channels, height, width, int(map_features))
        vector_size = sum(gym.spaces.flatdim(space[key]) for key in self.vector_keys)
        self.vector_mlp = _mlp([vector_size, *vector_hiddens], nn.ReLU)
        features = int(map_features) + (vector_hiddens[-1] if vector_hiddens else vector_size)
        actions = int(self.action_space.shape[0])
        self.pi_mlp = _mlp([features, *pi_hiddens], nn.Tanh)
        self.pi_mean = nn.Linear(pi_hiddens[-1] if pi_hiddens else features, actions)
        self.log_std = nn.Parameter(torch.full((actions,), float(log_std_init)))
        self.vf_mlp = _mlp([features, *vf_hiddens], nn.Tanh)
        self.vf_out = nn.Linear(vf_hiddens[-1] if vf_hiddens else features, 1)
        # small initial policy means and values, as in SB3's PPO (orthogonal init, gains 0.01 and 1)
        nn.init.orthogonal_(self.pi_mean.weight, gain=0.01)
        nn.init.zeros_(self.pi_mean.bias)
        nn.init.orthogonal_(self.vf_out.weight, gain=1.0)
        nn.init.zeros_(self.vf_out.bias)

    # -- the network -------------------------------------------------------------------------------
    def encode(self, observation: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The shared embedding ``(B, features)`` of a batch of observations.

        ``belief_map`` may be ``uint8`` (as the env returns it) or float with
        the same 0..255 values; it is divided by 255 here.
        """
        belief = observation[MAP_KEY].to(torch.float32) / 255.0
        vectors = torch.cat(
            [observation[key].to(torch.float32).flatten(start_dim=1) for key in self.vector_keys], dim=1
        )
        return torch.cat([self.map_head(self.cnn(belief)), self.vector_mlp(vectors)], dim=1)

    def _dist_inputs(self, embeddings: torch.Tensor) -> torch.Tensor:
        """``(mean, log_std)`` concatenated: the inputs of RLlib's ``TorchDiagGaussian``."""
        mean = self.pi_mean(self.pi_mlp(embeddings))
        return torch.cat([mean, self.log_std.expand_as(mean)], dim=-1)

    def _forward(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        """Inference and exploration: the action distribution's inputs."""
        return {Columns.ACTION_DIST_INPUTS: self._dist_inputs(self.encode(batch[Columns.OBS]))}

    def _forward_train(self, batch: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
        """Training: the distribution's inputs and the embeddings (reused by :meth:`compute_values`)."""
        embeddings = self.encode(batch[Columns.OBS])
        return {Columns.ACTION_DIST_INPUTS: self._dist_inputs(embeddings), Columns.EMBEDDINGS: embeddings}

    def compute_values(self, batch: dict[str, Any], embeddings: Any | None = None) -> torch.Tensor:
        """Value estimates ``(B,)``; ``embeddings`` from :meth:`_forward_train` avoid a second encoder pass."""
        if embeddings is None:
            embeddings = self.encode(batch[Columns.OBS])
        return self.vf_out(self.vf_mlp(embeddings)).squeeze(-1)

    def deterministic_action(self, observation: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The Gaussian's mean ``(B, A)`` for a batch of observations (no sampling)."""
        with torch.no_grad():
            return self.pi_mean(self.pi_mlp(self.encode(observation)))


# -- loading ---------------------------------------------------------------------------------------
def module_checkpoint(path: str | os.PathLike) -> Path:
    """The RLModule directory of ``path``.

    Parameters
    ----------
    path : str or Path
        An algorithm checkpoint written by ``agents.rllib_train`` (it holds
        ``learner_group/learner/rl_module/default_policy``), or that module
        directory itself.

    Returns
    -------
    Path

    Raises
    ------
    TypeError
        ``path`` is not a str or path.
    FileNotFoundError
        Neither is there.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or path, got {type(path).__name__}")
    root = Path(path)
    for candidate in (root / _MODULE_SUBDIR, root):
        if (candidate / RLModule.CLASS_AND_CTOR_ARGS_FILE_NAME).is_file():
            return candidate
    raise FileNotFoundError(f"path has no RLModule checkpoint (neither {root / _MODULE_SUBDIR} nor {root}): {path}")


class RLlibAgent(Agent):
    """A trained RLlib policy (a :class:`BeliefRLModule` checkpoint) behind the common agent interface.

    Parameters
    ----------
    path : str or Path
        An algorithm checkpoint from ``python -m agents.rllib_train`` (the
        ``checkpoint`` directory in its ``--out``), or the module directory
        inside it (see :func:`module_checkpoint`).
    env : gymnasium.Env or None
        Unused but for a check: its observation space must be the one the
        module was trained on.

    Raises
    ------
    TypeError
        ``path`` is not a str or path.
    FileNotFoundError
        No module checkpoint under ``path``.
    ValueError
        ``env``'s observation space differs from the module's.

    Notes
    -----
    The module is loaded with RLlib's ``RLModule.from_checkpoint`` (no Ray
    cluster is started) and runs on the CPU. :meth:`predict` always acts
    deterministically (the mean action, clipped to ``[-1, 1]``), whatever
    ``deterministic`` says, so that evaluations are reproducible.
    """

    name = "rllib"

    def __init__(self, path: str | os.PathLike, env: Any | None = None) -> None:
        super().__init__(env)
        self.path = module_checkpoint(path)
        module = RLModule.from_checkpoint(self.path)
        if not isinstance(module, BeliefRLModule):
            raise TypeError(f"path holds a {type(module).__name__}, not a BeliefRLModule: {path}")
        self.module: BeliefRLModule = module
        self.module.eval()
        if env is not None:
            space = getattr(env, "observation_space", None)
            if space != self.module.observation_space:
                raise ValueError(
                    f"env's observation space {space} differs from the module's {self.module.observation_space}"
                )

    def actions(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """Deterministic actions ``(n, 2)`` for a batch of observations (a leading ``n`` axis on every entry)."""
        batch = {key: torch.as_tensor(np.asarray(value)) for key, value in observation.items()}
        return np.clip(self.module.deterministic_action(batch).numpy(), -1.0, 1.0).astype(np.float32)

    def _act(self, observation: Mapping[str, np.ndarray], index: int) -> np.ndarray:
        """One unbatched observation (the module is stateless)."""
        return self.actions({key: np.asarray(value)[None] for key, value in observation.items()})[0]

    def __repr__(self) -> str:
        return f"RLlibAgent({str(self.path)!r})"
