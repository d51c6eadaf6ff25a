"""Random numbers of the transport: xoshiro256** (Blackman and Vigna) in numba, one stream per
batch of histories, seeded from NumPy's :class:`~numpy.random.SeedSequence`.

A batch's numbers depend only on the seed and the batch's index, so the same seed gives the
same histories on any number of threads, processes or Dask workers.
"""

from __future__ import annotations

import numba
import numpy as np

import xray_viz.tracing._numba_cache  # noqa: F401  (the kernels' one disk cache)

__all__ = ["batch_states"]            # and the kernel ``uniform``


def batch_states(seed: int, n_batches: int, *, first: int = 0) -> np.ndarray:
    """(n_batches, 4) uint64: the xoshiro256** states of batches ``first ...``.

    Examples
    --------
    >>> a = batch_states(7, 3)
    >>> bool((batch_states(7, 2, first=1) == a[1:]).all())
    True
    """
    out = np.empty((n_batches, 4), np.uint64)
    for k in range(n_batches):
        ss = np.random.SeedSequence(entropy=int(seed), spawn_key=(first + k,))
        out[k] = ss.generate_state(4, np.uint64)
        if not out[k].any():                    # the one state xoshiro cannot leave
            out[k, 0] = 1
    return out


@numba.njit(inline="always")
def _rotl(x, k):
    return (x << np.uint64(k)) | (x >> np.uint64(64 - k))


@numba.njit(cache=True, nogil=True)
def uniform(s):
    """A float64 uniform in [0, 1) from the state ``s`` ((4,) uint64, advanced in place)."""
    result = _rotl(s[1] * np.uint64(5), 7) * np.uint64(9)
    t = s[1] << np.uint64(17)
    s[2] ^= s[0]
    s[3] ^= s[1]
    s[1] ^= s[2]
    s[0] ^= s[3]
    s[2] ^= t
    s[3] = _rotl(s[3], 45)
    return float(result >> np.uint64(11)) * (1.0 / 9007199254740992.0)
