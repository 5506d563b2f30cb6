"""A SEIF or ESEIF step that fails at any stage leaves the filter bit-identical.

Failures are injected by replacing a kernel (or a step function) with one that
raises, either instead of the real computation or after it has written its
results (a failure midway through a step). The state compared is every array
and scalar of the filter, its information store and its recovery queue, raw
(spare capacity included), and the id table.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from seif_gym.slam import ESEIF, SEIF, _kernels
from seif_gym.slam import eseif as eseif_module
from seif_gym.slam import seif as seif_module


class InjectedFailure(np.linalg.LinAlgError):
    """The failure the tests inject (a LinAlgError, like a failed Cholesky)."""


def state_of(filt) -> dict[str, object]:
    """Everything a filter holds, as plain values (arrays copied raw, capacity included)."""
    state: dict[str, object] = {}
    for prefix, owner in (("filter", filt), ("store", filt._store), ("queue", filt._queue)):
        for name, value in vars(owner).items():
            if isinstance(value, np.ndarray):
                state[f"{prefix}.{name}"] = (value.dtype.str, value.shape, value.tobytes())
            elif isinstance(value, (int, float, bool, str, type(None))):
                state[f"{prefix}.{name}"] = value
            elif isinstance(value, dict) and name == "_id_to_index":
                state[f"{prefix}.{name}"] = dict(value)
    return state


def assert_same_state(before: dict, after: dict) -> None:
    assert before.keys() == after.keys()
    changed = [key for key in before if before[key] != after[key]]
    assert not changed, f"changed by the failed step: {changed}"


def failing(real, *, call_through: bool, on_call: int = 1):
    """A stand-in for ``real`` that raises on its ``on_call``-th call (after running ``real`` if ``call_through``)."""
    calls = {"n": 0}

    def stand_in(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == on_call:
            if call_through:
                real(*args, **kwargs)
            raise InjectedFailure("injected failure")
        return real(*args, **kwargs)

    stand_in.calls = calls
    return stand_in


def busy(cls, ring_loop_run, steps: int, **options):
    motion, sensor, run = ring_loop_run
    filt = cls(motion, sensor, run.initial_pose, **options)
    for t in range(steps):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    return filt


def advance_to(filt, ring_loop_run, start: int, wanted) -> int:
    """Feed ``filt`` from step ``start`` up to (not including) the first step whose update does what
    ``wanted(copy_before, copy_after)`` says, and return that step."""
    _, _, run = ring_loop_run
    probe = copy.deepcopy(filt)
    for t in range(start, run.steps):
        before = copy.deepcopy(probe)
        probe.predict(run.controls[t], run.dt)
        probe.update(run.ranges[t], run.bearings[t], run.ids[t])
        if wanted(before, probe):
            for s in range(start, t):
                filt.predict(run.controls[s], run.dt)
                filt.update(run.ranges[s], run.bearings[s], run.ids[s])
            return t
    raise AssertionError("no step of the run exercises this stage")


def adds_and_deactivates(before, after) -> bool:
    """A step that adds a landmark (capacity may grow) and deactivates one: every SEIF stage runs."""
    added = after.num_landmarks > before.num_landmarks
    return added and bool(set(before.active_landmarks.tolist()) - set(after.active_landmarks.tolist()))


def check_failed_step(filt, ring_loop_run, t, monkeypatch, module, name, *, call_through, on_call=1, stage="update"):
    """Step ``t`` with ``module.name`` failing on its ``on_call``-th call: the filter is unchanged, then goes on
    exactly as a copy that never failed."""
    _, _, run = ring_loop_run
    control, dt, ranges, bearings, ids = run.controls[t], run.dt, run.ranges[t], run.bearings[t], run.ids[t]
    reference = copy.deepcopy(filt)
    stand_in = failing(getattr(module, name), call_through=call_through, on_call=on_call)
    monkeypatch.setattr(module, name, stand_in)
    if stage != "predict":
        filt.predict(control, dt)
        reference.predict(control, dt)
    before = state_of(filt)
    with pytest.raises(InjectedFailure):
        filt.predict(control, dt) if stage == "predict" else filt.update(ranges, bearings, ids)
    assert stand_in.calls["n"] == on_call
    assert_same_state(before, state_of(filt))
    monkeypatch.undo()
    if stage == "predict":
        filt.predict(control, dt)
        reference.predict(control, dt)
    filt.update(ranges, bearings, ids)
    reference.update(ranges, bearings, ids)
    assert_same_state(state_of(reference), state_of(filt))


def cases(stages: list[tuple], stage_column: int, instead_only: str) -> list[tuple]:
    """Each stage failing instead of its computation and after it (midway), except ``instead_only``."""
    return [(*stage, through) for stage in stages for through in (False, True)
            if not (through and stage[stage_column] == instead_only)]  # fmt: skip


# (module, attribute, filter options, what the failing step must exercise)
SEIF_STAGES = [
    (_kernels, "predict", {}, "predict"),
    (_kernels, "measurement_update", {}, "update"),
    (_kernels, "recover_mean_wavefront", {}, "update"),
    (_kernels, "recover_mean", {"mean_recovery": "amortized"}, "update"),
    (seif_module, "recover_mean_exact", {"mean_recovery": "exact"}, "update"),
    (_kernels, "sparsify", {}, "sparsify"),
]
# The compiled motion update (gather, compute, scatter in one kernel) can only fail before it writes: its
# "midway" case is not a failure that can happen, and the journal of a motion update saves no rows for it.
SEIF_CASES = cases(SEIF_STAGES, 3, "predict")


@pytest.mark.parametrize(
    "module, name, options, stage, call_through", SEIF_CASES,
    ids=[f"{c[1]}-{'midway' if c[4] else 'instead'}" for c in SEIF_CASES],
)  # fmt: skip
def test_seif_failure_leaves_filter_unchanged(ring_loop_run, monkeypatch, module, name, options, stage, call_through):
    filt = busy(SEIF, ring_loop_run, 60, max_active=4, **options)
    t = advance_to(filt, ring_loop_run, 60, adds_and_deactivates)
    check_failed_step(filt, ring_loop_run, t, monkeypatch, module, name, call_through=call_through, stage=stage)


# (module, attribute, which call of it fails, the stage)
ESEIF_STAGES = [
    (eseif_module, "relocalization_pose_information", 1, "plan"),
    (_kernels, "measurement_update", 1, "alpha"),  # (b): incorporate z_alpha
    (_kernels, "recover_mean_wavefront", 1, "recover"),  # after (b)
    (eseif_module, "marginalize_robot_block", 1, "marginalize"),  # (c)
    (_kernels, "measurement_update", 2, "relocalize"),  # (d): z_beta on the new pose
    (_kernels, "recover_mean_wavefront", 2, "recover after relocalization"),
    (_kernels, "recover_mean", 2, "amortized recover after relocalization"),  # with mean_recovery="amortized"
]
# planning writes nothing, so failing after it is the same case as failing instead of it
ESEIF_CASES = cases(ESEIF_STAGES, 3, "plan")


@pytest.mark.parametrize(
    "module, name, on_call, stage, call_through", ESEIF_CASES,
    ids=[f"{c[3]}-{'midway' if c[4] else 'instead'}" for c in ESEIF_CASES],
)  # fmt: skip
def test_eseif_failure_leaves_filter_unchanged(ring_loop_run, monkeypatch, module, name, on_call, stage, call_through):
    recovery = "amortized" if name == "recover_mean" else "wavefront"
    filt = busy(ESEIF, ring_loop_run, 60, max_active=3, mean_recovery=recovery)
    t = advance_to(filt, ring_loop_run, 60, lambda before, after: after.relocalizations > before.relocalizations)
    check_failed_step(filt, ring_loop_run, t, monkeypatch, module, name, call_through=call_through, on_call=on_call)


def test_reference_path_failure_leaves_filter_unchanged(ring_loop_run, monkeypatch):
    """The plain numpy path restores too (its recovery saves copies instead of logging)."""
    filt = busy(SEIF, ring_loop_run, 60, max_active=4, implementation="reference")
    t = advance_to(filt, ring_loop_run, 60, adds_and_deactivates)
    check_failed_step(filt, ring_loop_run, t, monkeypatch, seif_module, "sparsify", call_through=True)
