"""Threads: BLAS limits for seif_gym's command lines, and numba's threads for the batched kernels.

The filters factorise small dense blocks (tens to a few hundred rows), where
BLAS threads cost far more in synchronisation than they save
(``docs/performance_notes.md`` has figures). Environment variables such as
``OPENBLAS_NUM_THREADS`` act only before numpy is imported;
:func:`limit_blas_threads` acts at any time, through ``threadpoolctl`` (the
maintained library that finds every BLAS and OpenMP runtime a process has
loaded and sets their thread counts through their own APIs).

>>> from seif_gym.threads import limit_blas_threads
>>> libraries = limit_blas_threads(1)   # numpy's and scipy's BLAS, process-wide

With ``num_threads > 1`` the native vector env runs its envs' kernels in one
``numba.prange`` loop; :func:`numba_threads` runs such a loop on a given
number of numba's threads (each env's arithmetic is the same on any number).
One thread (the default) never starts numba's thread pool.

>>> from seif_gym.threads import numba_threads
>>> with numba_threads(1):
...     pass   # numba's parallel kernels run on one thread here
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np

__all__ = ["check_thread_count", "limit_blas_threads", "numba_threads"]

_numba_pool_started = False


def _start_numba_pool() -> None:
    """Start numba's thread pool once per process, leaving OpenMP's thread counts as they were.

    Numba picks its threading layer when the pool starts (``NUMBA_THREADING_LAYER``; by default TBB,
    else GNU OpenMP where it finds it: torch loads it, else its own work queue). Starting it on GNU
    OpenMP sets torch's OpenMP thread count to numba's (undoing ``OMP_NUM_THREADS=1``, which changes
    what torch computes), so the counts are put back after the start. That layer also kills a
    ``fork``-ed child that runs a parallel kernel ("fork() called from a process already using GNU
    OpenMP"): ``NUMBA_THREADING_LAYER=forksafe`` picks a layer without that limit (numba's work queue
    where TBB is absent), at some cost in speed.
    """
    global _numba_pool_started
    if _numba_pool_started:
        return
    import numba
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=None, user_api="openmp"):  # restores the OpenMP thread counts on exit
        numba.get_num_threads()  # starts the pool (a no-op where it runs already)
    _numba_pool_started = True


def check_thread_count(value: object, name: str) -> int:
    """``value`` as a count of numba threads, from 1 to ``NUMBA_NUM_THREADS``; a clear error naming ``name`` else."""
    import numba

    limit = numba.config.NUMBA_NUM_THREADS
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int in [1, {limit}] (NUMBA_NUM_THREADS), got {value!r}")
    if not 1 <= value <= limit:
        raise ValueError(f"{name} must be an int in [1, {limit}] (NUMBA_NUM_THREADS), got {value!r}")
    return int(value)


@contextlib.contextmanager
def numba_threads(count: int) -> Iterator[None]:
    """Run numba's parallel kernels on ``count`` threads inside the block.

    Numba's count is per calling thread; it is put back on exit. The first use starts numba's thread
    pool (:func:`_start_numba_pool`).

    Parameters
    ----------
    count : int
        Threads, from 1 to ``numba.config.NUMBA_NUM_THREADS`` (checked before anything starts).
    """
    count = check_thread_count(count, "count")
    _start_numba_pool()
    import numba

    previous = numba.get_num_threads()
    numba.set_num_threads(count)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def limit_blas_threads(count: int = 1) -> list[str]:
    """Limit every BLAS this process has loaded (numpy's and scipy's) to ``count`` threads.

    The limit is process-wide and stays until changed. scipy's BLAS (also
    called by the numba kernels) is loaded first, so that it is limited too.

    Parameters
    ----------
    count : int
        Threads per BLAS library (at least 1).

    Returns
    -------
    list of str
        The paths of the BLAS libraries now limited (empty where none was
        found).

    Raises
    ------
    TypeError
        If ``count`` is not an int.
    ValueError
        If ``count`` is less than 1.
    """
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)):
        raise TypeError(f"count must be an int, got {type(count).__name__}")
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    import scipy.linalg  # noqa: F401  (loads scipy's BLAS, so that it is limited too)
    from threadpoolctl import threadpool_info, threadpool_limits

    threadpool_limits(limits=int(count), user_api="blas")
    return [str(info["filepath"]) for info in threadpool_info() if info.get("user_api") == "blas"]
