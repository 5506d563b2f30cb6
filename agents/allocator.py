"""The C heap of a training process: keep what it frees for reuse instead of handing it back to the kernel.

Torch's CPU tensors come from the C library's ``malloc``. glibc serves a block
of 128 KiB or more (a threshold that rises with use, up to 32 MiB) with a fresh
``mmap``, unmaps it again on ``free``, and hands the top of its heap back to
the kernel once more than that lies free there. A PPO update builds and drops
tensors of tens of MiB over and over, so without this every page of each is
mapped, zeroed and faulted in anew. :func:`keep_freed_memory` tells glibc to
serve every block from its heap (``M_MMAP_MAX = 0``) and to keep what is freed
there (``M_TRIM_THRESHOLD`` at its maximum). Results are the same bit for bit
(``tests/agents/test_allocator.py``); the process keeps its peak heap until it exits.
What it saves is in ``docs/performance_notes.md``.

``python -m agents.train`` calls it before building the run
(``--no-keep-freed-memory`` leaves the allocator alone).

Usage (process-wide, best before torch allocates)::

    from agents.allocator import keep_freed_memory
    keep_freed_memory()   # True where the C library is glibc; False, and nothing changed, elsewhere
"""

from __future__ import annotations

import ctypes
import platform

__all__ = ["keep_freed_memory"]

#: ``mallopt`` parameters of glibc's ``<malloc.h>``.
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
#: The largest trim threshold ``mallopt`` takes (an ``int``): 2 GiB, never reached by a free top of heap here.
TRIM_THRESHOLD_MAX = 2**31 - 1


def keep_freed_memory() -> bool:
    """Make glibc's ``malloc`` serve every block from its heap and never give freed memory back.

    Process-wide, for every allocation from here on (blocks already mapped are
    unmapped as before when freed). Numerical results do not change: only
    where a block lives does.

    Returns
    -------
    bool
        ``True`` if both settings took effect; ``False`` where the C library
        is not glibc (nothing is changed there).
    """
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    libc = ctypes.CDLL(None)  # the C library this process already runs on
    mallopt = libc.mallopt
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    # the trim threshold first: setting either also stops glibc from adjusting both thresholds itself
    return bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_MAX)) and bool(mallopt(M_MMAP_MAX, 0))
