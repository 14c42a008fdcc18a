"""The machine service: one machine's worker, its running session and the pump that records
it. What the API and the dashboard ask of the machine, and nothing of HTTP or viser.

- **start** fits the trainer's request to the machine (:mod:`sessions.requests`), stores the
  session, hands it to the worker and waits (bounded) until the worker has started it;
- **stop** (controlled), **estop** (zero torque on the worker's next cycle, latched),
  **reset** (clears a latch; a lost worker is replaced; never starts motion);
- **status**, **live** and **active_session** read what the worker and the pump know.

One instance per machine; the web process has one today. Not thread-safe: it lives on the web
process's event loop (the dashboard reaches it through :class:`webui.bridge.Bridge`).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
from typing import Any

from pydantic import BaseModel, Field

from server.service.live import LiveHub
from server.service.pump import Pump
from server.service.reasons import one_line
from server.service.session import ActiveSession, LiveSession
from sessions.codes import phase_name
from sessions.machine.spec import MachineSpec
from sessions.requests import Rig, SessionStart, session_config
from sessions.store import ConflictError, SessionRecord, Store
from sessions.telemetry import RECORD_INDEX as RING
from sessions.worker import Worker, WorkerError, WorkerOptions

log = logging.getLogger("ergoseek.machine")

START_TIMEOUT = 10.0  # s for the worker to accept a session
END_TIMEOUT = 5.0  # s for the pump to record the end of a session the worker has ended
LIVE_CHANNELS = ("t", "w", "wd", "u", "tau", "p", "W", "gamma")


class BusyError(RuntimeError):
    """409: a session is running (or the machine is latched and must be reset first)."""


class MachineStatus(BaseModel):
    """The machine now: backend, worker state, latched fault, loop timing."""

    backend: str
    state: str
    armed: bool
    fault: str | None
    session_id: int | None
    heartbeat_age_ms: float | None
    limits: dict[str, float]
    rate_hz: float
    timing: dict[str, float | int] | None
    realtime: dict[str, object] | None


class Live(BaseModel):
    """A running session as the worker reports it now."""

    state: str
    t: float | None = None
    w: float | None = None
    wd: float | None = None
    u: float | None = None
    tau: float | None = None
    p: float | None = None
    W: float | None = None
    gamma: float | None = None
    phase: str | None = None
    target: float | None = None
    done: bool = False
    evaluations: int = 0
    stage: dict[str, Any] | None = Field(
        None, description="the protocol stage running (sessions.protocol.stage.Stage), SI"
    )
    time_left: float | None = Field(None, description="s left in the stage (planned)")
    phase_time_left: float | None = Field(None, description="s left in the phase (planned)")


class MachineService:
    def __init__(
        self, store: Store, spec: MachineSpec, rig: Rig, hub: LiveHub, options: WorkerOptions
    ) -> None:
        self.store = store
        self.spec = spec
        self.rig = rig
        self.hub = hub
        self.options = options
        self.worker: Worker | None = None
        self.pump = Pump(store, hub)
        self._lock = asyncio.Lock()

    @property
    def backend(self) -> str:
        return self.rig.name

    @property
    def active(self) -> LiveSession | None:
        return self.pump.session

    @property
    def lost(self) -> str | None:
        return self.pump.lost

    # -- life ------------------------------------------------------------------------------------
    async def open(self) -> None:
        await self._spawn()
        self.pump.start()

    async def _spawn(self) -> None:
        worker = Worker(self.spec, self.options)
        ready = await asyncio.to_thread(worker.start)
        self.worker = worker
        self.pump.attach(worker)
        log.info("worker %s ready (%s)", worker.pid, ready.fault or "no fault" if ready else "")

    async def halt(self, reason: str = "server shut down") -> None:
        """Zero torque now; the running session ends as stopped for ``reason``, its last
        records and its end stored and published (the first step of a shutdown, while the
        live clients are still connected to see it)."""
        worker, pump = self.worker, self.pump
        if worker is not None and pump.session is not None:
            with contextlib.suppress(WorkerError):
                worker.stop(immediate=True, reason=reason)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(pump.session.ended.wait(), 3.0)

    async def close(self) -> None:
        """Zero torque, the running session ends as stopped, the worker exits; nothing lost."""
        worker, pump = self.worker, self.pump
        await self.halt()
        await pump.stop()
        if worker is not None:
            events = await asyncio.to_thread(worker.shutdown)
            pump.drain_ring()
            for ev in events:
                await pump.handle(ev)
        if pump.session is not None:  # the worker never told: end it from what was stored
            await pump.finish(pump.session, "stopped", None, "server shut down")
        pump.close()

    # -- commands --------------------------------------------------------------------------------
    async def start(self, req: SessionStart, account_id: int | None) -> SessionRecord:
        """Start the session ``req`` asks for; its record once the worker runs it. Raises
        RequestError (422), NotFoundError (404), BusyError (409)."""
        async with self._lock:
            worker = self._require_worker()
            await self._recorded_end(worker)
            if self.active is not None:
                raise BusyError(f"session {self.active.db_id} is running")
            state = worker.status().state
            if state != "idle":
                raise BusyError(f"the machine is {state}: reset it first")
            user = await asyncio.to_thread(self.store.users.get, req.user_id)
            current = await asyncio.to_thread(self.store.setpoints.current, req.user_id)
            optimum = current.velocity if current else None
            cfg = session_config(req, self.rig, sim_profile=user.sim_profile, optimum=optimum)
            record = await asyncio.to_thread(
                self.store.sessions.start,
                req.user_id,
                cfg,
                backend=self.backend,
                account_id=account_id,
            )
            await self._launch(
                worker, LiveSession(record.id, req.user_id, cfg, self.store.recorder(record.id))
            )
            self.hub.session_id = record.id
            return record

    async def _recorded_end(self, worker: Worker) -> None:
        """A session the worker has ended (and said so: it reads idle, e-stopped or faulted)
        while the pump is still recording its end: wait (bounded) for that record. A trainer
        who sees the machine idle or e-stopped and acts in that moment is not refused for a
        session that no longer runs."""
        active = self.active
        if active is None or worker.status().state in ("running", "stopping", "starting"):
            return
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(active.ended.wait(), END_TIMEOUT)

    async def _launch(self, worker: Worker, session: LiveSession) -> None:
        """Hand the session to the worker and wait until it runs it (or refuses)."""
        self.pump.session = session
        try:
            worker.start_session(session.cfg, session.tag)
            await asyncio.wait_for(session.started.wait(), START_TIMEOUT)
        except (WorkerError, ValueError, TimeoutError) as exc:
            reason = one_line(session.rejected or str(exc)) or "the worker did not start it"
            await self.pump.finish(session, "faulted", None, reason)
            raise BusyError(f"the machine refused the session: {reason}") from None
        if session.rejected is not None:
            reason = one_line(session.rejected)
            await self.pump.finish(session, "faulted", None, reason)
            raise BusyError(f"the machine refused the session: {reason}")

    def stop(self, session_id: int) -> None:
        """A controlled stop of the running session ``session_id`` (409 if it is not)."""
        active = self.active
        if active is None or active.db_id != session_id:
            raise ConflictError(f"session {session_id} is not running")
        self._require_worker().stop()

    def estop(self) -> None:
        """Zero torque at once; latched until :meth:`reset`. With no worker (lost, however it
        went) nothing drives the motor: the e-stop holds as it is (the lost state is latched
        too, until a reset), and it never fails."""
        worker = self.worker
        if worker is None or self.lost is not None:
            log.warning("e-stop with the worker lost (%s): nothing drives the motor", self.lost)
            return
        try:
            worker.estop()
        except WorkerError as exc:  # it died just now: the pump records the end
            log.warning("e-stop: %s; nothing drives the motor", exc)

    async def reset(self) -> None:
        """Clear a latched e-stop or fault; a lost worker (killed, crashed, exited, unreachable)
        is replaced, after its last events are recorded. Never starts motion; refused (409)
        while a session runs on a healthy worker: a reset there would do nothing."""
        async with self._lock:
            worker = self.worker
            healthy = (
                worker is not None and self.lost is None and worker.state not in ("lost", "closed")
            )
            if healthy:
                await self._recorded_end(worker)
            if healthy and self.active is not None:
                raise BusyError(f"session {self.active.db_id} is running: stop it first")
            if healthy:
                try:
                    worker.reset()
                    return
                except WorkerError:  # found gone on the way: replace it below
                    pass
            if worker is not None:
                await self._retire(worker)
            await self._spawn()

    async def _retire(self, worker: Worker) -> None:
        """Take down a worker that is gone or going, recording what it said last (a session
        it was running ends aborted, its data kept). What is left of it cannot keep the
        machine down: a failure taking it down is logged and the new worker starts anyway."""
        pump = self.pump
        pump.worker = None  # the pump stops polling it: a handle is used from one thread
        try:
            events = await asyncio.to_thread(worker.shutdown)
        except Exception:
            log.exception("taking down the lost worker")
            events = []
        pump.drain_ring()
        for ev in events:
            await pump.handle(ev)
        if pump.session is not None:  # it never told: end the session from what was stored
            await pump.finish(pump.session, "aborted", None, self.lost or "worker lost")

    def _require_worker(self) -> Worker:
        if self.worker is None or self.lost is not None:
            raise BusyError(f"the machine's worker is lost ({self.lost}): reset it")
        return self.worker

    # -- reads -------------------------------------------------------------------------------------
    def status(self) -> MachineStatus:
        worker = self.worker
        st = worker.status() if worker is not None else None
        state = "lost" if self.lost else (st.state if st else "starting")
        active = self.active
        m = self.rig.machine
        return MachineStatus(
            backend=self.backend,
            state=state,
            armed=state in ("running", "stopping"),
            fault=one_line(self.lost or (st.fault if st else None)),
            session_id=active.db_id if active is not None else None,
            heartbeat_age_ms=(
                st.heartbeat_age * 1e3 if st and st.heartbeat_age is not None else None
            ),
            limits={"max_torque": m.max_torque, "max_velocity": m.max_velocity},
            rate_hz=self.rig.rate,
            timing=dataclasses.asdict(st.timing) if st and st.timing else None,
            realtime=dataclasses.asdict(st.realtime) if st and st.realtime else None,
        )

    def active_session(self) -> ActiveSession | None:
        active = self.active
        return active.snapshot() if active is not None else None

    def running_user(self) -> int | None:
        """The user whose session is running, if one is."""
        active = self.active
        return active.user_id if active is not None else None

    def live(self, session_id: int) -> Live | None:
        """The running session ``session_id`` now (None if it is not running)."""
        active = self.active
        if active is None or active.db_id != session_id:
            return None
        out = Live(
            state=self.worker.state if self.worker else "lost",
            target=active.target,
            done=active.done,
            evaluations=active.evaluations,
        )
        stage = active.stage
        if stage is not None:
            out.stage = stage.to_dict()
        row = active.last_row
        if row is None:
            return out
        if stage is not None:
            now = float(row[RING["t"]])
            out.time_left = max(0.0, stage.end - now)
            out.phase_time_left = max(0.0, stage.phase_end - now)
        values = {k: float(row[RING[k]]) for k in LIVE_CHANNELS}
        clean = {k: (v if math.isfinite(v) else None) for k, v in values.items()}
        return out.model_copy(update={**clean, "phase": phase_name(float(row[RING["phase"]]))})
