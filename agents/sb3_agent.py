"""A saved Stable-Baselines3 or sb3-contrib model behind the :class:`~agents.base.Agent` interface.

Its forward passes run on a set number of torch threads (:class:`SB3Agent`'s ``threads``, one by
default), and inside :meth:`SB3Agent.exact_batches` a batched ``predict`` gives every row the bits a
``predict`` of that row alone gives (what a batched evaluation needs to equal a serial one).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agents.base import Agent
from agents.memories import PolicyMemories, has_policy_entries, needs_acting_env, policy_memories, policy_view

if TYPE_CHECKING:
    import torch
    from stable_baselines3.common.base_class import BaseAlgorithm

__all__ = ["EXACT_BATCH_LAYERS", "InexactBatchError", "SB3Agent", "sb3_algorithm"]

#: The layer types (``torch.nn`` class names) of a policy that :meth:`SB3Agent.exact_batches` runs row by
#: row exactly: ``Linear`` and ``Conv2d`` are computed as for one row; the others act on each row alone
#: (activations, ``Flatten``, ``Dropout`` in evaluation), or, for ``LSTM``, are checked to (the first call).
EXACT_BATCH_LAYERS: tuple[str, ...] = ("Linear", "Conv2d", "LSTM", "ReLU", "Tanh", "Sigmoid", "ELU", "LeakyReLU",
                                       "GELU", "SiLU", "Softplus", "Identity", "Flatten", "Dropout")  # fmt: skip
# torch's batched matrix product switches to a plain loop below this many multiply-adds per row (K * N)
_SMALL_PRODUCT = 400


def _batch_rows(model_input: Any) -> int:
    """Rows of a batched dict observation with the env's ``pose`` entry (shape ``(rows, 7)``), else 0."""
    pose = np.asarray(model_input["pose"]) if isinstance(model_input, Mapping) and "pose" in model_input else None
    return int(pose.shape[0]) if pose is not None and pose.ndim == 2 else 0


class InexactBatchError(RuntimeError):
    """A batched forward pass inside :meth:`SB3Agent.exact_batches` gave a row other bits than that row alone."""


def check_threads(threads: object, name: str = "threads") -> int | None:
    """``threads`` as a positive int, or ``None``; a clear error naming ``name`` otherwise."""
    if threads is None:
        return None
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)):
        raise TypeError(f"{name} must be a positive int or None, got {threads!r}")
    if threads < 1:
        raise ValueError(f"{name} must be a positive int or None, got {threads!r}")
    return int(threads)


@contextlib.contextmanager
def torch_threads(count: int | None) -> Iterator[None]:
    """Torch's intra-op threads set to ``count`` inside the block (``None``: left as they are), restored after."""
    if count is None:
        yield
        return
    import torch

    previous = torch.get_num_threads()
    if previous == count:
        yield
        return
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _exact_linear(layer: Any) -> Callable[[torch.Tensor], torch.Tensor]:
    """``layer``'s forward with every row computed as a one-row call computes it (a one-row matrix product)."""
    import torch
    import torch.nn.functional as F

    def forward(x: torch.Tensor) -> torch.Tensor:
        rows = x.reshape(-1, layer.in_features)
        count = rows.shape[0]
        if count <= 1:
            return F.linear(x, layer.weight, layer.bias)
        if layer.in_features * layer.out_features < _SMALL_PRODUCT:  # torch's own loop there: one call per row
            out = torch.cat([F.linear(rows[i : i + 1], layer.weight, layer.bias) for i in range(count)])
        else:  # a batch of one-row products with the same weights (the weights are not copied)
            weight = layer.weight.t().expand(count, layer.in_features, layer.out_features)
            if layer.bias is None:
                out = torch.bmm(rows.unsqueeze(1), weight)
            else:
                out = torch.baddbmm(layer.bias.expand(count, 1, layer.out_features), rows.unsqueeze(1), weight)
        return out.reshape(*x.shape[:-1], layer.out_features)

    return forward


