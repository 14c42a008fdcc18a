"""The emulator in a process of its own (spawn), driven over a pipe: what the tests and the
benchmarks use, so that nothing in the host process (its garbage collector, its GIL) can delay
the device's answers."""

from __future__ import annotations

import contextlib
import gc
import multiprocessing as mp
import os
import signal
from multiprocessing.connection import Connection

from sessions.machine.odrive.emulator.device import DeviceFault, EmulatorConfig, EmulatorSnapshot
from sessions.machine.odrive.emulator.pty import Injection, OdriveEmulator


class EmulatorProcess:
    """An :class:`OdriveEmulator` in its own process, with the same observation and
    fault-injection calls."""

    def __init__(
        self, rig: EmulatorConfig | None = None, timeout: float = 30.0, *, realtime: bool = True
    ) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve_in_child,
            args=(child, rig or EmulatorConfig(), realtime),
            daemon=True,
            name="odrive-emulator",
        )
        self._proc.start()
        child.close()
        if not self._conn.poll(timeout):
            self._proc.kill()
            raise RuntimeError("the ODrive emulator did not start")
        self.path: str = self._conn.recv()
        self.pid: int = self._proc.pid

    def _call(self, name: str, *args: object) -> object:
        self._conn.send((name, args))
        if not self._conn.poll(10.0):
            raise TimeoutError(f"the emulator did not answer {name}")
        result = self._conn.recv()
        if isinstance(result, Exception):
            raise result
        return result

    def snapshot(self) -> EmulatorSnapshot:
        return self._call("snapshot")  # type: ignore[return-value]

    def inject(self, kind: Injection | None, count: int | None = 1) -> None:
        self._call("inject", kind, count)

    def device_fault(self, kind: DeviceFault) -> None:
        self._call("device_fault", kind)

    def torques_since(self, t: float) -> list[tuple[float, float]]:
        return self._call("torques_since", t)  # type: ignore[return-value]

    def events(self) -> list[tuple[float, str]]:
        return self._call("events")  # type: ignore[return-value]

    def close(self) -> None:
        if self._proc.is_alive():
            with contextlib.suppress(OSError, EOFError, TimeoutError):
                self._call("close")
            self._proc.join(2.0)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(1.0)
        self._conn.close()

    def __enter__(self) -> EmulatorProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def device_priority(priority: int = 60) -> bool:
    """Run the calling process as a device would: SCHED_FIFO above the worker's default (50),
    so it answers within microseconds of a request however busy the host is. Quietly False
    when not permitted."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError):
        return False
    return True


def _serve_in_child(control: Connection, rig: EmulatorConfig, realtime: bool) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if realtime:
        device_priority()
    emu = OdriveEmulator(rig)
    gc.collect()
    gc.freeze()  # the long-lived state stays out of every collection
    control.send(emu.path)
    try:
        emu.serve_forever(control)
    finally:
        emu.close()
