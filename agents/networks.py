"""Feature extractor and policy for SB3 on SeifExplore observations.

:class:`BeliefPolicy` is SB3's ``MultiInputPolicy`` with :class:`BeliefExtractor`
as its default feature extractor. Configs name it by its dotted path
(``policy: agents.networks.BeliefPolicy``), which rl-zoo3 imports; a
``policy_kwargs`` string naming ``BeliefExtractor`` would not work there, as
rl-zoo3 evaluates that string in its own namespace. Keeping the extractor in
the policy's defaults also survives rl-zoo3's Optuna sampler, which replaces
``policy_kwargs`` with its own ``net_arch`` and ``activation_fn``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch
from sb3_contrib.common.recurrent.policies import RecurrentMultiInputActorCriticPolicy
from stable_baselines3.common.policies import MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.sac.policies import MultiInputPolicy as SACMultiInputPolicy
from torch import nn

__all__ = [
    "BeliefExtractor",
    "BeliefPolicy",
    "BeliefRecurrentPolicy",
    "BeliefSACPolicy",
    "fused_lstm_sequence",
]


def belief_map_encoder(
    channels: int, height: int, width: int, map_features: int
) -> tuple[nn.Sequential, nn.Sequential]:
    """The belief map's CNN (three strided convolutions, flattened) and its linear head to ``map_features``.

    Shared by the SB3 extractor (:class:`BeliefExtractor`) and the RLlib module
    (``agents.rllib_agent``), so that both read the map with one architecture.
    The CNN is built before the head, so one seed gives both users the same initial weights.

    Parameters
    ----------
    channels, height, width : int
        The shape of the belief map.
    map_features : int
        Width of the embedding.

    Returns
    -------
    cnn : torch.nn.Sequential
        ``(batch, channels, height, width)`` -> ``(batch, flat)``.
    head : torch.nn.Sequential
        ``(batch, flat)`` -> ``(batch, map_features)`` (linear, then ReLU).
    """
    cnn = nn.Sequential(
        nn.Conv2d(channels, 16, kernel_size=4, stride=2, padding=1),
        nn.ReLU(),
        nn.Conv2d(16, 32, kernel_size=4, stride=2, padding=1),
        nn.ReLU(),
        nn.Conv2d(32, 32, kernel_size=3, stride=2, padding=1),
        nn.ReLU(),
        nn.Flatten(),
    )
    with torch.no_grad():
        flat = int(cnn(torch.zeros(1, channels, height, width)).shape[1])
    return cnn, nn.Sequential(nn.Linear(flat, int(map_features)), nn.ReLU())


class BeliefExtractor(BaseFeaturesExtractor):
    """A small CNN for ``belief_map`` and an MLP for the vector entries.

    The belief map is an egocentric raster (``C x H x W``; ``uint8`` in the
    env, which SB3's preprocessing, ``normalize_images=True``, hands over as
    floats in [0, 1]); three strided convolutions keep its geometry (where the unswept area and
    the walls are relative to the heading), which a flattening MLP would
    have to learn from scratch. ``pose``, ``landmarks`` and
    ``landmarks_mask`` are flattened and concatenated.

    Parameters
    ----------
    observation_space : gymnasium.spaces.Dict
        The env's observation space.
    map_features : int
        Width of the belief-map embedding.

    Raises
    ------
    ValueError
        If ``belief_map`` is not ``C x H x W``.
    """

    def __init__(self, observation_space: gym.spaces.Dict, map_features: int = 128) -> None:
        shape = observation_space["belief_map"].shape
        if shape is None or len(shape) != 3:
            raise ValueError(f"observation_space['belief_map'] must be C x H x W, got shape {shape}")
        channels, height, width = shape
        vector_keys = [key for key in observation_space.spaces if key != "belief_map"]
        vector_size = sum(int(torch.tensor(observation_space[key].shape).prod()) for key in vector_keys)
        super().__init__(observation_space, features_dim=map_features + vector_size)
        self.vector_keys = vector_keys
        self.cnn, self.map_head = belief_map_encoder(channels, height, width, map_features)

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        """The belief map's embedding followed by the flattened vector entries, per batch row."""
        belief = self.map_head(self.cnn(observations["belief_map"]))
        vectors = [observations[key].flatten(start_dim=1) for key in self.vector_keys]
        return torch.cat([belief, *vectors], dim=1)


