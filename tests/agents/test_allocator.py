"""agents.allocator: freed blocks are reused without page faults, and training computes the same weights with it."""

from __future__ import annotations

import platform
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"

#: Page faults of touching a 64 MiB block freshly malloc'ed after an equal one was freed, in a new process.
REFAULT_SCRIPT = textwrap.dedent(
    """
    import ctypes, resource, sys
    from agents.allocator import keep_freed_memory
    if sys.argv[1] == "keep":
        assert keep_freed_memory()
    libc = ctypes.CDLL(None)
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = (ctypes.c_size_t,)
    libc.free.argtypes = (ctypes.c_void_p,)
    size = 64 << 20
    block = libc.malloc(size)
    ctypes.memset(block, 1, size)
    libc.free(block)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    block = libc.malloc(size)
    ctypes.memset(block, 2, size)
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    """
)


def _refaults(mode: str) -> int:
    done = subprocess.run([sys.executable, "-c", REFAULT_SCRIPT, mode], capture_output=True, text=True, check=True)
    return int(done.stdout.split()[-1])


@pytest.mark.slow
@pytest.mark.skipif(not GLIBC, reason="glibc's mallopt: the function returns False elsewhere (tested below)")
def test_a_freed_block_is_reused_without_faulting_its_pages_in_again():
    # glibc's default: the block is mapped anew and its pages fault in again (the control: this can fail);
    # 16 384 faults of 4 KiB pages, or 32 where the kernel backs the mapping with 2 MiB pages
    default = _refaults("default")
    assert default >= 32
    # kept: the second block is the first one's pages, already in memory
    assert _refaults("keep") * 10 < default


@pytest.mark.slow
def test_keep_freed_memory_says_whether_it_acted():
    # in a fresh process: it changes the allocator of the process it runs in
    script = "from agents.allocator import keep_freed_memory; print(keep_freed_memory())"
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert done.stdout.split() == [str(GLIBC)]


def _train_both(folder: Path) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """Final weights of one small run with the allocator kept and one without, side by side."""
    from stable_baselines3 import PPO

    # a fresh process each: the allocator's settings are process-wide and cannot be undone within one
    argv = [sys.executable, "-m", "agents.train", "--env", "SeifExplore-v1", "--n-envs", "2", "--seed", "3",
            "-n", "512", "--env-kwargs", '{"num_landmarks": 10, "max_episode_steps": 60}', "--hyperparams",
            "n_steps=128", "batch_size=128", "n_epochs=2", "env_wrapper=null", "--eval-freq", "-1",
            "--checkpoint-freq", "256", "--quiet"]  # fmt: skip
    runs = [subprocess.Popen([*argv, "--out", str(folder / "kept")], stderr=subprocess.PIPE, text=True),
            subprocess.Popen([*argv, "--out", str(folder / "plain"), "--no-keep-freed-memory"],
                             stderr=subprocess.PIPE, text=True)]  # fmt: skip
    for run in runs:
        _, errors = run.communicate(timeout=600)
        assert run.returncode == 0, errors
    kept, plain = (PPO.load(folder / name / "SeifExplore-v1.zip", device="cpu").policy.state_dict()
                   for name in ("kept", "plain"))  # fmt: skip
    return kept, plain


@pytest.mark.slow
def test_training_computes_the_same_weights_with_and_without_it(tmp_path):
    pytest.importorskip("rl_zoo3", reason="rl_zoo3 is in the train extra")
    kept, plain = _train_both(tmp_path)
    assert kept.keys() == plain.keys()
    for name in kept:
        assert torch.equal(kept[name], plain[name]), name
    # and the runs learned: the checkpoint at 256 steps (taken after the first update) differs
    from stable_baselines3 import PPO

    before = PPO.load(tmp_path / "kept" / "rl_model_256_steps.zip", device="cpu").policy.state_dict()
    assert any(not torch.equal(before[name], kept[name]) for name in kept)
