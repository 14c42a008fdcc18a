"""Live telemetry and events fanned out to subscribers (WebSocket clients, the dashboard).

The pump publishes every batch of records it reads from the worker's ring, and every event.
Each client has its own subscription: a sample rate (default 30 Hz, up to the loop rate:
samples whose sequence number is a multiple of loop_rate/rate), a bounded backlog of pending
samples and events, and its own sender. The pump never waits for a client: a client that
reads slower than data arrives loses its *oldest* pending samples, and every frame it gets
says how many it has lost so far (``dropped``), so it always sees the newest data.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sessions.codes import ZERO_TORQUE_FLAGS
from sessions.telemetry import RECORD_INDEX as RING

# Channels a telemetry frame carries (a record's, sessions.telemetry).
FRAME_CHANNELS: tuple[str, ...] = (
    "t", "q", "w", "wd", "ad", "u", "u_out", "tau", "p", "W", "gamma", "phase", "flags", "mono",
    "stage",
)  # fmt: skip
FRAME_RATE_MAX = 30.0  # frames per second at most; faster sample rates come batched
BACKLOG_SECONDS = 2.0  # pending samples a slow client may accumulate before losing the oldest
MAX_PENDING_EVENTS = 500


def _finite_list(col: np.ndarray) -> list[float | None]:
    return [x if math.isfinite(x) else None for x in col.tolist()]


@dataclass(eq=False)
class Subscription:
    rate: float
    step: int
    max_pending: int
    pending: deque[np.ndarray] = field(default_factory=deque)  # blocks of ring rows
    seqs: deque[np.ndarray] = field(default_factory=deque)
    pending_n: int = 0
    through: int = -1  # the newest sequence number queued for this client
    dropped: int = 0  # samples this client lost by being slow
    missed: int = 0  # samples the server lost from the ring (the same for every client)
    events: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=MAX_PENDING_EVENTS))
    wake: asyncio.Event = field(default_factory=asyncio.Event)

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.pending:
            return np.zeros(0, np.int64), np.zeros((0, len(RING)))
        seqs, rows = np.concatenate(self.seqs), np.concatenate(self.pending)
        self.pending.clear()
        self.seqs.clear()
        self.pending_n = 0
        return seqs, rows


class LiveHub:
    def __init__(self, loop_rate: float) -> None:
        self.loop_rate = loop_rate
        self.subscribers: set[Subscription] = set()
        self.session_id: int | None = None
        self._last: tuple[int, np.ndarray] | None = None  # the newest record published

    def subscribe(self, rate: float) -> Subscription:
        rate = min(max(rate, 0.1), self.loop_rate)
        step = max(1, round(self.loop_rate / rate))
        max_pending = max(1, math.ceil(BACKLOG_SECONDS * self.loop_rate / step))
        sub = Subscription(rate=self.loop_rate / step, step=step, max_pending=max_pending)
        self.subscribers.add(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        self.subscribers.discard(sub)

    def publish_telemetry(self, seq: np.ndarray, data: np.ndarray, missed: int) -> None:
        """One batch of ring records (all columns), in order; never blocks."""
        if len(seq):
            self._last = (int(seq[-1]), data[-1].copy())
        for sub in self.subscribers:
            sub.missed += missed
            # every step-th sample, and always the ones that end in zero torque (e-stop, fault)
            keep = (seq % sub.step == 0) | (
                (data[:, RING["flags"]].astype(np.int64) & ZERO_TORQUE_FLAGS) != 0
            )
            if not keep.any():
                continue
            rows, s = data[keep], seq[keep]
            sub.through = int(s[-1])
            sub.pending.append(rows)
            sub.seqs.append(s)
            sub.pending_n += len(rows)
            while sub.pending_n > sub.max_pending:  # too slow: lose the oldest
                extra = sub.pending_n - sub.max_pending
                head = sub.pending[0]
                if len(head) <= extra:
                    sub.pending.popleft()
                    sub.seqs.popleft()
                    sub.pending_n -= len(head)
                    sub.dropped += len(head)
                else:
                    sub.pending[0] = head[extra:]
                    sub.seqs[0] = sub.seqs[0][extra:]
                    sub.pending_n -= extra
                    sub.dropped += extra
            sub.wake.set()

    def publish_last(self, seq: int) -> None:
        """A session's last record (the one that wrote zero torque) to every subscriber,
        whatever its rate: everyone sees how it ended. (It must be the newest published.)"""
        if self._last is None or self._last[0] != seq:
            return
        row, at = self._last[1][None, :], np.array([seq], np.int64)
        for sub in self.subscribers:
            if sub.through < seq:
                sub.through = seq
                sub.pending.append(row)
                sub.seqs.append(at)
                sub.pending_n += 1
                sub.wake.set()

    async def flush(self, timeout: float) -> None:
        """Wait (at most ``timeout`` s) until every subscriber has sent what is pending."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while loop.time() < deadline and any(s.pending_n or s.events for s in self.subscribers):
            await asyncio.sleep(0.01)

    def publish_event(self, frame: dict[str, Any]) -> None:
        for sub in self.subscribers:
            if len(sub.events) == sub.events.maxlen:
                sub.dropped += 1
            sub.events.append(frame)
            sub.wake.set()

    def telemetry_frame(self, sub: Subscription) -> dict[str, Any] | None:
        seqs, rows = sub.take()
        if not len(rows):
            return None
        frame: dict[str, Any] = {
            "type": "telemetry",
            "session_id": self.session_id,
            "rate": sub.rate,
            "seq": seqs.tolist(),
            "dropped": sub.dropped,
            "missed": sub.missed,
        }
        for name in FRAME_CHANNELS:
            frame[name] = _finite_list(rows[:, RING[name]])
        return frame


Send = Callable[[dict[str, Any]], Awaitable[None]]


async def serve_subscription(hub: LiveHub, sub: Subscription, send: Send) -> None:
    """Send a subscription's frames until cancelled: events as they come, telemetry at most
    FRAME_RATE_MAX times a second. ``send`` is the WebSocket's ``send_json``-like coroutine."""
    # up to FRAME_RATE_MAX samples a second, each goes out as it comes (the decimation sets
    # the pace); above it, samples are batched into FRAME_RATE_MAX frames a second
    interval = 1.0 / FRAME_RATE_MAX if sub.rate > FRAME_RATE_MAX else 0.0
    loop = asyncio.get_running_loop()
    next_frame = loop.time()
    try:
        while True:
            await sub.wake.wait()
            sub.wake.clear()
            while sub.events:
                await send(sub.events.popleft())
            now = loop.time()
            if now < next_frame:
                await asyncio.sleep(next_frame - now)
            next_frame = max(next_frame + interval, loop.time())
            while sub.events:
                await send(sub.events.popleft())
            frame = hub.telemetry_frame(sub)
            if frame is not None:
                await send(frame)
    finally:
        with contextlib.suppress(Exception):
            hub.unsubscribe(sub)