class _ObservationChecked:
    """Refuses an observation that lacks entries of the policy's space, saying what to use instead.

    A policy trained with entries the env does not give (the budget's clock, :mod:`agents.memories`)
    must compute them on the agent's side: loaded as a bare Stable-Baselines3 model it would fail deep
    inside the extractor with a ``KeyError``.
    """

    observation_space: gym.spaces.Space

    def obs_to_tensor(self, observation: Any) -> Any:
        """SB3's ``obs_to_tensor``, after checking that a dict ``observation`` has every entry.

        Raises
        ------
        ValueError
            If ``observation`` is a dict without an entry of the policy's ``Dict`` space.
        """
        if isinstance(observation, dict) and isinstance(self.observation_space, gym.spaces.Dict):
            missing = sorted(set(self.observation_space.spaces) - set(observation))
            if missing:
                raise ValueError(
                    f"observation lacks {missing}: entries this policy computes on its own side; act with "
                    "agents.load_agent(PATH, env) (or agents.pretrained(NAME) for a shipped policy), which "
                    "computes them, instead of the bare Stable-Baselines3 model"
                )
        return super().obs_to_tensor(observation)  # type: ignore[misc]


class BeliefPolicy(_ObservationChecked, MultiInputActorCriticPolicy):
    """SB3's ``MultiInputPolicy`` (actor-critic) with :class:`BeliefExtractor` by default.

    Takes every argument of
    :class:`~stable_baselines3.common.policies.MultiInputActorCriticPolicy`;
    only the default of ``features_extractor_class`` differs. Its modules
    (and so its ``state_dict`` keys) are those of a ``MultiInputPolicy``
    built with ``features_extractor_class=BeliefExtractor``, so weights move
    between the two (``--init-from`` of a model saved either way).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", BeliefExtractor)
        super().__init__(*args, **kwargs)


def fused_lstm_sequence(
    features: torch.Tensor,
    lstm_states: tuple[torch.Tensor, torch.Tensor],
    episode_starts: torch.Tensor,
    lstm: nn.LSTM,
) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """Run padded sequences through ``lstm`` in one call: sb3-contrib's sequence step, fused.

    The reference is ``RecurrentActorCriticPolicy._process_sequence`` of
    sb3-contrib, with the same arguments and result: ``features`` is
    ``(n_seq * length, input_size)`` (sequence-major, padded), ``lstm_states``
    the ``(hidden, cell)`` states each sequence starts from, ``episode_starts``
    ``(n_seq * length,)`` with 1.0 where an episode begins. Where an episode
    begins inside a sequence the reference steps the LSTM one time step at a
    time in Python to zero the states there, which during a gradient update is
    nearly every minibatch (any sequence that starts an episode).

    Its rollout buffer cuts a sequence at every episode start, so an episode
    can begin only at a sequence's first step: the reset is then folded into
    the initial states and the whole sequence runs in one ``lstm`` call (one
    fused kernel, and one node in the autograd graph instead of one per step).
    Any other ``episode_starts`` falls back to the reference.

    Returns
    -------
    tuple
        ``(output, (hidden, cell))``: ``output`` is ``(n_seq * length,
        hidden_size)``, in the order of ``features``.

    Raises
    ------
    ValueError
        If ``features`` is not ``(rows, lstm.input_size)`` or ``episode_starts``
        does not hold one flag per row, in ``n_seq`` sequences of equal length
        (``n_seq`` from ``lstm_states``). The function keeps no state.

    Notes
    -----
    The outputs and final states equal the reference's: the same gate
    arithmetic per step, but the input products of all steps are one matrix
    product instead of one per step, which a BLAS may round differently
    (``tests/agents/test_networks.py`` checks them equal). One-step sequences, as when acting, run the very
    operations of the reference, so actions are equal bit for bit. The
    gradients of the LSTM's weights equal the reference's to float32 round-off
    only, since the fused backward sums the steps' contributions in another
    order: a run trained with it follows the same recipe, not the same bits.
    """
    n_seq = lstm_states[0].shape[1]
    if features.dim() != 2 or features.shape[1] != lstm.input_size:
        raise ValueError(f"features must be (n_seq * length, {lstm.input_size}), got {tuple(features.shape)}")
    rows = features.shape[0]
    if episode_starts.numel() != rows or rows % max(n_seq, 1) != 0:
        raise ValueError(
            f"episode_starts must hold one flag per row of features, {n_seq} sequences of equal length: "
            f"got {episode_starts.numel()} flags for {rows} rows"
        )
    starts = episode_starts.reshape((n_seq, -1))
    if bool(torch.any(starts[:, 1:] != 0.0)):
        # sb3-contrib annotates the states it returns as one tensor; they are the (hidden, cell) pair
        reference = RecurrentMultiInputActorCriticPolicy._process_sequence
        return reference(features, lstm_states, episode_starts, lstm)  # type: ignore[return-value]
    keep = (1.0 - starts[:, 0]).view(1, n_seq, 1)
    sequences = features.reshape((n_seq, -1, lstm.input_size)).swapaxes(0, 1)
    output, states = lstm(sequences, (keep * lstm_states[0], keep * lstm_states[1]))
    return torch.flatten(output.transpose(0, 1), start_dim=0, end_dim=1), states


class BeliefRecurrentPolicy(_ObservationChecked, RecurrentMultiInputActorCriticPolicy):
    """sb3-contrib's ``RecurrentPPO`` ``MultiInputLstmPolicy`` with :class:`BeliefExtractor` by default.

    The LSTM runs on the extractor's features, so the policy can remember
    what the belief observation forgets (where it has been, when it last saw
    a landmark). ``policy: agents.networks.BeliefRecurrentPolicy`` in
    ``agents/hyperparams/ppo_lstm.yml``.

    Parameters
    ----------
    *args, **kwargs
        Those of sb3-contrib's ``RecurrentMultiInputActorCriticPolicy``.
    fused_lstm : bool, default False
        Run each sequence of a gradient update through the LSTM in one call
        (:func:`fused_lstm_sequence`) instead of sb3-contrib's step-by-step
        loop. Actions are the same bit for bit either way; training differs
        in round-off, so a recipe reproduces only with the setting it was
        trained with (``False`` for those that do not name it). Given in
        ``policy_kwargs`` and saved with the model. Its speed-up:
        ``docs/performance_notes.md``.

    Raises
    ------
    TypeError
        If ``fused_lstm`` is not a bool.
    """

    def __init__(self, *args: Any, fused_lstm: bool = False, **kwargs: Any) -> None:
        if not isinstance(fused_lstm, bool):
            raise TypeError(f"fused_lstm must be a bool, got {type(fused_lstm).__name__}")
        kwargs.setdefault("features_extractor_class", BeliefExtractor)
        super().__init__(*args, **kwargs)
        self.fused_lstm = fused_lstm
        if fused_lstm:
            # An instance attribute shadows the inherited staticmethod: sb3-contrib calls
            # ``self._process_sequence(...)`` everywhere, so the choice is made once, here.
            self._process_sequence = fused_lstm_sequence  # type: ignore[method-assign, assignment]


class BeliefSACPolicy(_ObservationChecked, SACMultiInputPolicy):
    """SB3's ``SAC`` ``MultiInputPolicy`` with :class:`BeliefExtractor` by default.

    Actor and critics each get their own extractor (SB3's default for SAC,
    ``share_features_extractor=False``).
    ``policy: agents.networks.BeliefSACPolicy`` in ``agents/hyperparams/sac.yml``.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", BeliefExtractor)
        super().__init__(*args, **kwargs)
