"""The web process's side of the machine: it starts sessions on the worker, and a pump (an
asyncio task, 100 Hz) moves what the worker produces to the store and the live clients.

    worker ring ──► pump ──► SessionRecorder (store, committed ≤ 1 s)
                        └──► LiveHub (WebSocket clients)
    worker events ─► pump ──► store (evaluations, events, the end) + LiveHub

When a session completes with a converged seeker, its optimum becomes the user's setpoint,
and the next session's bracket starts around it. A worker that dies or stops beating ends
the session ``aborted`` (its data stays); the API stays up and reports the machine lost until
a reset starts a new worker.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from server.live import LiveHub
from server.schemas import Live, SessionStart
from server.settings import Settings
from sessions.config import (
    ScenarioError,
    SessionConfig,
    UserConfig,
    parse_session_config,
)
from sessions.machine.spec import MachineSpec
from sessions.store import ConflictError, SessionRecord, SessionRecorder, Store, StoreValueError
from sessions.telemetry import WIDTH
from sessions.worker.handle import Worker, WorkerError
from sessions.worker.messages import (
    EStopped,
    Event,
    Faulted,
    LimitHit,
    Rejected,
    SeekerEvaluation,
    SessionEnded,
    SessionStarted,
    WorkerLost,
)
from sessions.worker.process import WorkerOptions
from sessions.worker.ring import INDEX as RING
from sessions.worker.ring import RingReader

log = logging.getLogger("ergoseek.control")

PUMP_INTERVAL = 0.01  # s
START_TIMEOUT = 10.0  # s for the worker to accept a session
EARLY_ROWS_MAX = 100_000  # ring rows kept while waiting for SessionStarted (100 s at 1 kHz)
PHASES = {0.0: "delay", 1.0: "settling", 2.0: "measuring", 3.0: "done", -1.0: "stopping"}


class RequestError(ValueError):
    """A request the machine cannot take: ``field`` (dotted, under the body) and ``reason``."""

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}")


class BusyError(RuntimeError):
    """409: a session is running (or the machine is latched and must be reset first)."""


@dataclass
class Active:
    db_id: int
    user_id: int
    cfg: SessionConfig
    recorder: SessionRecorder
    worker_session: int | None = None
    started: asyncio.Event = field(default_factory=asyncio.Event)
    rejected: str | None = None
    ended: asyncio.Event = field(default_factory=asyncio.Event)
    target: float | None = None
    done: bool = False
    evaluations: int = 0
    last_row: np.ndarray | None = None
    # Ring rows read before the worker's SessionStarted event was: the loop may run a few
    # periods before the pump sees the event; they are recorded once it does.
    early: list[np.ndarray] = field(default_factory=list)


def default_bracket(v: float | None, vmax: float) -> tuple[float, float, float] | None:
    """A bracket around a stored optimum v: [0.6 v, v, 1.5 v] within the machine's range."""
    if v is None or not math.isfinite(v) or v <= 0:
        return None
    top = 0.9 * vmax
    mid = min(v, 0.8 * top)
    lo, hi = max(0.2, 0.6 * mid), min(1.5 * mid, top)
    return (lo, mid, hi) if lo < mid < hi else None


