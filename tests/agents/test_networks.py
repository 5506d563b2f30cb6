"""agents.networks: the fused LSTM sequence step against sb3-contrib's step-by-step reference."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

import seif_gym  # noqa: F401

sb3_contrib = pytest.importorskip("sb3_contrib", reason="sb3-contrib is in the train extra")

from sb3_contrib import RecurrentPPO  # noqa: E402
from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy  # noqa: E402
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402

from agents import networks  # noqa: E402
from agents.networks import BeliefRecurrentPolicy, fused_lstm_sequence  # noqa: E402

reference_sequence = RecurrentActorCriticPolicy._process_sequence


def padded_batch(n_seq: int, length: int, layers: int, starts_at_zero: list[int], seed: int = 0):
    """Sequences as sb3-contrib's recurrent buffer hands them over: sequence-major, with initial states."""
    generator = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng():
        torch.manual_seed(seed)  # the LSTM's initial weights too: the same test every run
        lstm = nn.LSTM(6, 5, num_layers=layers)
    features = torch.randn(n_seq * length, 6, generator=generator, requires_grad=True)
    starts = torch.zeros(n_seq, length)
    starts[starts_at_zero, 0] = 1.0
    states = (torch.randn(layers, n_seq, 5, generator=generator), torch.randn(layers, n_seq, 5, generator=generator))
    return lstm, features, states, starts.flatten()


@pytest.mark.parametrize("layers", [1, 2])
def test_fused_sequence_equals_the_reference_bit_for_bit_and_its_gradients_to_round_off(layers):
    lstm, features, states, starts = padded_batch(n_seq=7, length=23, layers=layers, starts_at_zero=[0, 2, 3, 6])
    output, (hidden, cell) = fused_lstm_sequence(features, states, starts, lstm)
    expected, (expected_hidden, expected_cell) = reference_sequence(features, states, starts, lstm)
    # bit for bit on the machines measured so far; a BLAS may round one product of all steps and one per step
    # differently, so the test allows float32 round-off and no more
    for got, want in ((output, expected), (hidden, expected_hidden), (cell, expected_cell)):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-6)

    weights = torch.randn_like(output, generator=torch.Generator().manual_seed(1))
    inputs = [features, *lstm.parameters()]
    fused = torch.autograd.grad((output * weights).sum(), inputs)
    reference = torch.autograd.grad((expected * weights).sum(), inputs)
    for got, want in zip(fused, reference, strict=True):
        scale = float(want.abs().max())
        assert scale > 1e-3  # a gradient that is there
        # round-off of sums over the steps, in another order: relative to the tensor's scale, not each entry's
        # (an entry near zero that sums 23 steps' contributions can differ by 1e-4 of itself)
        torch.testing.assert_close(got, want, rtol=0, atol=1e-5 * scale)


def test_a_reset_inside_a_sequence_falls_back_to_the_reference(monkeypatch):
    lstm, features, states, starts = padded_batch(n_seq=3, length=9, layers=1, starts_at_zero=[1])
    starts = starts.reshape(3, 9)
    starts[2, 4] = 1.0  # an episode that begins mid-sequence: the initial states cannot carry the reset
    starts = starts.flatten()
    expected = reference_sequence(features, states, starts, lstm)
    calls = []
    monkeypatch.setattr(
        networks.RecurrentMultiInputActorCriticPolicy,
        "_process_sequence",
        staticmethod(lambda *args: calls.append(1) or reference_sequence(*args)),
    )
    output, (hidden, cell) = fused_lstm_sequence(features, states, starts, lstm)
    assert calls == [1]
    assert (
        torch.equal(output, expected[0]) and torch.equal(hidden, expected[1][0]) and torch.equal(cell, expected[1][1])
    )


def test_misshaped_input_is_refused_naming_the_argument():
    lstm, features, states, starts = padded_batch(n_seq=3, length=9, layers=1, starts_at_zero=[0])
    with pytest.raises(ValueError, match="features"):
        fused_lstm_sequence(features[:, :4], states, starts, lstm)
    with pytest.raises(ValueError, match="features"):
        fused_lstm_sequence(features[:, 0], states, starts, lstm)  # one dimension
    with pytest.raises(ValueError, match="episode_starts"):
        fused_lstm_sequence(features, states, starts[:-1], lstm)
    with pytest.raises(ValueError, match="episode_starts"):
        fused_lstm_sequence(features[:-1], states, starts[:-1], lstm)  # 26 rows in 3 sequences


def one_update(fused: bool) -> RecurrentPPO:
    """One RecurrentPPO update on 2 envs of 12-step episodes (episodes begin inside every rollout)."""
    env = make_vec_env(
        "SeifExploreLoopBudget-v2", n_envs=2, seed=3, env_kwargs={"num_landmarks": 8, "max_episode_steps": 12}
    )
    model = RecurrentPPO(
        BeliefRecurrentPolicy,
        env,
        n_steps=30,
        batch_size=60,
        n_epochs=2,
        seed=5,
        device="cpu",
        policy_kwargs={"lstm_hidden_size": 16, "fused_lstm": fused},
    )
    model.learn(total_timesteps=60)
    return model


@pytest.mark.slow
def test_training_with_the_fused_step_collects_the_same_rollout_and_takes_the_same_update(monkeypatch):
    reference = one_update(fused=False)
    calls = []
    original = networks.RecurrentMultiInputActorCriticPolicy._process_sequence
    monkeypatch.setattr(
        networks.RecurrentMultiInputActorCriticPolicy,
        "_process_sequence",
        staticmethod(lambda *args: calls.append(1) or original(*args)),
    )
    fused = one_update(fused=True)
    assert calls == []  # every sequence of the update ran fused: the buffer cuts sequences at episode starts
    assert fused.policy.fused_lstm and not reference.policy.fused_lstm

    buffers = reference.rollout_buffer, fused.rollout_buffer
    assert buffers[0].episode_starts[1:].any()  # episodes began inside the rollout
    for name in ("actions", "values", "log_probs", "rewards"):
        np.testing.assert_array_equal(getattr(buffers[1], name), getattr(buffers[0], name), err_msg=name)

    for (name, got), (_, want) in zip(
        fused.policy.state_dict().items(), reference.policy.state_dict().items(), strict=True
    ):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-6, msg=name)
    untrained = RecurrentPPO(
        BeliefRecurrentPolicy,
        reference.get_env(),
        n_steps=30,
        seed=5,
        device="cpu",
        policy_kwargs={"lstm_hidden_size": 16},
    )
    moved = 0.0
    for (_, before), (_, after) in zip(
        untrained.policy.state_dict().items(), reference.policy.state_dict().items(), strict=True
    ):
        moved = max(moved, float((after - before).abs().max()))
    assert moved > 1e-4  # the update moved the weights far more than the tolerance


def test_fused_lstm_is_saved_with_the_model_and_refused_when_not_a_bool(tmp_path):
    fused = one_update(fused=True)
    fused.save(tmp_path / "model.zip")
    assert RecurrentPPO.load(tmp_path / "model.zip", device="cpu").policy.fused_lstm
    with pytest.raises(TypeError, match="fused_lstm"):
        RecurrentPPO(BeliefRecurrentPolicy, fused.get_env(), policy_kwargs={"fused_lstm": 1}, device="cpu")
