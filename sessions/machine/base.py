"""The machine a session drives: one lifecycle, one read → update → write cycle, any backend.

Shaped like a ros2_control hardware interface. The controller (:class:`sessions.loop.Loop`)
never knows which backend it drives; the worker calls, once per period::

    q, w, tau = machine.read()      # state in (tau: measured user torque, or NaN)
    u = loop.step(q, w, tau)        # update
    machine.write(u)                # command out

Lifecycle (:class:`MachineState`)::

    UNCONNECTED --connect()--> CONNECTED --arm(cfg)--> ARMED --activate()--> ACTIVE
    ACTIVE/ARMED --disarm()--> DISARMED --arm(cfg)--> ARMED ...
    any --close()--> CLOSED
    any failure --> FAULT (latched: torque zero as far as the backend can make it)
    FAULT --reset()--> CONNECTED (never armed, never moving by itself)

Every failure of a backend operation becomes a :class:`MachineError`: the machine enters
FAULT, writes zero torque best effort, and the fault stays latched until :meth:`reset`.
:meth:`zero` never raises: it is what e-stops and shutdown paths call.
"""

from __future__ import annotations

import contextlib
import enum
from collections.abc import Callable
from typing import Any, ClassVar

from sessions.config import SessionConfig
from sessions.machine.spec import check_controller
from sessions.truth import Truth


class MachineState(enum.IntEnum):
    UNCONNECTED = 0
    CONNECTED = 1
    ARMED = 2
    ACTIVE = 3
    DISARMED = 4
    CLOSED = 5
    FAULT = 6


class MachineError(RuntimeError):
    """A fault: the machine failed; it is now in FAULT with zero torque commanded (best effort)."""


def _nothing() -> None:
    return None


class Machine:
    """Base class: the lifecycle and its checks; backends implement the ``_``-prefixed hooks.

    ``keepalive`` is called by backends while they wait inside long operations (arming a
    drive takes up to seconds), so the worker's heartbeat keeps beating.
    """

    kind: ClassVar[str] = "machine"
    has_torque_sensor: ClassVar[bool] = False
    # the plant moves on its own clock between writes (a real drive holds the last torque):
    # a period the worker misses is real time the loop must account for. A simulator that
    # advances one period per write is not free-running.
    free_running: ClassVar[bool] = False

    def __init__(self) -> None:
        self.state = MachineState.UNCONNECTED
        self.fault_reason: str | None = None
        self.keepalive: Callable[[], None] = _nothing
        self.max_torque = 0.0
        self.last_command = 0.0
        self.cues: Any = None

    def follow(self, cues: Any) -> None:
        """The session's cues to the person (``effort``, 0 … 1: :mod:`sessions.protocol.cues`),
        before :meth:`arm`: a simulated person follows them; a real one reads them on the
        dashboard, so hardware ignores them."""
        self.cues = cues

    # -- lifecycle ---------------------------------------------------------------------
    def connect(self) -> None:
        self._require(MachineState.UNCONNECTED, "connect")
        self._guard(self._connect)
        self.state = MachineState.CONNECTED

    def arm(self, cfg: SessionConfig) -> None:
        """Prepare for a session: limits set, drive enabled, zero torque."""
        self._require((MachineState.CONNECTED, MachineState.DISARMED), "arm")
        check_controller(self.kind, self.has_torque_sensor, cfg.controller.kind)
        self.max_torque = cfg.machine.max_torque
        self.last_command = 0.0
        self._guard(lambda: self._arm(cfg))
        self.state = MachineState.ARMED

    def activate(self) -> None:
        self._require(MachineState.ARMED, "activate")
        self.state = MachineState.ACTIVE

    def read(self) -> tuple[float, float, float]:
        """(q rad, w rad/s, measured user torque N·m or NaN). Raises MachineError."""
        if self.state is not MachineState.ACTIVE and self.state is not MachineState.ARMED:
            raise MachineError(self._not_in("read"))
        try:
            return self._read()
        except MachineError as exc:
            self._fail(str(exc))
            raise
        except Exception as exc:
            self._fail(f"read failed: {exc}")
            raise MachineError(self.fault_reason) from exc

    def write(self, u: float) -> None:
        """Command motor torque u (N·m at the handle), clamped to the session's limit."""
        if self.state is not MachineState.ACTIVE:
            raise MachineError(self._not_in("write"))
        if not -1e300 < u < 1e300:  # NaN or infinite: a bug upstream, never a command
            self._fail(f"non-finite torque command {u!r}")
            raise MachineError(self.fault_reason)
        m = self.max_torque
        if u > m:
            u = m
        elif u < -m:
            u = -m
        try:
            self._write(u)
        except MachineError as exc:
            self._fail(str(exc))
            raise
        except Exception as exc:
            self._fail(f"write failed: {exc}")
            raise MachineError(self.fault_reason) from exc
        self.last_command = u

    def truth(self) -> Truth | None:
        """The person's true power curve where the backend has one (the simulator's simulated
        person: the session's summary then scores its ``regret``); None on real hardware."""
        return None

    def zero(self) -> None:
        """Zero torque now, best effort, whatever the state. Never raises."""
        self.last_command = 0.0
        with contextlib.suppress(Exception):  # the safe path must not throw
            self._zero()

    def disarm(self) -> None:
        """Zero torque and disable the drive; the session is over."""
        if self.state in (MachineState.ARMED, MachineState.ACTIVE):
            self.zero()
            self._guard(self._disarm)
            self.state = MachineState.DISARMED

    def reset(self) -> None:
        """Clear a latched fault. The machine comes back CONNECTED, disarmed, not moving."""
        if self.state is MachineState.FAULT:
            self._guard(self._reset)
            self.fault_reason = None
            self.state = MachineState.CONNECTED

    def close(self) -> None:
        if self.state is MachineState.CLOSED:
            return
        self.zero()
        with contextlib.suppress(Exception):  # closing must finish
            if self.state in (MachineState.ARMED, MachineState.ACTIVE):
                self._disarm()
        try:
            self._close()
        finally:
            self.state = MachineState.CLOSED

    # -- helpers -------------------------------------------------------------------------
    def _require(self, states: MachineState | tuple[MachineState, ...], op: str) -> None:
        ok = states if isinstance(states, tuple) else (states,)
        if self.state not in ok:
            if self.state is MachineState.FAULT:
                raise MachineError(f"cannot {op}: latched fault ({self.fault_reason}); reset first")
            raise MachineError(self._not_in(op))

    def _not_in(self, op: str) -> str:
        return f"cannot {op} in state {self.state.name}"

    def _guard(self, fn: Callable[[], None]) -> None:
        try:
            fn()
        except MachineError as exc:
            self._fail(str(exc))
            raise
        except Exception as exc:
            self._fail(f"{type(exc).__name__}: {exc}")
            raise MachineError(self.fault_reason) from exc

    def _fail(self, reason: str) -> None:
        if self.state is not MachineState.FAULT:
            self.fault_reason = reason
        self.state = MachineState.FAULT
        self.zero()

    # -- backend hooks -------------------------------------------------------------------
    def _connect(self) -> None:
        raise NotImplementedError

    def _arm(self, cfg: SessionConfig) -> None:
        raise NotImplementedError

    def _read(self) -> tuple[float, float, float]:
        raise NotImplementedError

    def _write(self, u: float) -> None:
        raise NotImplementedError

    def _zero(self) -> None:
        raise NotImplementedError

    def _disarm(self) -> None:
        raise NotImplementedError

    def _reset(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError
