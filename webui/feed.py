"""From the LiveHub to the dashboards, ~25 times a second, without ever stalling anyone.

    LiveHub ──(subscription, 50 samples/s)──► Feed.run (asyncio task on the web process's loop)
        takes the pending samples and events (O(1), no copies of the ring), and every 0.25 s
        the machine status (which must be read on that loop), then hands them to
    Feed.apply (one dedicated thread): the bounded live window, the seeker's progress, then
    the shared picture once (3D machine, live charts: :class:`webui.views.SharedView`) and
    each connected browser's own dashboard (:class:`webui.views.ClientView`: status, log,
    buttons, seeker), text about six times a second and only what changed. (viser handle
    updates are thread-safe.)

The task awaits the thread, so a slow render never piles up work: the subscription keeps at
most its backlog (2 s) and drops the oldest samples, and the web process's loop only ever
spends microseconds per tick here. With no browser connected nothing is rendered.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from server.service import ActiveSession, LiveHub, MachineService, MachineStatus, Subscription
from webui.charts import SAMPLE_RATE, LiveWindow
from webui.escape import Markdown, md
from webui.progress import SeekerProgressView

if TYPE_CHECKING:
    from webui.views import ClientView, SharedView

log = logging.getLogger("ergoseek.dashboard")

TICK = 0.04  # s: 25 chart frames per second
TEXT_EVERY = 4  # ticks between text updates (about 6 a second)
STATUS_EVERY = 0.25  # s between machine status reads
LOG_LINES = 8


@dataclass
class Snapshot:
    rows: np.ndarray  # records (sessions.telemetry.RECORD_NAMES), as the hub holds them
    events: list[dict[str, Any]]  # event frames, JSON-ready
    status: MachineStatus | None  # when read this tick
    active: ActiveSession | None


@dataclass
class LiveState:
    """What every view renders, kept by the feed thread only."""

    window: LiveWindow = field(default_factory=LiveWindow)
    window_version: int = 0
    seeker: SeekerProgressView = field(default_factory=SeekerProgressView)
    status: MachineStatus | None = None
    status_version: int = 0
    active: ActiveSession | None = None
    last_finished: tuple[int, str] | None = None  # (session id, status)
    log: deque[Markdown] = field(default_factory=lambda: deque(maxlen=LOG_LINES))
    log_version: int = 0

    @property
    def disarmed(self) -> bool:
        """No session and the worker not armed: the torque written is zero. (The live window
        is sampled at 50 Hz, so the last record of a session, written with zero torque, is
        usually not in it; the machine's state says it.)"""
        return self.active is None and self.status is not None and not self.status.armed

    def note(self, text: Markdown) -> None:
        self.log.appendleft(md("{} {}", time.strftime("%H:%M:%S"), text))
        self.log_version += 1


def _number(value: Any) -> str:
    return format(value, ".3g") if isinstance(value, int | float) else str(value)


def describe_event(frame: dict[str, Any]) -> Markdown | None:
    """One log line for the events a trainer should see (reasons and faults come from the
    worker and the device: escaped like any other text)."""
    kind = frame.get("kind")
    if frame.get("type") == "session_finished":
        return md("session #{} ended: {}", frame.get("session_id"), frame.get("status"))
    if kind == "estop":
        return md("E-STOP: zero torque written, latched until reset")
    if kind == "fault":
        return md("fault: {}", frame.get("reason"))
    if kind == "limit":
        return md("{} limit hit ({})", frame.get("limit"), _number(frame.get("value", 0)))
    if kind == "stopping":
        return md("stopping: {}", frame.get("reason"))
    if kind == "reset":
        return (
            md("reset failed: {}", frame["fault"]) if frame.get("fault") else md("reset: cleared")
        )
    if kind == "lost":
        return md("worker lost: {}", frame.get("reason"))
    if kind == "rejected":
        return md("machine refused {}: {}", frame.get("command"), frame.get("reason"))
    return None


def _sid(active: ActiveSession | None) -> int | None:
    return active.session_id if active is not None else None


class Feed:
    def __init__(
        self,
        hub: LiveHub,
        machine: MachineService,
        shared: SharedView,
        views: Callable[[], list[ClientView]],
        *,
        load_evaluations: Callable[[int], list[dict[str, Any]]],
        on_finished: Callable[[int, str], None],
    ) -> None:
        self.hub = hub
        self.machine = machine
        self.shared = shared
        self.views = views
        self.load_evaluations = load_evaluations
        self.on_finished = on_finished
        self.state = LiveState()
        self.tick = 0
        self.thread = ThreadPoolExecutor(1, thread_name_prefix="ergoseek-dashboard-feed")
        self.task: asyncio.Task[None] | None = None
        self.subscription: Subscription | None = None

    def start(self) -> None:
        self.task = asyncio.get_running_loop().create_task(self.run(), name="ergoseek-dashboard")

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        hub, machine = self.hub, self.machine
        sub = self.subscription = hub.subscribe(SAMPLE_RATE)
        next_status = 0.0
        try:
            while True:
                started = loop.time()
                _, rows = sub.take()
                events = list(sub.events)
                sub.events.clear()
                status = None
                if started >= next_status:
                    next_status = started + STATUS_EVERY
                    with contextlib.suppress(Exception):
                        status = machine.status()
                snap = Snapshot(rows, events, status, machine.active_session())
                try:
                    await loop.run_in_executor(self.thread, self.apply, snap)
                except RuntimeError:  # the thread was shut down: we are stopping
                    return
                except Exception:
                    log.exception("dashboard feed")
                await asyncio.sleep(max(0.0, TICK - (loop.time() - started)))
        finally:
            hub.unsubscribe(sub)

    # -- the feed thread ---
    def apply(self, snap: Snapshot) -> None:
        st = self.state
        if len(snap.rows):
            st.window.extend(snap.rows)
            st.window_version += 1
        if snap.status is not None:
            st.status = snap.status
            st.status_version += 1
        active = snap.active
        if _sid(active) != _sid(st.active):
            st.status_version += 1
        st.active = active
        if active is not None and st.seeker.session_id != active.session_id:
            st.seeker.reset(active.session_id, active.cfg)
            try:  # a session that was running before this dashboard saw it start
                for ev in self.load_evaluations(active.session_id):
                    st.seeker.add(ev)
            except Exception:
                log.exception("loading the evaluations of session %s", active.session_id)
            if active.target is not None and st.seeker.evaluations:
                st.seeker.target, st.seeker.done = active.target, active.done
        for frame in snap.events:
            self._event(frame)
        self.tick += 1
        if not self.shared.has_clients():
            return
        text = self.tick % TEXT_EVERY == 0
        try:
            self.shared.render(st, text)
        except Exception:
            log.exception("rendering the dashboard's shared picture")
        picture = self.shared.picture(st) if text else None
        for view in self.views():
            try:
                view.render(st, picture)
            except Exception:
                log.exception("rendering dashboard client %s", view.client_id)

    def _event(self, frame: dict[str, Any]) -> None:
        st = self.state
        if frame.get("type") == "seeker":  # (the pump adds the session's database id)
            if frame.get("db_session_id") == st.seeker.session_id:
                st.seeker.add(frame)
            return
        text = describe_event(frame)
        if text is not None:
            st.note(text)
        if frame.get("type") == "session_finished":
            sid, status = int(frame["session_id"]), str(frame.get("status"))
            st.last_finished = (sid, status)
            st.status_version += 1
            self.on_finished(sid, status)

    def stop(self, loop: asyncio.AbstractEventLoop | None) -> None:
        """Cancel the task (from any thread) and end the feed thread."""
        task = self.task
        if task is not None and loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(task.cancel)
        self.thread.shutdown(wait=True, cancel_futures=True)
