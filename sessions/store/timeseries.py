"""Telemetry of a session: the full-rate channels of :mod:`sessions.telemetry` stored as
compressed chunks of at most one second (:mod:`.codec`), written by the
:class:`~sessions.store.recorder.SessionRecorder` and read back here at full rate, decimated
(min/max-preserving, :mod:`.decimate`), for a time window, or as CSV streamed chunk by chunk.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session as OrmSession

from sessions.store import codec
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.decimate import decimate, decimate_pairs, minmax_pairs
from sessions.store.errors import NotFoundError, StoreValueError
from sessions.store.models import ExerciseSession, TelemetryChunk
from sessions.store.records import TelemetryData, TelemetrySpan
from sessions.telemetry import NAMES, WIDTH, csv_header

CHUNK_SECONDS = 1.0  # a chunk spans less than this: t[-1] - t[0] < 1 s
MAX_CHUNK_SAMPLES = 20_000  # one second at the highest loop rate a configuration allows
OVERVIEW_FACTOR = 4  # decimate from the overview when a bucket spans ≥ 4 overview blocks
CSV_FORMAT = ",".join(["%.9g"] * WIDTH) + "\n"
_C = TelemetryChunk


def columns_of(rows: Any, after: float | None = None) -> np.ndarray:
    """Telemetry rows (n, WIDTH) or one row, checked, as float64 columns (WIDTH, n): time
    finite, ≥ 0, strictly increasing and after ``after``. Other channels may hold NaN or ±inf
    (a fault's last samples are worth keeping as they are)."""
    try:
        a = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise StoreValueError("telemetry", f"not an array of numbers ({exc})") from None
    if a.ndim == 1 and a.size == WIDTH:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != WIDTH:
        raise StoreValueError(
            "telemetry", f"expected rows of {WIDTH} channels ({', '.join(NAMES)}), got {a.shape}"
        )
    t = a[:, 0]
    if t.size:
        if not np.isfinite(t).all():
            raise StoreValueError("telemetry.t", "must be finite")
        if t[0] < 0:
            raise StoreValueError("telemetry.t", f"must be at least 0, got {t[0]:g}")
        if t.size > 1 and not (np.diff(t) > 0).all():
            raise StoreValueError("telemetry.t", "must increase from sample to sample")
        if after is not None and t[0] <= after:
            raise StoreValueError(
                "telemetry.t", f"starts at {t[0]:g}, not after the last sample stored ({after:g})"
            )
    return np.ascontiguousarray(a.T)


def chunk_starts(t: np.ndarray) -> list[int]:
    """Where each chunk of ``t`` begins: every chunk spans < 1 s and ≤ MAX_CHUNK_SAMPLES."""
    starts: list[int] = []
    i, n = 0, len(t)
    while i < n:
        starts.append(i)
        j = int(np.searchsorted(t, t[i] + CHUNK_SECONDS, side="left"))
        i = min(max(j, i + 1), i + MAX_CHUNK_SAMPLES)
    return starts


def chunk_row(session_id: int, seq: int, cols: np.ndarray) -> dict[str, Any]:
    payload, overview = codec.encode(cols)
    return {
        "session_id": session_id,
        "seq": seq,
        "t0": float(cols[0, 0]),
        "t1": float(cols[0, -1]),
        "n": int(cols.shape[1]),
        "encoding": codec.ENCODING,
        "payload": payload,
        "overview": overview,
    }


INDEX_OF = {name: i for i, name in enumerate(NAMES)}


def _unknown(name: str) -> int:
    raise StoreValueError("channels", f"unknown channel {name!r} (one of {', '.join(NAMES)})")


def _window(start: Any, end: Any) -> tuple[float | None, float | None]:
    lo = None if start is None else v.number("start", start)
    hi = None if end is None else v.number("end", end)
    if lo is not None and hi is not None and hi < lo:
        raise StoreValueError("end", f"{hi:g} is before start {lo:g}")
    return lo, hi


def _trim(cols: np.ndarray, lo: float | None, hi: float | None) -> np.ndarray:
    t = cols[0]
    i = 0 if lo is None else int(np.searchsorted(t, lo, side="left"))
    j = len(t) if hi is None else int(np.searchsorted(t, hi, side="right"))
    return cols[:, i:j]


def _where(session_id: int, lo: float | None, hi: float | None) -> list[Any]:
    where: list[Any] = [_C.session_id == session_id]
    if lo is not None:
        where.append(_C.t1 >= lo)
    if hi is not None:
        where.append(_C.t0 <= hi)
    return where


def _require_session(s: OrmSession, session_id: int) -> None:
    if s.get(ExerciseSession, session_id) is None:
        raise NotFoundError("session", session_id)


class TelemetryRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def span(self, session_id: int) -> TelemetrySpan:
        """Samples, chunks, first and last time and stored bytes, without decoding."""
        with self._db.session(write=False) as s:
            _require_session(s, session_id)
            chunks, samples, t0, t1, size = s.execute(
                select(
                    func.count(),
                    func.coalesce(func.sum(_C.n), 0),
                    func.min(_C.t0),
                    func.max(_C.t1),
                    func.coalesce(func.sum(func.length(_C.payload) + func.length(_C.overview)), 0),
                ).where(_C.session_id == session_id)
            ).one()
        return TelemetrySpan(
            samples=int(samples), chunks=int(chunks), t0=t0, t1=t1, stored_bytes=int(size)
        )

    def load(
        self,
        session_id: int,
        *,
        start: float | None = None,
        end: float | None = None,
        points: int | None = None,
    ) -> TelemetryData:
        """The session's telemetry with ``start ≤ t ≤ end`` (either bound optional): at full
        rate, or, with ``points``, at most that many samples: min/max pairs of equal buckets
        (every extreme kept) when the window holds more."""
        lo, hi = _window(start, end)
        if points is not None:
            points = v.integer("points", points, ge=2, le=10_000_000)
        where = _where(session_id, lo, hi)
        with self._db.session(write=False) as s:
            _require_session(s, session_id)
            meta = s.execute(select(_C.seq, _C.n).where(*where).order_by(_C.seq)).all()
            estimate = sum(n for _, n in meta)
            if not meta:
                return TelemetryData(np.empty((WIDTH, 0)), decimated=False, samples=0)
            last = meta[-1][0]
            if points is not None and estimate > points:
                per_bucket = estimate / (points // 2)
                if per_bucket >= OVERVIEW_FACTOR * codec.BLOCK:
                    pairs, samples = self._overview(s, where, last, lo, hi)
                    return TelemetryData(
                        decimate_pairs(pairs, points), decimated=True, samples=samples
                    )
            cols = self._full(s, where, last, lo, hi)
        samples = cols.shape[1]
        if points is not None and samples > points:
            return TelemetryData(decimate(cols, points), decimated=True, samples=samples)
        return TelemetryData(cols, decimated=False, samples=samples)

    def iter_chunks(
        self,
        session_id: int,
        *,
        start: float | None = None,
        end: float | None = None,
        batch: int = 16,
    ) -> Iterator[np.ndarray]:
        """Full-rate columns (WIDTH, n) chunk after chunk, read ``batch`` chunks per short
        transaction, so a long session is never in memory at once."""
        lo, hi = _window(start, end)
        batch = v.integer("batch", batch, ge=1, le=10_000)
        with self._db.session(write=False) as s:
            _require_session(s, session_id)
        return self._chunks(session_id, lo, hi, batch)

    def columns(
        self,
        session_id: int,
        names: tuple[str, ...],
        *,
        start: float | None = None,
        end: float | None = None,
    ) -> dict[str, np.ndarray]:
        """Only the channels ``names`` at full rate (``start ≤ t ≤ end``), read chunk batch
        by chunk batch: an hour at 1 kHz of five channels is 144 MB, not all ten's 288 MB."""
        rows = [INDEX_OF[n] if n in INDEX_OF else _unknown(n) for n in names]
        lo, hi = _window(start, end)
        with self._db.session(write=False) as s:
            _require_session(s, session_id)
            bound = s.scalar(
                select(func.coalesce(func.sum(_C.n), 0)).where(*_where(session_id, lo, hi))
            )
        out = np.empty((len(rows), int(bound or 0)))
        k = 0
        for cols in self._chunks(session_id, lo, hi, 64):
            m = min(cols.shape[1], out.shape[1] - k)  # (a chunk added since: not read)
            out[:, k : k + m] = cols[rows, :m]
            k += m
        return {n: out[i, :k] for i, n in enumerate(names)}

    def export_csv(
        self, session_id: int, *, start: float | None = None, end: float | None = None
    ) -> Iterator[str]:
        """CSV text in pieces: the header row with units (``t [s],q [rad],…``), then the
        samples, one piece per stored chunk. A bad window is refused now, not mid-stream."""
        _window(start, end)
        chunks = self.iter_chunks(session_id, start=start, end=end)

        def pieces() -> Iterator[str]:
            yield csv_header() + "\n"
            for cols in chunks:
                yield "".join([CSV_FORMAT % tuple(row) for row in cols.T.tolist()])

        return pieces()

    def _chunks(
        self, session_id: int, lo: float | None, hi: float | None, batch: int
    ) -> Iterator[np.ndarray]:
        after = -1
        where = _where(session_id, lo, hi)
        while True:
            with self._db.session(write=False) as s:
                rows = s.execute(
                    select(_C.seq, _C.n, _C.encoding, _C.payload)
                    .where(*where, _C.seq > after)
                    .order_by(_C.seq)
                    .limit(batch)
                ).all()
            if not rows:
                return
            for seq, n, encoding, payload in rows:
                cols = _trim(codec.decode(payload, n, encoding), lo, hi)
                if cols.shape[1]:
                    yield cols
                after = seq

    @staticmethod
    def _full(
        s: OrmSession, where: list[Any], last: int, lo: float | None, hi: float | None
    ) -> np.ndarray:
        rows = s.execute(
            select(_C.n, _C.encoding, _C.payload).where(*where, _C.seq <= last).order_by(_C.seq)
        ).all()
        out = np.empty((WIDTH, sum(r[0] for r in rows)))
        k = 0
        for n, encoding, payload in rows:
            codec.decode(payload, n, encoding, out[:, k : k + n])
            k += n
        return _trim(out, lo, hi)

    @staticmethod
    def _overview(
        s: OrmSession, where: list[Any], last: int, lo: float | None, hi: float | None
    ) -> tuple[np.ndarray, int]:
        """Min/max pairs of the window from the stored overviews; the chunks cut by the
        window's edges are decoded and paired afresh."""
        rows = s.execute(
            select(_C.seq, _C.t0, _C.t1, _C.n, _C.encoding, _C.overview)
            .where(*where, _C.seq <= last)
            .order_by(_C.seq)
        ).all()
        parts: list[np.ndarray] = []
        samples = 0
        for seq, t0, t1, n, encoding, overview in rows:
            if (lo is not None and t0 < lo) or (hi is not None and t1 > hi):
                payload = s.scalar(select(_C.payload).where(*where, _C.seq == seq))
                cols = _trim(codec.decode(payload, n, encoding), lo, hi)
                parts.append(minmax_pairs(cols, codec.BLOCK))
                samples += cols.shape[1]
            else:
                parts.append(codec.decode_overview(overview, n, encoding))
                samples += n
        return np.concatenate(parts, axis=1), samples
