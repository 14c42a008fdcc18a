"""What an export is given, as plain data: a session's telemetry columns and its protocol phases,
and the totals both exports compute from them in one way.

Telemetry comes as columns named as in :mod:`sessions.telemetry` (``t``, ``w``, ``tau`` …):
a mapping of name → 1-D array, or anything with a ``column(name)`` method (the store's
:class:`~sessions.store.TelemetryData`, a :class:`~sessions.simulation.SimulationResult`).
Times ``t`` are seconds since the session started.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sessions.telemetry import NAMES

Columns = Mapping[str, np.ndarray]


class ExportError(ValueError):
    """Input an export cannot use, with a one-line reason naming the argument."""


@dataclass(frozen=True, slots=True)
class Phase:
    """One phase of a session's protocol, in seconds since the session started, with the
    totals the runner stored for it (None: computed from the telemetry)."""

    name: str
    start: float
    end: float
    kind: str = ""  # warmup, seek, train, work, rest, profile, cooldown …
    mean_power: float | None = None  # W
    peak_power: float | None = None  # W
    work: float | None = None  # J
    optimum_w: float | None = None  # rad/s, the optimum this phase found or held
    at_bound: str | None = None  # lower, upper: that optimum is the bracket's edge, not a peak


@dataclass(frozen=True, slots=True)
class Totals:
    """Totals over a span of telemetry: the definitions of :class:`~sessions.summary.SessionSummary`
    (power τ·w, τ̂·w under RISE; work from the passivity integral W (5))."""

    duration: float  # s
    mean_power: float  # W
    peak_power: float  # W
    work: float  # J
    mean_w: float  # rad/s
    peak_w: float  # rad/s


def telemetry_columns(source: Any, names: Iterable[str]) -> dict[str, np.ndarray]:
    """The named columns of ``source`` as float arrays of one length, ``t`` finite and
    non-decreasing; :class:`ExportError` otherwise."""
    out: dict[str, np.ndarray] = {}
    for name in names:
        if name not in NAMES:
            raise ExportError(f"telemetry: unknown channel {name!r}")
        try:
            col = source[name] if isinstance(source, Mapping) else source.column(name)
        except (KeyError, AttributeError):
            raise ExportError(f"telemetry.{name}: missing") from None
        col = np.asarray(col, dtype=float)
        if col.ndim != 1:
            raise ExportError(f"telemetry.{name}: must be 1-D, got shape {col.shape}")
        out[name] = col
    lengths = {len(c) for c in out.values()}
    if len(lengths) > 1:
        raise ExportError(f"telemetry: columns differ in length {sorted(lengths)}")
    t = out.get("t")
    if t is not None and len(t):
        if not np.isfinite(t).all():
            raise ExportError("telemetry.t: not finite (NaN or ∞)")
        if (np.diff(t) < 0).any():
            raise ExportError("telemetry.t: must not decrease")
    return out


def sample_period(t: np.ndarray) -> float:
    """The loop period: the median spacing of the first 10 000 samples of ``t`` (robust to a
    lost sample; 0 for fewer than two samples)."""
    return float(np.median(np.diff(t[:10_001]))) if len(t) > 1 else 0.0


def check_phases(phases: Sequence[Phase]) -> tuple[Phase, ...]:
    """Phases in order and not overlapping, each ending after it starts."""
    out = tuple(phases)
    for i, ph in enumerate(out):
        if not isinstance(ph, Phase):
            raise ExportError(f"phases[{i}]: must be a Phase, got {type(ph).__name__}")
        if not (math.isfinite(ph.start) and math.isfinite(ph.end)) or ph.start < 0:
            raise ExportError(f"phases[{i}]: start and end must be finite and ≥ 0")
        if not ph.end > ph.start:
            raise ExportError(f"phases[{i}].end: must be after start ({ph.start} s), got {ph.end}")
        if i and ph.start < out[i - 1].end - 1e-9:
            raise ExportError(
                f"phases[{i}].start: overlaps the phase before (ends {out[i - 1].end} s), "
                f"got {ph.start}"
            )
    return out


def totals(cols: Columns, start: float | None = None, end: float | None = None) -> Totals:
    """Totals over the samples with ``start ≤ t < end`` (either bound optional). Work is the
    rise of W over them: W[k] includes period k's τ w dt, so it is W[last] - W[first - 1]."""
    t = cols["t"]
    i = 0 if start is None else int(np.searchsorted(t, start, "left"))
    j = len(t) if end is None else int(np.searchsorted(t, end, "left"))
    dt = sample_period(t)
    if j <= i:
        return Totals(0.0 if start is None or end is None else end - start, 0.0, 0.0, 0.0, 0.0, 0.0)
    w, tau, W = cols["w"][i:j], cols["tau"][i:j], cols["W"]
    power = tau * w
    before = float(W[i - 1]) if i > 0 else 0.0
    duration = (j - i) * dt if start is None or end is None else end - start
    return Totals(
        duration=duration,
        mean_power=float(np.nanmean(power)),
        peak_power=float(np.nanmax(power)),
        work=float(W[j - 1]) - before,
        mean_w=float(np.nanmean(w)),
        peak_w=float(np.nanmax(w)),
    )


def write_atomically(path: str | Path, data: bytes) -> int:
    """``data`` to ``path`` through a temporary file in the same folder (a reader never sees
    a partial file); returns its size in bytes."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return len(data)
