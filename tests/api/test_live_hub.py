"""The live fan-out: a slow client loses its oldest samples, never holds up the pump or others."""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np

from server.service.live import BACKLOG_SECONDS, LiveHub, serve_subscription
from sessions.codes import FLAG_ESTOP
from sessions.worker.ring import INDEX as RING

RATE = 1000.0


def batch(first: int, n: int, flags: int = 0) -> tuple[np.ndarray, np.ndarray]:
    seq = np.arange(first, first + n, dtype=np.int64)
    data = np.zeros((n, len(RING)))
    data[:, RING["t"]] = seq / RATE
    data[:, RING["flags"]] = flags
    return seq, data


def test_a_client_that_never_reads_keeps_only_the_newest_backlog() -> None:
    hub = LiveHub(RATE)
    slow, fast = hub.subscribe(RATE), hub.subscribe(RATE)
    got: list[int] = []
    total = 10_000  # 10 s at 1 kHz, in 100-sample batches
    for first in range(0, total, 100):
        hub.publish_telemetry(*batch(first, 100), missed=0)
        frame = hub.telemetry_frame(fast)
        got.extend(frame["seq"])
    cap = int(BACKLOG_SECONDS * RATE)
    assert slow.pending_n == cap
    frame = hub.telemetry_frame(slow)
    assert frame["seq"] == list(range(total - cap, total))  # the newest, in order, no holes
    assert frame["dropped"] == total - cap
    assert got == list(range(total))  # the reading client saw every sample
    assert hub.telemetry_frame(fast) is None


def test_decimation_keeps_every_step_th_sample_and_every_zero_torque_one() -> None:
    hub = LiveHub(RATE)
    sub = hub.subscribe(50.0)  # every 20th sample
    hub.publish_telemetry(*batch(0, 100), missed=0)
    hub.publish_telemetry(*batch(100, 7, flags=FLAG_ESTOP), missed=3)
    frame = hub.telemetry_frame(sub)
    assert frame["seq"] == [0, 20, 40, 60, 80, *range(100, 107)]
    assert frame["missed"] == 3 and frame["dropped"] == 0
    assert frame["t"][:2] == [0.0, 0.02]


def test_a_stalled_socket_does_not_hold_up_another() -> None:
    async def scenario() -> tuple[int, list[dict[str, Any]]]:
        hub = LiveHub(RATE)
        stalled = asyncio.Event()  # never set: a browser that stopped reading

        async def send_stalled(frame: dict[str, Any]) -> None:
            await stalled.wait()

        frames: list[dict[str, Any]] = []

        async def send_fast(frame: dict[str, Any]) -> None:
            frames.append(frame)

        tasks = [
            asyncio.create_task(serve_subscription(hub, hub.subscribe(RATE), send_stalled)),
            asyncio.create_task(serve_subscription(hub, hub.subscribe(RATE), send_fast)),
        ]
        published = 0
        for _ in range(40):  # 4 s of data in 10 ms batches, as the pump publishes it
            hub.publish_telemetry(*batch(published, 10), missed=0)
            published += 10
            await asyncio.sleep(0.002)
        hub.publish_event({"type": "event", "kind": "session_ended"})
        await asyncio.sleep(0.2)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        return published, frames

    published, frames = asyncio.run(scenario())
    seqs = [s for f in frames if f["type"] == "telemetry" for s in f["seq"]]
    assert seqs == list(range(published))
    assert {"type": "event", "kind": "session_ended"} in frames
