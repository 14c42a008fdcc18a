"""Min/max-preserving decimation of telemetry held column-major, shape (channels, samples).

A series is cut into consecutive blocks; each block becomes two samples per channel: its
minimum and its maximum, in the order they occur (so the time channel, which only grows,
keeps each block's first and last time). Every extreme of every channel survives, and a plot
of the result has the same envelope as the full-rate data. The operation composes: the pairs
of larger blocks made of whole smaller blocks equal the pairs of the smaller blocks' pairs,
which is what lets the store decimate from the per-chunk overview (see :mod:`.codec`)
without decoding full-rate data. NaN counts as neither minimum nor maximum unless a block is
all NaN.
"""

from __future__ import annotations

import numpy as np


def minmax_pairs(cols: np.ndarray, size: int) -> np.ndarray:
    """``cols`` (k, n) → (k, 2·⌈n/size⌉): min and max of each block of ``size`` samples,
    first-occurring first."""
    k, n = cols.shape
    if n == 0:
        return np.empty((k, 0))
    size = max(int(size), 1)
    nb = -(-n // size)
    pad = nb * size - n
    if pad:  # repeat the last sample: argmin/argmax return the first of equal values
        cols = np.concatenate((cols, np.repeat(cols[:, -1:], pad, axis=1)), axis=1)
    blocks = cols.reshape(k, nb, size)
    nan = np.isnan(blocks)
    if nan.any():
        imin = np.argmin(np.where(nan, np.inf, blocks), axis=2)
        imax = np.argmax(np.where(nan, -np.inf, blocks), axis=2)
    else:
        imin = np.argmin(blocks, axis=2)
        imax = np.argmax(blocks, axis=2)
    vmin = np.take_along_axis(blocks, imin[..., None], axis=2)[..., 0]
    vmax = np.take_along_axis(blocks, imax[..., None], axis=2)[..., 0]
    first_min = imin <= imax
    out = np.empty((k, nb, 2))
    out[..., 0] = np.where(first_min, vmin, vmax)
    out[..., 1] = np.where(first_min, vmax, vmin)
    return out.reshape(k, 2 * nb)


def decimate(cols: np.ndarray, points: int) -> np.ndarray:
    """At most ``points`` samples (``points`` ≥ 2) with every block's min and max; the data
    unchanged if it already fits."""
    n = cols.shape[1]
    if n <= points:
        return cols
    buckets = points // 2
    return minmax_pairs(cols, -(-n // buckets))


def decimate_pairs(pairs: np.ndarray, points: int) -> np.ndarray:
    """Like :func:`decimate` for a series of min/max pairs: buckets of whole pairs."""
    blocks = pairs.shape[1] // 2
    buckets = points // 2
    if blocks <= buckets:
        return pairs
    return minmax_pairs(pairs, 2 * -(-blocks // buckets))
