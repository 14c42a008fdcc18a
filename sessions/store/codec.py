"""How a telemetry chunk is stored (``encoding = 1``).

A chunk is at most one second of the ten channels of :mod:`sessions.telemetry`. Its payload
holds them column by column: ``t`` and ``q`` (which grow without bound) as float64, the
other eight as float32 (7 significant digits, far finer than any sensor of the machine).
The bytes of each group are shuffled into planes (all first bytes, then all second
bytes, …: neighbouring samples share their high bytes) and the whole is one zstd frame at
level 1. On simulated 1 kHz sessions (with noise) payload and overview take about 1 MB per
session minute, a fifth of raw float64, and decode at several hundred MB/s.

``overview`` holds the chunk's min/max pairs per block of :data:`BLOCK` samples
(:func:`sessions.store.decimate.minmax_pairs`, computed from the values as stored) in the
same layout without the shuffle (it is small; unshuffled it decodes with no per-chunk
work), so decimating a long session needs no full-rate decoding.
"""

from __future__ import annotations

import threading

import numpy as np
import zstandard

from sessions.store.decimate import minmax_pairs
from sessions.telemetry import WIDTH

ENCODING = 1
BLOCK = 32  # samples per overview block
DOUBLE = 2  # the first two channels (t, q) stay float64
LEVEL = 1

_local = threading.local()


def _compressor() -> zstandard.ZstdCompressor:
    c = getattr(_local, "c", None)
    if c is None:
        c = _local.c = zstandard.ZstdCompressor(level=LEVEL)
    return c


def _decompressor() -> zstandard.ZstdDecompressor:
    d = getattr(_local, "d", None)
    if d is None:
        d = _local.d = zstandard.ZstdDecompressor()
    return d


def _shuffle(a: np.ndarray) -> bytes:
    w = a.dtype.itemsize
    return np.ascontiguousarray(a).view(np.uint8).reshape(-1, w).T.tobytes()


def _unshuffle(planes: np.ndarray, dtype: type[np.floating]) -> np.ndarray:
    """Byte planes (w, m) back to m values, by shifts and ors (faster than a strided copy)."""
    w = planes.shape[0]
    ut = np.uint64 if w == 8 else np.uint32
    acc = planes[0].astype(ut)
    for i in range(1, w):
        acc |= planes[i].astype(ut) << ut(8 * i)
    return acc.view(dtype)


def quantize(cols: np.ndarray) -> np.ndarray:
    """``cols`` (WIDTH, n) as they will read back: the float32 channels rounded."""
    out = np.array(cols, dtype=np.float64)
    out[DOUBLE:] = out[DOUBLE:].astype(np.float32)
    return out


def pack(cols: np.ndarray, *, shuffle: bool = True) -> bytes:
    hi = np.ascontiguousarray(cols[:DOUBLE], dtype=np.float64)
    lo = np.ascontiguousarray(cols[DOUBLE:], dtype=np.float32)
    if shuffle:
        return _compressor().compress(_shuffle(hi) + _shuffle(lo))
    return _compressor().compress(hi.tobytes() + lo.tobytes())


def unpack(
    blob: bytes, n: int, out: np.ndarray | None = None, *, shuffle: bool = True
) -> np.ndarray:
    """(WIDTH, n) float64 from :func:`pack`'s bytes, written into ``out`` if given."""
    raw = np.frombuffer(_decompressor().decompress(blob), dtype=np.uint8)
    split = 8 * DOUBLE * n
    if raw.size != split + 4 * (WIDTH - DOUBLE) * n:
        raise ValueError(f"telemetry chunk holds {raw.size} bytes, not {n} samples")
    if out is None:
        out = np.empty((WIDTH, n))
    if shuffle:
        hi = _unshuffle(raw[:split].reshape(8, -1), np.float64)
        lo = _unshuffle(raw[split:].reshape(4, -1), np.float32)
    else:
        hi, lo = raw[:split].view(np.float64), raw[split:].view(np.float32)
    out[:DOUBLE] = hi.reshape(DOUBLE, n)
    out[DOUBLE:] = lo.reshape(WIDTH - DOUBLE, n)
    return out


def overview_length(n: int) -> int:
    return 2 * -(-n // BLOCK)


def encode(cols: np.ndarray) -> tuple[bytes, bytes]:
    """Payload and overview of one chunk given column-major (WIDTH, n) float64."""
    return pack(cols), pack(minmax_pairs(quantize(cols), BLOCK), shuffle=False)


def decode(payload: bytes, n: int, encoding: int, out: np.ndarray | None = None) -> np.ndarray:
    if encoding != ENCODING:
        raise ValueError(f"unknown telemetry encoding {encoding}")
    return unpack(payload, n, out)


def decode_overview(overview: bytes, n: int, encoding: int) -> np.ndarray:
    if encoding != ENCODING:
        raise ValueError(f"unknown telemetry encoding {encoding}")
    return unpack(overview, overview_length(n), shuffle=False)
