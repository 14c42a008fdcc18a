"""A user's progress across sessions, and two sessions on one time axis (the overlay).

Progress: each ended session's optimum (first found and at the end), peak and mean power,
work and profile fits (:class:`sessions.store.ProgressRecord`), with W/kg where the user's body
mass is known (:func:`sessions.units.per_kg`).

Overlay: both sessions' telemetry on a common grid of equal buckets, in seconds from an
alignment point (the session's start, or the start of its first phase of a kind, e.g. its
train phase), each bucket the mean of the samples in it. Computed from the stored chunks as
they stream by (an hour at 1 kHz is never in memory), so both series share their buckets
exactly and can be compared point by point.
"""

from __future__ import annotations

from datetime import datetime

import numpy as np

from sessions.codes import PHASE_KINDS
from sessions.requests import RequestError
from sessions.store import ProgressRecord, Store
from sessions.telemetry import INDEX, UNITS
from sessions.units import per_kg

OVERLAY_CHANNELS = ("w", "wd", "tau", "power", "W")
OVERLAY_UNITS = {**{k: UNITS[k] for k in ("w", "wd", "tau", "W")}, "power": "W", "t": "s"}
ALIGNMENTS = ("start", *PHASE_KINDS)


def progress(
    store: Store, user_id: int, *, since: datetime | None, until: datetime | None, limit: int
) -> tuple[ProgressRecord, list[dict[str, float | None]]]:
    """The user's progress, and per session its W/kg figures (None without a body mass)."""
    record = store.progress.user(user_id, since=since, until=until, limit=limit)
    mass = record.body_mass_kg
    per = [
        {
            "peak_power_per_kg": per_kg(p.peak_power, mass),
            "mean_power_per_kg": per_kg(p.mean_power, mass),
            "optimum_p_per_kg": per_kg(p.optimum_p, mass),
        }
        for p in record.sessions
    ]
    return record, per


def alignment(store: Store, session_id: int, align: str, field: str) -> float:
    """Session time of the alignment point."""
    if align == "start":
        store.sessions.get(session_id)  # 404 for an unknown session
        return 0.0
    for phase in store.phases.list(session_id):
        if phase.kind == align:
            return phase.t_start
    raise RequestError(field, f"session {session_id} has no {align} phase to align on")


def bucket_means(
    store: Store, session_id: int, offset: float, edges: np.ndarray
) -> tuple[dict[str, np.ndarray], int]:
    """Per bucket of ``edges`` (s from the alignment point), the mean of each overlay channel
    (NaN where a bucket has no sample), and the samples used."""
    n = len(edges) - 1
    sums = {k: np.zeros(n) for k in OVERLAY_CHANNELS}
    counts = {k: np.zeros(n) for k in OVERLAY_CHANNELS}
    used = 0
    lo, hi = edges[0] + offset, edges[-1] + offset
    for cols in store.telemetry.iter_chunks(session_id, start=max(lo, 0.0), end=hi, batch=64):
        idx = np.searchsorted(edges, cols[INDEX["t"]] - offset, side="right") - 1
        inside = (idx >= 0) & (idx < n)
        idx = idx[inside]
        used += int(inside.sum())
        w, tau = cols[INDEX["w"], inside], cols[INDEX["tau"], inside]
        values = {"w": w, "wd": cols[INDEX["wd"], inside], "tau": tau, "power": tau * w,
                  "W": cols[INDEX["W"], inside]}  # fmt: skip
        for k, x in values.items():
            ok = np.isfinite(x)
            sums[k] += np.bincount(idx[ok], weights=x[ok], minlength=n)
            counts[k] += np.bincount(idx[ok], minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = {k: np.where(counts[k] > 0, sums[k] / counts[k], np.nan) for k in sums}
    return means, used


def overlay_grid(
    store: Store, ids: tuple[int, int], offsets: tuple[float, float], points: int
) -> np.ndarray:
    """Bucket edges covering both sessions from the earlier start to the later end."""
    spans = [store.telemetry.span(sid) for sid in ids]
    lo = min(-off for off in offsets)
    hi = max(((s.t1 or 0.0) - off) for s, off in zip(spans, offsets, strict=True))
    if not hi > lo:
        hi = lo + 1.0
    return np.linspace(lo, hi, points + 1)
