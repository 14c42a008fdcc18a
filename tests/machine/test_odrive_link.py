"""The serial line's writes on a real pty: a line nobody reads times out within the bound, and
a write that went out is never called timed out because its process was descheduled past the
deadline (a host stall: the loop must see the stall for what it is, not a dead link).

Independent truth: the pty itself. Its other end either drains what is written (every byte
arrives, counted) or reads nothing (the kernel's buffer fills and a write must block).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pty
import random
import select
import signal
import threading
import time

import pytest

from sessions.machine.base import MachineError
from sessions.machine.odrive.link import AsciiLink

LINE = b"c 0 0.125\n" * 8  # 80 bytes: a burst of torque writes


def _pty() -> tuple[int, int, str]:
    """A pty: its master, its slave (held open, so that the master reads rather than failing
    with EIO while no one else has the slave open) and the slave's name (the link opens it by
    name, as it opens a real port)."""
    master, slave = pty.openpty()
    return master, slave, os.ttyname(slave)


def _drain(master: int, counted: list[int], stop: threading.Event) -> None:
    while not stop.is_set():
        if select.select((master,), (), (), 0.05)[0]:
            counted[0] += len(os.read(master, 65536))


def test_a_line_nobody_reads_times_out_within_the_bound_and_says_so():
    master, slave, path = _pty()
    link = AsciiLink(path, 115200, timeout=0.02, use_checksum=True)
    link.open()
    try:
        with pytest.raises(MachineError, match=r"^write timed out after 20 ms$"):
            for _ in range(100_000):  # the kernel's pty buffer is a few kB: it fills
                t0 = time.monotonic()
                link.send(LINE)
        assert time.monotonic() - t0 < 0.5  # the one that timed out waited ~20 ms, not forever
    finally:
        link.close()
        os.close(master)
        os.close(slave)


def _writer(path: str, seconds: float, ready: object, out: object) -> None:
    link = AsciiLink(path, 115200, timeout=0.01, use_checksum=True)
    link.open()
    sent = 0
    ready.set()  # type: ignore[attr-defined]
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            link.send(LINE)
            sent += len(LINE)
    except MachineError as exc:
        out.put(("error", str(exc), sent))  # type: ignore[attr-defined]
    else:
        out.put(("ok", "", sent))  # type: ignore[attr-defined]
    finally:
        link.close()


@pytest.mark.realtime  # timed where it happens: alone, after the parallel rooms (a starved
# drain would fill the pty's buffer within the 10 ms bound: a true timeout)
def test_a_writer_stopped_past_its_deadline_is_not_a_write_timeout():
    # 30 stops of 30 ms (3x the 10 ms bound) land at random points of a writer that does
    # nothing but write, on a line that is drained: each stop that lands inside a write finds
    # its deadline passed on resuming, although the bytes went out
    master, slave, path = _pty()
    counted = [0]
    stop = threading.Event()
    drain = threading.Thread(target=_drain, args=(master, counted, stop), daemon=True)
    drain.start()
    spawn = mp.get_context("spawn")
    ready, out = spawn.Event(), spawn.Queue()
    proc = spawn.Process(target=_writer, args=(path, 4.0, ready, out))
    proc.start()
    rng = random.Random(7)
    try:
        assert ready.wait(30)
        time.sleep(0.2)
        for _ in range(30):
            os.kill(proc.pid, signal.SIGSTOP)
            time.sleep(0.03)
            os.kill(proc.pid, signal.SIGCONT)
            time.sleep(rng.uniform(0.02, 0.08))
        verdict, message, sent = out.get(timeout=30)
        proc.join(10)
        assert verdict == "ok", message
        time.sleep(0.2)
        assert counted[0] == sent > 0  # every byte written arrived
    finally:
        if proc.is_alive():
            proc.kill()
        stop.set()
        drain.join(5)
        os.close(slave)
        os.close(master)
