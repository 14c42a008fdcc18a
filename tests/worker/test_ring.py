"""The shared-memory telemetry ring: readers in other processes see every record in order, or
learn exactly how many they missed; a record is never torn; readers never remove the ring.

Independent truth: the writer (a separate process) writes record n as the row f(n) = n + i/100
in column i, so every value a reader gets can be checked against its sequence number, and
the count of records read plus the count reported missed must equal what was written.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import time

import numpy as np
import pytest

from sessions.worker.ring import (
    COLUMNS,
    H_HEAD,
    WIDTH,
    RingInfo,
    RingReader,
    RingWriter,
    TelemetryRing,
)

COLS = np.arange(WIDTH) / 100.0


def row(n: int) -> tuple[float, ...]:
    return tuple(float(n) + c for c in COLS)


def _writer(name: str, total: int, pace: float, go: object) -> None:
    w = RingWriter(name)
    go.wait()  # type: ignore[attr-defined]
    for n in range(total):
        w.write(row(n))
        if pace and n % 64 == 0:
            time.sleep(pace)
    w.close()


def _check_batch(seq: np.ndarray, data: np.ndarray) -> None:
    assert np.all(np.diff(seq) == 1), "a batch is contiguous and in order"
    expected = seq[:, None].astype(float) + COLS[None, :]
    np.testing.assert_array_equal(data, expected)  # no torn or stale record


@pytest.fixture
def spawn():
    return mp.get_context("spawn")


def test_layout_and_info_are_plain_data():
    ring = TelemetryRing.create(capacity=64)
    try:
        info = pickle.loads(pickle.dumps(ring.info))
        assert info == RingInfo(ring.name, 64, COLUMNS)
        assert len(COLUMNS) == WIDTH and COLUMNS[:3] == ("t", "q", "w")
        with RingReader(info, "oldest") as r:
            assert len(r.read()) == 0 and r.read().missed == 0
    finally:
        ring.close()


def test_reader_that_keeps_up_sees_every_record_in_order(spawn):
    # three times round a ring of 32768 (slots are reused under the reader), at ~60 k
    # records/s: the reader may stall for half a second on a loaded machine and keep up
    total = 100_000
    ring = TelemetryRing.create(capacity=1 << 15)
    go = spawn.Event()
    proc = spawn.Process(target=_writer, args=(ring.name, total, 0.001, go))
    proc.start()
    try:
        reader = RingReader(ring.info, start=0)
        go.set()
        got, missed = 0, 0
        deadline = time.monotonic() + 60
        while got + missed < total and time.monotonic() < deadline:
            b = reader.read()
            if len(b):
                assert int(b.seq[0]) == got + missed
                _check_batch(b.seq, b.data)
            got += len(b)
            missed += b.missed
        proc.join(10)
        assert missed == 0
        assert got == total
        reader.close()
    finally:
        ring.close()


def test_slow_reader_learns_exactly_how_many_it_missed(spawn):
    total, cap = 200_000, 1024
    ring = TelemetryRing.create(capacity=cap)
    go = spawn.Event()
    proc = spawn.Process(target=_writer, args=(ring.name, total, 0.0, go))
    proc.start()
    try:
        reader = RingReader(ring.info, start=0)
        go.set()
        got = missed = 0
        expected_next = 0
        batches_with_gaps = 0
        deadline = time.monotonic() + 60
        # the overrun is made, not hoped for: on a loaded machine the writer may get less CPU
        # than this reader (CI once saw it keep up), so the first read waits until the writer
        # is two rings ahead
        while reader.head < 2 * cap and time.monotonic() < deadline:
            time.sleep(0.001)
        while got + missed < total and time.monotonic() < deadline:
            b = reader.read(max_records=200)  # a reader that cannot keep up
            if len(b):
                assert int(b.seq[0]) == expected_next + b.missed
                _check_batch(b.seq, b.data)
                expected_next = int(b.seq[-1]) + 1
            else:
                expected_next += b.missed
            batches_with_gaps += b.missed > 0
            got += len(b)
            missed += b.missed
            time.sleep(0.001)
        proc.join(10)
        assert got + missed == total, "every record is either read or counted missed"
        assert missed > 0 and batches_with_gaps > 0, "the test must actually overrun the reader"
        assert reader.missed_total == missed
        reader.close()
    finally:
        ring.close()


def test_reader_falling_a_full_ring_behind(spawn):
    cap = 64
    ring = TelemetryRing.create(capacity=cap)
    try:
        w = RingWriter(ring.name)
        reader = RingReader(ring.info, start="now")
        for n in range(1000):
            w.write(row(n))
        b = reader.read()
        # the writer may be reusing the oldest slot, so the reader gets capacity - 1
        assert b.missed == 1000 - (cap - 1)
        assert int(b.seq[0]) == 1000 - (cap - 1) and int(b.seq[-1]) == 999
        _check_batch(b.seq, b.data)
        assert len(reader.read()) == 0 and reader.read().missed == 0
        w.write(row(1000))
        b = reader.read()
        assert list(b.seq) == [1000] and b.missed == 0
        w.close()
        reader.close()
    finally:
        ring.close()


def _attach_and_exit(name: str) -> None:
    r = RingReader(name)
    r.read()
    r.close()


def test_a_reader_process_exiting_does_not_remove_the_ring(spawn):
    ring = TelemetryRing.create(capacity=64)
    try:
        for _ in range(2):
            p = spawn.Process(target=_attach_and_exit, args=(ring.name,))
            p.start()
            p.join(30)
            assert p.exitcode == 0
        assert os.path.exists(f"/dev/shm/{ring.name}")
        w = RingWriter(ring.name)
        w.write(row(0))
        assert ring.header(H_HEAD) == 1
        w.close()
    finally:
        ring.close()
    assert not os.path.exists(f"/dev/shm/{ring.name}")


def test_readers_cannot_write():
    ring = TelemetryRing.create(capacity=64)
    try:
        r = RingReader(ring.info)
        with pytest.raises(ValueError):
            r.view.data[0, 0] = 1.0
        r.close()
    finally:
        ring.close()