def _conv_backend(layer: Any, image: torch.Tensor) -> str:
    """The name of torch's convolution backend for ``layer`` on the one-image batch ``image`` ('' if unknown)."""
    import torch

    if layer.padding_mode != "zeros" or isinstance(layer.padding, str):
        return ""
    try:
        backend = torch._C._select_conv_backend(image, layer.weight, layer.bias, list(layer.stride),
                                                list(layer.padding), list(layer.dilation), False, [0, 0],
                                                layer.groups, None)  # fmt: skip
    except (AttributeError, RuntimeError, TypeError):  # a torch without this (private) entry point
        return ""
    return str(backend).rsplit(".", 1)[-1]


def _exact_conv2d(layer: Any) -> Callable[[torch.Tensor], torch.Tensor]:
    """``layer``'s forward with every image computed by the backend torch picks for that image alone."""
    import torch

    def forward(x: torch.Tensor) -> torch.Tensor:
        if x.dim() != 4 or x.shape[0] <= 1:
            return layer._conv_forward(x, layer.weight, layer.bias)
        backend = _conv_backend(layer, x[:1])
        if backend == "Slow2d":  # one image: unfold and one matrix product; on a batch, that for each image
            return torch.ops.aten._slow_conv2d_forward(x, layer.weight, list(layer.kernel_size), layer.bias,
                                                       list(layer.stride), list(layer.padding))  # fmt: skip
        if backend == "Mkldnn":  # oneDNN computes each image alone (checked on the first call)
            return layer._conv_forward(x, layer.weight, layer.bias)
        return torch.cat([layer._conv_forward(x[i : i + 1], layer.weight, layer.bias) for i in range(x.shape[0])])

    return forward


def sb3_algorithm(path: str | os.PathLike) -> type[BaseAlgorithm]:
    """The algorithm class that loads the SB3 model at ``path``: ``PPO``, ``RecurrentPPO`` or ``SAC``.

    Read from the policy class saved in the ``.zip`` (without loading the weights).

    Raises
    ------
    ValueError
        ``path`` is not a model of one of the three algorithms.
    """
    import zipfile

    from sb3_contrib import RecurrentPPO
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.save_util import json_to_data
    from stable_baselines3.sac.policies import SACPolicy

    try:
        with zipfile.ZipFile(path) as archive:
            policy = json_to_data(archive.read("data").decode()).get("policy_class")
    except (OSError, KeyError, zipfile.BadZipFile, ValueError) as error:
        raise ValueError(f"path: {str(path)!r} is not a saved SB3 model ({error})") from error
    # the recurrent policy is an actor-critic policy too: ask for it first
    for policy_base, algorithm in ((RecurrentActorCriticPolicy, RecurrentPPO), (SACPolicy, SAC),
                                   (ActorCriticPolicy, PPO)):  # fmt: skip
        if isinstance(policy, type) and issubclass(policy, policy_base):
            return algorithm
    raise ValueError(f"path: {str(path)!r} holds a {policy!r} policy, not one of PPO, RecurrentPPO or SAC")


