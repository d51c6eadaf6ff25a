"""The library's one pool of threads, for work split into one contiguous piece per thread: the
fast engine's kernels (numba, ``nogil``), the self-intersection sweep of the mesh checks and the
image step's large NumPy ufuncs (NumPy releases the GIL in its loops).

The pool is kept for the life of the process: starting a thread per call cost more than half of
what splitting an ``exp`` of a 512 x 512 image over two threads saves. Its threads are named
``xray_viz-pool_N`` (idle between calls; :func:`xray_viz.cli.run` knows them).
"""

from __future__ import annotations

import os
import sys
import threading

_pool = None
_lock = threading.Lock()


def count() -> int:
    """Threads to split work over: numba's setting when numba is loaded (``NUMBA_NUM_THREADS``,
    or ``numba.set_num_threads`` once called: the engine's), else the processors this process
    may use. It never starts numba's threading layer (the kernels are not ``parallel``; an old
    TBB, which Open3D brings, makes that start warn)."""
    numba = sys.modules.get("numba")
    if numba is not None:
        layer = sys.modules.get("numba.np.ufunc.parallel")
        if getattr(layer, "_is_initialized", False):      # set_num_threads was called
            return numba.get_num_threads()
        return int(numba.config.NUMBA_NUM_THREADS)
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def pool(k: int):
    """The pool, with at least ``k - 1`` threads (the caller runs one piece itself)."""
    global _pool
    with _lock:
        if _pool is None or _pool._max_workers < k - 1:
            from concurrent.futures import ThreadPoolExecutor

            old, _pool = _pool, ThreadPoolExecutor(max_workers=k - 1,
                                                   thread_name_prefix="xray_viz-pool")
            if old is not None:
                old.shutdown(wait=False)
        return _pool


def run_pieces(fn, k: int) -> list:
    """``[fn(0), ..., fn(k - 1)]``, piece 0 in this thread and the others on the pool; every
    piece has ended when this returns (the first exception is raised after)."""
    if k <= 1:
        return [fn(0)]
    futures = [pool(k).submit(fn, j) for j in range(1, k)]
    try:
        first = fn(0)
    finally:
        rest = [f.result() for f in futures]
    return [first, *rest]