class Control:
    """Owns the worker and the running session's recorder; everything else asks it."""

    def __init__(self, settings: Settings, store: Store, spec: MachineSpec, hub: LiveHub) -> None:
        self.settings = settings
        self.store = store
        self.spec = spec
        self.hub = hub
        self.worker: Worker | None = None
        self.reader: RingReader | None = None
        self.active: Active | None = None
        self.lost: str | None = None
        self._pump: asyncio.Task[None] | None = None
        self._lock = asyncio.Lock()

    # -- life ------------------------------------------------------------------------------------
    async def open(self) -> None:
        await self._spawn()
        self._pump = asyncio.create_task(self._run_pump(), name="ergoseek-pump")

    async def _spawn(self) -> None:
        options = WorkerOptions()
        worker = Worker(self.spec, options)
        ready = await asyncio.to_thread(worker.start)
        self.worker = worker
        self.reader = worker.open_reader("now")
        self.lost = None
        log.info("worker %s ready (%s)", worker.pid, ready.fault or "no fault" if ready else "")

    async def close(self) -> None:
        """Zero torque, the running session ends as stopped, the worker exits; nothing lost."""
        worker = self.worker
        if worker is not None and self.active is not None:
            with contextlib.suppress(WorkerError):
                worker.stop(immediate=True)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.active.ended.wait(), 3.0)
        if self._pump is not None:
            self._pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._pump
        if worker is not None:
            events = await asyncio.to_thread(worker.shutdown)
            self._drain_ring()
            for ev in events:
                await self._handle(ev)
        if self.active is not None:  # the worker never told: end it from what was stored
            await self._finish(self.active, "stopped", None, "server shut down")
        if self.reader is not None:
            self.reader.close()
            self.reader = None

    # -- commands --------------------------------------------------------------------------------
    def build_config(
        self, req: SessionStart, user_sim: dict[str, Any] | None, v_opt: float | None
    ) -> SessionConfig:
        s = self.settings
        limits = req.limits
        max_torque, max_velocity = s.max_torque, s.max_velocity
        if limits is not None and limits.max_torque is not None:
            if limits.max_torque > s.max_torque:
                raise RequestError(
                    "limits.max_torque", f"must not exceed the machine's {s.max_torque:g} N·m"
                )
            max_torque = limits.max_torque
        if limits is not None and limits.max_velocity is not None:
            if limits.max_velocity > s.max_velocity:
                raise RequestError(
                    "limits.max_velocity",
                    f"must not exceed the machine's {s.max_velocity:g} rad/s",
                )
            max_velocity = limits.max_velocity
        seeker = req.seeker.model_dump() if req.seeker is not None else {}
        given = req.seeker.model_fields_set if req.seeker is not None else set()
        if "bracket" not in given:
            around = default_bracket(v_opt, max_velocity)
            if around is not None:
                seeker["bracket"] = around
            else:
                lo, mid, hi = seeker.get("bracket", (1.0, 3.5, 6.0))
                top = 0.9 * max_velocity
                if hi >= top:  # the default bracket, scaled into a slow machine
                    k = top / hi
                    seeker["bracket"] = (lo * k, mid * k, hi * k)
        if "setpoint" not in given and seeker.get("kind") == "fixed" and v_opt is not None:
            seeker["setpoint"] = min(v_opt, 0.9 * max_velocity)
        user = UserConfig.model_validate(user_sim) if user_sim else UserConfig()
        data = {
            "duration": req.duration,
            "rate": s.rate,
            "seed": req.seed if req.seed is not None else int(time.time() * 1000) % 2**31,
            "machine": {
                "inertia": s.inertia,
                "max_torque": max_torque,
                "max_velocity": max_velocity,
            },
            "user": user.model_dump(),
            "controller": req.controller.model_dump() if req.controller is not None else {},
            "seeker": seeker,
        }
        try:
            return parse_session_config(data)
        except ScenarioError as exc:
            field_, _, reason = str(exc).partition(": ")
            raise RequestError(field_, reason or str(exc)) from None

    async def start(self, req: SessionStart, account_id: int | None) -> SessionRecord:
        async with self._lock:
            worker = self._require_worker()
            if self.active is not None:
                raise BusyError(f"session {self.active.db_id} is running")
            state = worker.status().state
            if state != "idle":
                raise BusyError(f"the machine is {state}: reset it first")
            user = await asyncio.to_thread(self.store.users.get, req.user_id)
            current = await asyncio.to_thread(self.store.setpoints.current, req.user_id)
            cfg = self.build_config(req, user.sim_profile, current.velocity if current else None)
            if cfg.controller.kind == "measured" and not self.spec.has_torque_sensor:
                raise RequestError(
                    "controller.kind",
                    f"the {self.backend} machine has no torque sensor: use 'rise' (eq. 23)",
                )
            record = await asyncio.to_thread(
                self.store.sessions.start,
                req.user_id,
                cfg,
                backend=self.backend,
                account_id=account_id,
            )
            active = Active(record.id, req.user_id, cfg, self.store.recorder(record.id))
            self.active = active
            try:
                worker.start_session(cfg, str(record.id))
                await asyncio.wait_for(active.started.wait(), START_TIMEOUT)
            except (WorkerError, ValueError, TimeoutError) as exc:
                reason = active.rejected or str(exc) or "the worker did not start the session"
                await self._finish(active, "faulted", None, reason)
                raise BusyError(f"the machine refused the session: {reason}") from None
            if active.rejected is not None:
                await self._finish(active, "faulted", None, active.rejected)
                raise BusyError(f"the machine refused the session: {active.rejected}")
            self.hub.session_id = record.id
            return record

    def stop(self, session_id: int) -> None:
        active = self.active
        if active is None or active.db_id != session_id:
            raise ConflictError(f"session {session_id} is not running")
        self._require_worker().stop()

    def estop(self) -> None:
        """Zero torque at once; latched until :meth:`reset`."""
        self._require_worker().estop()

    async def reset(self) -> None:
        """Clear a latched e-stop or fault; a lost worker is replaced. Never starts motion."""
        async with self._lock:
            if self.worker is None or self.lost is not None:
                if self.worker is not None:
                    await asyncio.to_thread(self.worker.shutdown)
                    if self.reader is not None:
                        self.reader.close()
                await self._spawn()
                return
            self.worker.reset()

    def _require_worker(self) -> Worker:
        if self.worker is None or self.lost is not None:
            raise BusyError(f"the machine's worker is lost ({self.lost}): reset it")
        return self.worker

    # -- the pump ----------------------------------------------------------------------------------
    async def _run_pump(self) -> None:
        while True:
            try:
                await self.pump_once()
            except asyncio.CancelledError:
                raise
            except Exception:  # the pump must outlive any one bad batch
                log.exception("pump")
            await asyncio.sleep(PUMP_INTERVAL)

    async def pump_once(self) -> None:
        worker = self.worker
        if worker is None:
            return
        events = worker.poll()
        try:
            self._drain_ring()
        finally:  # events are never lost to a bad batch of telemetry
            for ev in events:
                await self._handle(ev)

    def _drain_ring(self) -> None:
        reader = self.reader
        if reader is None:
            return
        while True:
            batch = reader.read(max_records=50_000)
            if not len(batch):
                return
            self.hub.publish_telemetry(batch.seq, batch.data, batch.missed)
            active = self.active
            if active is None:
                continue
            if active.worker_session is None:
                if sum(map(len, active.early)) < EARLY_ROWS_MAX:
                    active.early.append(batch.data.copy())
                continue
            self._record(active, batch.data)

    def _record(self, active: Active, rows: np.ndarray) -> None:
        mine = rows[rows[:, RING["session"]] == active.worker_session]
        if len(mine):
            try:
                active.recorder.add_rows(mine[:, :WIDTH])
            except StoreValueError as exc:  # keep the session going; say what was refused
                log.warning("session %s: telemetry refused (%s)", active.db_id, exc)
            active.last_row = mine[-1]

    async def _handle(self, ev: Event) -> None:
        active = self.active
        frame = {"type": "event", **ev.to_dict()}
        if isinstance(ev, SessionStarted):
            if active is not None and ev.session_id == str(active.db_id):
                active.worker_session = ev.session
                for rows in active.early:
                    self._record(active, rows)
                active.early.clear()
                active.started.set()
                frame["db_session_id"] = active.db_id
        elif isinstance(ev, Rejected):
            if active is not None and ev.command == "start" and not active.started.is_set():
                active.rejected = ev.reason
                active.started.set()
        elif isinstance(ev, SeekerEvaluation):
            if active is not None and ev.session_id == str(active.db_id):
                active.target, active.done = ev.target, ev.done
                active.evaluations += 1
                with contextlib.suppress(StoreValueError):
                    active.recorder.add_evaluation(ev)
                frame["type"] = "seeker"
        elif isinstance(ev, LimitHit | EStopped | Faulted):
            session_t = getattr(ev, "session_t", None)
            if active is not None and active.last_row is not None and session_t is None:
                session_t = float(active.last_row[RING["t"]])
            if active is not None:
                detail = {k: v for k, v in ev.to_dict().items() if k not in ("kind", "t")}
                with contextlib.suppress(StoreValueError):
                    active.recorder.add_event(session_t or 0.0, ev.kind, detail)
        elif isinstance(ev, SessionEnded):
            if active is not None and ev.session_id == str(active.db_id):
                self._drain_ring()
                reason = None if ev.status == "completed" else ev.reason
                await self._finish(active, ev.status, ev.summary, reason)
        elif isinstance(ev, WorkerLost):
            self.lost = ev.reason
            if active is not None:
                await self._finish(active, "aborted", None, ev.reason)
        self.hub.publish_event(frame)

    async def _finish(self, active: Active, status: str, summary: Any, reason: str | None) -> None:
        if self.active is active:
            self.active = None
        self.hub.session_id = None
        try:
            record = await asyncio.to_thread(
                active.recorder.finish,
                status,
                summary,
                abort_reason=reason,  # type: ignore[arg-type]
            )
        except ConflictError:
            record = None
        except Exception:
            log.exception("could not finish session %s", active.db_id)
            record = None
        if record is not None and status == "completed" and record.converged and record.optimum_w:
            with contextlib.suppress(ConflictError):
                await asyncio.to_thread(self.store.setpoints.from_session, active.db_id)
        active.ended.set()
        self.hub.publish_event(
            {"type": "session_finished", "session_id": active.db_id, "status": status}
        )

    # -- reads -------------------------------------------------------------------------------------
    @property
    def backend(self) -> str:
        return (
            self.settings.machine
            if self.settings.machine != "odrive-emulator"
            else "odrive-emulator"
        )

    def live(self, session_id: int) -> Live | None:
        active = self.active
        if active is None or active.db_id != session_id:
            return None
        row = active.last_row
        out = Live(
            state=self.worker.state if self.worker else "lost",
            target=active.target,
            done=active.done,
            evaluations=active.evaluations,
        )
        if row is None:
            return out
        values = {k: float(row[RING[k]]) for k in ("t", "w", "wd", "u", "tau", "p", "W", "gamma")}
        clean = {k: (v if math.isfinite(v) else None) for k, v in values.items()}
        return out.model_copy(update={**clean, "phase": PHASES.get(float(row[RING["phase"]]))})