class SB3Agent(Agent):
    """A saved Stable-Baselines3 model (PPO, RecurrentPPO or SAC) behind the :class:`~agents.base.Agent` interface.

    Parameters
    ----------
    path : str or Path
        The model's ``.zip``.
    env : gymnasium.Env, optional
        Used only to rebuild a ``VecNormalize`` (its spaces).
    env_factory : callable, optional
        Builds an env for ``VecNormalize.load`` when the model's
        normalisation statistics are found
        (:func:`agents.checkpoints.vecnormalize_path`: a checkpoint's
        ``PREFIX_vecnormalize_<N>_steps.pkl``, else ``vecnormalize.pkl``
        in the model's folder or rl-zoo3's ``<EnvId>/vecnormalize.pkl``); its
        observation normalisation (``obs_rms``) is then applied to every
        observation (statistics frozen).
    threads : int or None, default 1
        Torch's intra-op threads during each ``predict`` (set for the call, the caller's count restored
        after; the attribute of that name may be changed later). ``None``: torch's count as it is.
        A small network's forward pass gains nothing from more threads and loses much when other
        processes want the cores.

    Raises
    ------
    TypeError, ValueError
        If ``threads`` is not a positive int or ``None``.
    """

    name = "sb3"

    def __init__(
        self,
        path: str | os.PathLike,
        env: Any | None = None,
        env_factory: Any | None = None,
        *,
        threads: int | None = 1,
    ) -> None:
        super().__init__(env)
        #: torch's threads during ``predict`` (``None``: as they are)
        self.threads = check_threads(threads)
        self._check_next_batch = False
        self.path = Path(path)
        # the recurrent state runs through predict's ``state`` (run_episode passes it back each step)
        self.model = sb3_algorithm(self.path).load(self.path, device="cpu")
        #: a recurrent policy's state when the caller passes none (``predict(observation)`` alone)
        self.recurrent = hasattr(self.model.policy, "lstm_actor")
        self._recurrent_state: Any = None
        self.vecnormalize = None
        from agents.checkpoints import vecnormalize_path

        factory: Callable[[], Any] = env_factory if env_factory is not None else (lambda: env)
        # a policy trained with entries of its own (the budget's clock, the coverage memory) computes them itself
        space = self.model.observation_space
        self.memories: PolicyMemories | None = None
        if has_policy_entries(space):
            if env is None and needs_acting_env(space):
                raise ValueError(f"env: {self.path} computes an entry from the env it acts in: pass that env")
            if env is not None:
                self.memories = policy_memories(space, env)
            else:
                probe = factory()
                try:
                    self.memories = policy_memories(space, probe)
                finally:
                    if probe is not None:
                        probe.close()
            plain_factory = factory
            factory = lambda: policy_view(plain_factory(), space)  # noqa: E731  (the spaces VecNormalize checks)
        # the statistics saved with this very model (a checkpoint's own, never a later moment's)
        stats_path = vecnormalize_path(self.path)
        if stats_path is not None:
            from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

            self.vecnormalize = VecNormalize.load(str(stats_path), DummyVecEnv([factory]))
            self.vecnormalize.training = False
            self.vecnormalize.norm_reward = False

    def predict(
        self,
        observation: Mapping[str, np.ndarray],
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, Any]:
        """The model's ``predict`` after its own entries and the saved observation normalisation (if any)."""
        model_input: Any = (
            dict(observation) if self.memories is None else self.memories.observe(observation, episode_start)
        )
        if self.vecnormalize is not None:
            model_input = self.vecnormalize.normalize_obs(model_input)
        own_state = state is None and self.recurrent
        if own_state:  # no state passed: the agent carries the recurrent state itself, as SB3's caller would
            state = self._recurrent_state
            if episode_start is None:
                episode_start = self._episode_start(model_input)
        check = self._check_next_batch and state is None and _batch_rows(model_input) > 0
        with torch_threads(self.threads):
            action, state = self.model.predict(
                model_input, state=state, episode_start=episode_start, deterministic=deterministic
            )
            if check:
                self._check_next_batch = False
                self._check_rows(model_input, episode_start, deterministic, action)
        if own_state:
            self._recurrent_state = state
        if self.memories is not None:
            action = self.memories.act(action)  # a residual's sum with the planner's action
        return np.asarray(action, dtype=np.float32), state

    def unbatchable_layers(self) -> list[str]:
        """The policy's layer types that :meth:`exact_batches` cannot run row by row (none: it can).

        A layer is a module without sub-modules; :data:`EXACT_BATCH_LAYERS` lists the types it can
        (their exact ``torch.nn`` classes, not subclasses, which may compute otherwise).
        """
        import torch

        known = tuple(getattr(torch.nn, name) for name in EXACT_BATCH_LAYERS)
        found = {type(module).__name__ for module in self.model.policy.modules()
                 if not any(True for _ in module.children()) and type(module) not in known}  # fmt: skip
        return sorted(found)

    @contextlib.contextmanager
    def exact_batches(self) -> Iterator[None]:
        """Inside the block, a batched ``predict`` gives each row the bits a ``predict`` of that row alone gives.

        A BLAS rounds a matrix product of many rows otherwise than one of a single row, so a batched
        forward pass differs from one-row passes in the last bits (and an episode's actions then drift
        apart). Inside the block every ``Linear`` layer computes a batch of one-row products and every
        ``Conv2d`` the backend torch picks for one image alone; the first batched call that starts
        from no recurrent state (``state=None``) also runs each row alone and compares.

        Raises
        ------
        ValueError
            On entry, if the policy has layers outside :data:`EXACT_BATCH_LAYERS`
            (:meth:`unbatchable_layers`).
        InexactBatchError
            From that first batched ``predict``, if a row's action differs from its one-row action
            (a BLAS or backend that rounds otherwise); the agent stays usable, outside the block.
        """
        import torch

        unknown = self.unbatchable_layers()
        if unknown:
            raise ValueError(f"{self.path.name}: layers {', '.join(unknown)} cannot be batched row by row exactly")
        patched = []
        for module in self.model.policy.modules():
            if type(module) is torch.nn.Linear:
                module.forward = _exact_linear(module)  # type: ignore[method-assign, assignment]
            elif type(module) is torch.nn.Conv2d:
                module.forward = _exact_conv2d(module)  # type: ignore[method-assign, assignment]
            else:
                continue
            patched.append(module)
        self._check_next_batch = True
        try:
            yield
        finally:
            self._check_next_batch = False
            for module in patched:
                del module.forward  # the class's forward again

    def _check_rows(self, model_input: Any, episode_start: Any, deterministic: bool, action: np.ndarray) -> None:
        """Raise :class:`InexactBatchError` unless every row of ``action`` is that row's action alone."""
        count = _batch_rows(model_input)
        starts = None if episode_start is None else np.asarray(episode_start).reshape(-1)
        for row in range(count):
            alone = {key: np.asarray(value)[row : row + 1] for key, value in model_input.items()}
            start = None if starts is None else starts[row : row + 1]
            single, _ = self.model.predict(alone, state=None, episode_start=start, deterministic=deterministic)
            if not np.array_equal(np.asarray(single).reshape(-1), np.asarray(action)[row].reshape(-1)):
                raise InexactBatchError(
                    f"{self.path.name}: row {row} of a batched forward pass differs from that row alone "
                    f"({np.asarray(action)[row].tolist()} against {np.asarray(single).reshape(-1).tolist()})"
                )

    def _act(self, observation: Mapping[str, np.ndarray], index: int) -> np.ndarray:
        """One unbatched observation (the model is stateless across envs)."""
        return self.predict(observation, deterministic=True)[0]

    def _episode_start(self, model_input: Any) -> np.ndarray:
        """``episode_start`` for a call without one: true for every env on the first call after a reset."""
        pose = np.asarray(model_input["pose"]) if isinstance(model_input, Mapping) else np.asarray(model_input)
        count = pose.shape[0] if pose.ndim == 2 else 1
        return np.full(count, self._recurrent_state is None)

    def reset(self, index: int | None = None) -> None:
        """Env ``index`` (every env when ``None``) starts a new episode; the policy's own entries restart with it.

        The recurrent state the agent carries itself (calls without ``state``) restarts for every env.
        """
        super().reset(index)
        self._recurrent_state = None
        if self.memories is not None:
            self.memories.reset(index)

    def __repr__(self) -> str:
        return f"SB3Agent({str(self.path)!r}, vecnormalize={self.vecnormalize is not None}, threads={self.threads})"
