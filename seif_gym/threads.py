"""BLAS thread limits for seif_gym's command lines: one small helper over ``threadpoolctl``.

The filters factorise small dense blocks (tens to a few hundred rows), where
BLAS threads cost far more in synchronisation than they save: on a loaded
2-core machine a threaded 160 × 160 Cholesky took 80 ms instead of 0.06 ms,
and one 63 × 63 solve 40 ms instead of 0.7 ms. Environment variables such as
``OPENBLAS_NUM_THREADS`` act only before numpy is imported;
:func:`limit_blas_threads` acts at any time, through ``threadpoolctl`` (the
maintained library that finds every BLAS and OpenMP runtime a process has
loaded and sets their thread counts through their own APIs).

>>> from seif_gym.threads import limit_blas_threads
>>> libraries = limit_blas_threads(1)   # numpy's and scipy's BLAS, process-wide
"""

from __future__ import annotations

import numpy as np

__all__ = ["limit_blas_threads"]


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
