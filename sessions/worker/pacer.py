"""Keeping time in the worker: the pace of the cycles, the OS settings a real-time loop asks
for, and the statistics of how well it kept its deadlines (like ros2_control's sleeping
policies, in a file of their own).

Schedule (:class:`Pacer`): absolute deadlines ``t0 + k·period`` (no drift). Each cycle sleeps
until ``spin`` before its deadline, then spins on the clock for the last stretch, so the
wake-up does not inherit the sleep's overshoot. A cycle that wakes a whole period (or more)
late skips the deadlines it missed (they are counted, not replayed).

Statistics: lateness (wake-up − deadline) and compute time (wake-up → record published) in
1 µs bins up to 20 ms (the maximum is kept exactly); percentiles are read off the cumulative
histogram. Recording a cycle is two list increments.
"""

from __future__ import annotations

import ctypes
import os
import time
from array import array
from collections.abc import Callable

import numpy as np

from sessions.worker.messages import RealtimeInfo, TimingStats

PR_SET_TIMERSLACK = 29
BINS = 20_000  # 1 µs bins: 0 … 20 ms, the last one open-ended


def setup_realtime(
    cpu: int | None, fifo: bool, priority: int, timer_slack_ns: int | None
) -> RealtimeInfo:
    """Ask for what was configured; note what was refused. Never raises."""
    notes: list[str] = []
    pinned = None
    got_fifo = False
    slack = None
    if timer_slack_ns is not None:
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(PR_SET_TIMERSLACK, int(timer_slack_ns), 0, 0, 0) == 0:
                slack = int(timer_slack_ns)
            else:
                notes.append(f"timer slack refused (errno {ctypes.get_errno()})")
        except (OSError, AttributeError) as exc:
            notes.append(f"timer slack unavailable ({exc})")
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
            pinned = cpu
        except (OSError, AttributeError, ValueError) as exc:
            notes.append(f"CPU {cpu} pinning refused ({exc})")
    if fifo:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            got_fifo = True
        except (OSError, AttributeError) as exc:
            notes.append(f"SCHED_FIFO refused ({exc}); running SCHED_OTHER")
    return RealtimeInfo(
        cpu=pinned,
        sched_fifo=got_fifo,
        priority=priority if got_fifo else 0,
        timer_slack_ns=slack,
        notes=tuple(notes),
    )


def _percentile(counts: np.ndarray, total: int, q: float, top: float) -> float:
    """The upper edge of the 1 µs bin holding the q-quantile (never above the maximum)."""
    if total == 0:
        return 0.0
    c = np.cumsum(counts)
    return min(float(np.searchsorted(c, q * total, side="left") + 1), round(top, 1))


class TimingRecorder:
    __slots__ = ("rate", "period", "late", "compute", "cycles", "missed", "late_max",
                 "compute_max", "overruns")  # fmt: skip

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self.period = 1.0 / rate
        self.late = array("q", bytes(8 * BINS))
        self.compute = array("q", bytes(8 * BINS))
        self.cycles = 0
        self.missed = 0
        self.late_max = 0.0
        self.compute_max = 0.0
        self.overruns = 0

    def record(self, late_s: float, compute_s: float) -> None:
        self.cycles += 1
        us = late_s * 1e6
        i = int(us) if us > 0.0 else 0
        self.late[i if i < BINS else BINS - 1] += 1
        if us > self.late_max:
            self.late_max = us
        us = compute_s * 1e6
        i = int(us) if us > 0.0 else 0
        self.compute[i if i < BINS else BINS - 1] += 1
        if us > self.compute_max:
            self.compute_max = us
        if compute_s > self.period:
            self.overruns += 1

    def stats(self) -> TimingStats:
        late = np.frombuffer(self.late, dtype=np.int64)
        comp = np.frombuffer(self.compute, dtype=np.int64)
        n = self.cycles
        return TimingStats(
            rate_hz=self.rate,
            cycles=n,
            missed=self.missed,
            missed_ratio=self.missed / (n + self.missed) if n + self.missed else 0.0,
            p50_us=_percentile(late, n, 0.5, self.late_max),
            p99_us=_percentile(late, n, 0.99, self.late_max),
            p999_us=_percentile(late, n, 0.999, self.late_max),
            max_us=round(self.late_max, 1),
            compute_p50_us=_percentile(comp, n, 0.5, self.compute_max),
            compute_p99_us=_percentile(comp, n, 0.99, self.compute_max),
            compute_max_us=round(self.compute_max, 1),
            overruns=self.overruns,
        )


class Pacer:
    """The cycle's clock: :meth:`wait` returns at the next deadline; :attr:`timing` keeps the
    statistics (lateness, compute, missed periods)."""

    __slots__ = ("deadline", "period", "spin", "timing")

    def __init__(self, rate: float, spin_s: float) -> None:
        self.period = 1.0 / rate
        self.spin = spin_s
        self.deadline = 0.0
        self.timing = TimingRecorder(rate)

    def start(self) -> None:
        """The first deadline: one period from now."""
        self.deadline = time.monotonic() + self.period

    def wait(
        self,
        mono: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> tuple[float, float]:
        """Sleep, then spin, until the deadline; returns (wake-up time, lateness), both s.
        (The clock functions are bound once, as defaults: this runs every period.)"""
        deadline = self.deadline
        now = mono()
        rem = deadline - now
        if rem > self.spin:
            sleep(rem - self.spin)
            now = mono()
        while now < deadline:
            now = mono()
        late = now - deadline
        period = self.period
        if late >= period:
            skipped = int(late / period)
            self.timing.missed += skipped
            deadline += skipped * period
        self.deadline = deadline + period
        return now, late
