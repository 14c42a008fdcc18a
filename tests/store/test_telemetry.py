"""Telemetry in the store: the recorder's chunks and commits, loads at full rate, decimated
(min/max kept) and windowed, CSV export, the chunk encoding, and refused rows."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from sessions.config import parse_session_config
from sessions.seekers import Evaluation
from sessions.store import ConflictError, Store, StoreError, StoreValueError, codec
from sessions.store.decimate import decimate, decimate_pairs, minmax_pairs
from sessions.store.timeseries import CHUNK_SECONDS
from sessions.telemetry import INDEX, NAMES, WIDTH, csv_header
from testing.store import telemetry

CFG = parse_session_config({"duration": 600.0})


def _running(store: Store) -> int:
    user = store.users.create("Tess")
    return store.sessions.start(user.id, CFG).id


def _record(store: Store, rows: np.ndarray, *, block: int = 10, flush_every: int = 0) -> int:
    """A session holding ``rows``, fed ``block`` rows at a time, flushed every
    ``flush_every`` rows (0: only at the end), then completed."""
    sid = _running(store)
    rec = store.recorder(sid, background=False)
    for i in range(0, len(rows), block):
        rec.add_rows(rows[i : i + block])
        if flush_every and (i + block) % flush_every == 0:
            rec.flush()
    rec.finish("completed")
    return sid


def _check_buckets(full: np.ndarray, out: np.ndarray) -> None:
    """Each output pair is the min and max of the full-rate samples its times span."""
    t = full[0]
    assert out.shape[1] % 2 == 0
    for b in range(0, out.shape[1], 2):
        i = np.searchsorted(t, out[0, b], side="left")
        j = np.searchsorted(t, out[0, b + 1], side="right")
        seg = full[:, i:j]
        pair = out[:, b : b + 2]
        np.testing.assert_array_equal(pair.min(axis=1), seg.min(axis=1))
        np.testing.assert_array_equal(pair.max(axis=1), seg.max(axis=1))


# -- recorder ------------------------------------------------------------------------------


def test_chunks_hold_at_most_one_second_and_read_back_exactly(store: Store) -> None:
    rows = telemetry(3.7)
    sid = _record(store, rows, flush_every=300)  # flushed every 0.3 s of data
    span = store.telemetry.span(sid)
    assert (span.samples, span.chunks, span.t0, span.t1) == (3700, 4, 0.0, 3.699)
    assert 0 < span.stored_bytes < rows.nbytes / 2
    loaded = store.telemetry.load(sid)
    assert not loaded.decimated and loaded.samples == 3700 and len(loaded) == 3700
    np.testing.assert_array_equal(loaded.columns, codec.quantize(rows.T))
    np.testing.assert_array_equal(loaded.column("t"), rows[:, 0])  # t and q are exact
    np.testing.assert_array_equal(loaded.column("q"), rows[:, INDEX["q"]])
    np.testing.assert_allclose(loaded.rows, rows, rtol=1e-6, atol=1e-6)
    chunks = list(store.telemetry.iter_chunks(sid))
    assert [c.shape[1] for c in chunks] == [1000, 1000, 1000, 700]
    assert all(c[0, -1] - c[0, 0] < CHUNK_SECONDS for c in chunks)


def test_open_chunk_is_rewritten_until_full(store: Store) -> None:
    sid = _running(store)
    rec = store.recorder(sid, background=False)
    rows = telemetry(2.2)
    seen = []
    for a, b in ((0, 300), (300, 600), (600, 1000), (1000, 1400), (1400, 2200)):
        rec.add_rows(rows[a:b])
        rec.flush()
        span = store.telemetry.span(sid)
        seen.append((span.chunks, span.samples))
        assert rec.stored_until == rows[b - 1, 0]
    assert seen == [(1, 300), (1, 600), (1, 1000), (2, 1400), (3, 2200)]
    rec.close()
    assert store.sessions.get(sid).status == "running"
    np.testing.assert_array_equal(store.telemetry.load(sid).columns, codec.quantize(rows.T))


def test_live_summary_follows_the_stored_data(store: Store) -> None:
    sid = _running(store)
    rec = store.recorder(sid, background=False)
    rows = telemetry(2.5)
    rows[100, INDEX["W"]] = -3.0  # a dip in W(t)
    rows[200, INDEX["tau"]] = math.nan  # a sensor glitch does not poison the figures
    rec.add_rows(rows)
    rec.add_evaluations([Evaluation(1.0, 2.0, 5.0, 0.1), Evaluation(2.0, 3.0, 6.0)])
    rec.flush()
    s = store.sessions.get(sid)
    pm = rows[:, INDEX["tau"]] * rows[:, INDEX["w"]]
    pm = pm[np.isfinite(pm)]
    assert s.duration == pytest.approx(2.5)
    assert s.mean_power == pytest.approx(pm.mean())
    assert s.peak_power == pytest.approx(pm.max())
    assert s.work == pytest.approx(rows[-1, INDEX["W"]])
    assert s.passivity_min == -3.0
    assert s.evaluation_count == 2
    assert s.summary().duration == pytest.approx(2.5)  # a valid SessionSummary
    done = rec.finish("stopped")
    assert (done.status, done.duration, done.evaluation_count) == ("stopped", s.duration, 2)


def test_background_thread_commits_while_feeding(store: Store) -> None:
    sid = _running(store)
    rec = store.recorder(sid, flush_interval=0.1)
    rows = telemetry(1.0)
    start = time.monotonic()
    lag = []
    for i in range(0, 1000, 20):  # 1 kHz in 20 ms blocks, in real time
        while time.monotonic() - start < rows[i, 0]:
            time.sleep(0.002)
        rec.add_rows(rows[i : i + 20])
        if i % 200 == 0 and i:
            lag.append(rows[i, 0] - (rec.stored_until or 0.0))
    assert rec.flushes >= 4
    assert max(lag) < 0.5
    rec.add_event(0.99, "estop", {"button": "red"})  # wakes the writer at once
    deadline = time.monotonic() + 5
    while not store.sessions.events(sid) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert store.sessions.events(sid)[0].detail == {"button": "red"}
    rec.finish("completed")
    assert rec.error is None
    with pytest.raises(StoreError, match="closed"):
        rec.add_rows(telemetry(0.1, t0=2.0))
    assert store.telemetry.span(sid).samples == 1000


def test_reads_while_the_recorder_writes(store: Store) -> None:
    sid = _running(store)
    rec = store.recorder(sid, flush_interval=0.05)
    rows = telemetry(6.0)
    errors: list[BaseException] = []

    def read() -> None:
        try:
            while not stop.is_set():
                store.telemetry.load(sid, points=200)
                store.sessions.list()
        except BaseException as exc:
            errors.append(exc)

    stop = threading.Event()
    readers = [threading.Thread(target=read) for _ in range(2)]
    for r in readers:
        r.start()
    for i in range(0, len(rows), 100):
        rec.add_rows(rows[i : i + 100])
        time.sleep(0.01)
    rec.finish("completed")
    stop.set()
    for r in readers:
        r.join()
    assert errors == [] and rec.error is None
    np.testing.assert_array_equal(store.telemetry.load(sid).columns, codec.quantize(rows.T))


def test_recorder_resumes_after_stored_data(store: Store) -> None:
    sid = _running(store)
    first = store.recorder(sid, background=False)
    first.add_rows(telemetry(1.5))
    first.close()
    second = store.recorder(sid, background=False)
    with pytest.raises(StoreValueError, match="not after the last sample"):
        second.add_rows(telemetry(0.5, t0=1.0))
    second.add_rows(telemetry(1.0, t0=1.5))
    done = second.finish("completed")
    assert store.telemetry.span(sid).samples == 2500
    assert done.duration == pytest.approx(2.5)
    np.testing.assert_array_equal(store.telemetry.load(sid).column("t"), telemetry(2.5)[:, 0])


def test_recorder_stops_when_the_session_ended_elsewhere(store: Store) -> None:
    sid = _running(store)
    rec = store.recorder(sid, background=False)
    rec.add_rows(telemetry(0.5))
    rec.flush()
    store.sessions.finish(sid, "aborted", abort_reason="operator")
    rec.add_rows(telemetry(0.5, t0=0.5))
    with pytest.raises(ConflictError, match="no longer running"):
        rec.flush()
    with pytest.raises(ConflictError):
        rec.add_rows(telemetry(0.1, t0=1.0))
    assert store.telemetry.span(sid).samples == 500
    with pytest.raises(ConflictError, match="aborted"):
        store.recorder(sid)


def test_bad_rows_are_refused_and_nothing_is_stored(store: Store) -> None:
    sid = _running(store)
    rec = store.recorder(sid, background=False)
    rows = telemetry(0.2)
    for bad, field in (
        (rows[:, :9], "telemetry"),
        ([[1, 2, 3]], "telemetry"),
        ([["a"] * WIDTH], "telemetry"),
        (rows[::-1], "telemetry.t"),
        (np.vstack([rows[:1], rows[:1]]), "telemetry.t"),
        (rows - 1.0, "telemetry.t"),
        (np.where(np.arange(WIDTH) == 0, math.nan, rows), "telemetry.t"),
    ):
        with pytest.raises(StoreValueError) as info:
            rec.add_rows(bad)
        assert info.value.field == field
    with pytest.raises(StoreValueError, match="channels"):
        rec.add_row((0.0, 1.0))
    rec.add_rows(rows[:100])
    with pytest.raises(StoreValueError, match="not after the last sample"):
        rec.add_row(tuple(rows[50]))
    rec.add_row(tuple(rows[100]))
    rec.close()
    assert store.telemetry.span(sid).samples == 101
    with pytest.raises(StoreValueError, match="points"):
        store.telemetry.load(sid, points=1)
    with pytest.raises(StoreValueError, match="end"):
        store.telemetry.load(sid, start=2.0, end=1.0)
    with pytest.raises(StoreValueError, match="flush_interval"):
        store.recorder(sid, flush_interval=2.0)


def test_non_finite_channels_are_kept(store: Store) -> None:
    rows = telemetry(0.5)
    rows[10, INDEX["tau"]] = math.nan
    rows[11, INDEX["u"]] = math.inf
    rows[12, INDEX["p"]] = -math.inf
    sid = _record(store, rows)
    cols = store.telemetry.load(sid).columns
    assert math.isnan(cols[INDEX["tau"], 10]) and cols[INDEX["u"], 11] == math.inf
    assert cols[INDEX["p"], 12] == -math.inf


# -- loading: full, window, decimated -------------------------------------------------------


def test_window_is_inclusive(store: Store) -> None:
    rows = telemetry(5.0)
    sid = _record(store, rows)
    w = store.telemetry.load(sid, start=1.2345, end=3.0)
    assert w.column("t")[0] == 1.235 and w.column("t")[-1] == 3.0 and w.samples == 1766
    np.testing.assert_array_equal(w.columns, codec.quantize(rows[1235:3001].T))
    assert len(store.telemetry.load(sid, start=4.5)) == 500
    assert len(store.telemetry.load(sid, end=0.0)) == 1
    assert len(store.telemetry.load(sid, start=7.0)) == 0
    empty = store.telemetry.load(_running(store))
    assert (empty.columns.shape, empty.samples) == ((WIDTH, 0), 0)


def test_decimated_load_preserves_minimum_and_maximum(store: Store) -> None:
    rows = telemetry(120.0)
    rows[54_321, INDEX["u"]] = 99.0  # a one-sample spike must survive
    rows[77_777, INDEX["tau"]] = -42.0
    sid = _record(store, rows, block=1000)
    full = codec.quantize(rows.T)
    for points, window in ((2000, {}), (300, {}), (1000, {"start": 10.0005, "end": 95.5})):
        d = store.telemetry.load(sid, points=points, **window)
        lo, hi = window.get("start", 0.0), window.get("end", 1e9)
        ref = full[:, (full[0] >= lo) & (full[0] <= hi)]
        assert d.decimated and len(d) <= points and d.samples == ref.shape[1]
        np.testing.assert_array_equal(d.columns.min(axis=1), ref.min(axis=1))
        np.testing.assert_array_equal(d.columns.max(axis=1), ref.max(axis=1))
        assert d.column("t")[0] == ref[0, 0] and d.column("t")[-1] == ref[0, -1]
        assert (np.diff(d.column("t")) >= 0).all()
        _check_buckets(ref, d.columns)
    assert store.telemetry.load(sid, points=2000).column("u").max() == np.float32(99.0)
    # short windows decimate from full-rate data, the same way
    small = store.telemetry.load(sid, points=100, start=50.0, end=50.999)
    assert small.decimated and len(small) <= 100
    _check_buckets(full, small.columns)
    # enough points: the samples themselves
    same = store.telemetry.load(sid, points=5000, start=50.0, end=50.999)
    assert not same.decimated and len(same) == 1000


def test_decimation_functions() -> None:
    rng = np.random.default_rng(3)
    x = rng.standard_normal((3, 1000))
    x[0] = np.arange(1000)  # a time channel
    x[1, 512:544] = math.nan  # a whole NaN block (the 17th), and NaN in others
    x[2, 10] = math.nan
    pairs = minmax_pairs(x, 32)
    assert pairs.shape == (3, 2 * 32)
    assert (pairs[0, 0::2] == np.arange(0, 1000, 32)).all()  # first time of each block
    assert (pairs[0, 1::2] == np.minimum(np.arange(31, 1031, 32), 999)).all()
    assert np.nanmax(pairs[1]) == np.nanmax(x[1]) and np.nanmin(pairs[2]) == np.nanmin(x[2])
    assert np.isnan(pairs[1, 2 * 16 : 2 * 16 + 2]).all() and not np.isnan(pairs[2, :2]).any()
    # composition: pairs of pairs equal pairs of the larger blocks
    y = rng.standard_normal((4, 32 * 48))
    np.testing.assert_array_equal(minmax_pairs(minmax_pairs(y, 32), 2 * 6), minmax_pairs(y, 192))
    np.testing.assert_array_equal(decimate_pairs(minmax_pairs(y, 32), 16), minmax_pairs(y, 192))
    assert decimate(y, 5000) is y and decimate(y, 101).shape[1] <= 101
    # the order of the extremes within a block follows the data
    z = np.array([[0.0, 1, 2, 3], [5, -1, 7, 0]])
    np.testing.assert_array_equal(minmax_pairs(z, 4), [[0, 3], [-1, 7]])
    np.testing.assert_array_equal(minmax_pairs(z[:, ::-1].copy(), 4), [[3, 0], [7, -1]])


# -- CSV -----------------------------------------------------------------------------------


def test_csv_export_header_rows_and_values(store: Store) -> None:
    rows = telemetry(2.5)
    sid = _record(store, rows)
    pieces = store.telemetry.export_csv(sid)
    first = next(pieces)
    assert first == csv_header() + "\n"
    assert first.startswith("t [s],q [rad],w [rad/s],") and "W [J]" in first
    rest = list(pieces)
    assert len(rest) == 3  # one piece per chunk: never the whole session at once
    lines = "".join(rest).splitlines()
    assert len(lines) == 2500
    back = np.array([[float(x) for x in line.split(",")] for line in lines])
    np.testing.assert_allclose(back, codec.quantize(rows.T).T, rtol=1e-8, atol=1e-12)
    assert lines[1].split(",")[0] == "0.001"
    window = "".join(store.telemetry.export_csv(sid, start=1.0, end=1.5)).splitlines()
    assert window[0] == csv_header() and len(window) == 1 + 501
    assert len(csv_header().split(",")) == len(NAMES)


# -- encoding ------------------------------------------------------------------------------


def test_codec_round_trip_and_size() -> None:
    cols = telemetry(1.0).T.copy()
    cols[5, 3] = math.nan
    payload, overview = codec.encode(cols)
    back = codec.decode(payload, 1000, codec.ENCODING)
    np.testing.assert_array_equal(back, codec.quantize(cols))
    np.testing.assert_array_equal(back[:2], cols[:2])  # float64 channels: exact
    assert np.abs(back[2:] - cols[2:])[np.isfinite(cols[2:])].max() < 1e-6 * 100
    ov = codec.decode_overview(overview, 1000, codec.ENCODING)
    np.testing.assert_array_equal(ov, minmax_pairs(codec.quantize(cols), codec.BLOCK))
    assert len(payload) < cols.nbytes * 0.6
    with pytest.raises(ValueError, match="encoding"):
        codec.decode(payload, 1000, 99)
    with pytest.raises(ValueError, match="samples"):
        codec.decode(payload, 999, codec.ENCODING)
