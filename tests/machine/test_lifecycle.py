"""The machine lifecycle of :class:`sessions.machine.base.Machine`, in-process: what each
state allows, and what a failing backend leaves behind.

A backend's operations fail in the field (a port gone, a drive refusing a write): the
lifecycle must turn every failure into a :class:`MachineError`, latch FAULT with zero torque
commanded, keep the first reason, and let nothing but a reset clear it. The backend here is
the simulator with a switch that makes one of its operations raise what a driver raises.
"""

from __future__ import annotations

import pytest

from sessions.config import SessionConfig, parse_session_config
from sessions.machine import MachineError, MachineState
from sessions.machine.base import Machine
from sessions.machine.sim import SimMachine


def cfg_(max_torque: float = 10.0) -> SessionConfig:
    return parse_session_config({"duration": 1.0, "machine": {"max_torque": max_torque}})


class FailingSim(SimMachine):
    """The simulator whose operation ``op`` (connect, arm, read, write, zero, disarm, reset,
    close) raises ``exc``; every zero-torque call is counted."""

    def __init__(self) -> None:
        super().__init__()
        self.fail: dict[str, BaseException] = {}
        self.zeros = 0
        self.disarms = 0

    def _maybe(self, op: str) -> None:
        if op in self.fail:
            raise self.fail[op]

    def _connect(self) -> None:
        self._maybe("connect")

    def _arm(self, cfg: SessionConfig) -> None:
        self._maybe("arm")
        super()._arm(cfg)

    def _read(self) -> tuple[float, float, float]:
        self._maybe("read")
        return super()._read()

    def _write(self, u: float) -> None:
        self._maybe("write")
        super()._write(u)

    def _zero(self) -> None:
        self.zeros += 1
        self._maybe("zero")

    def _disarm(self) -> None:
        self.disarms += 1
        self._maybe("disarm")

    def _reset(self) -> None:
        self._maybe("reset")

    def _close(self) -> None:
        self._maybe("close")
        super()._close()


def active(max_torque: float = 10.0) -> FailingSim:
    m = FailingSim()
    m.connect()
    m.arm(cfg_(max_torque))
    m.activate()
    return m


def test_a_new_machine_is_unconnected_with_nothing_commanded():
    m = SimMachine()
    assert m.state is MachineState.UNCONNECTED and m.fault_reason is None
    assert m.last_command == 0.0 and m.max_torque == 0.0 and m.cues is None
    assert m.keepalive() is None  # callable before a worker sets its own
    assert (Machine.kind, Machine.has_torque_sensor, Machine.free_running) == (
        "machine",
        False,
        False,
    )
    cues = object()
    m.follow(cues)
    assert m.cues is cues


def test_each_state_refuses_what_it_cannot_do_naming_it():
    m = SimMachine()
    for op, call in (("read", m.read), ("activate", m.activate)):
        with pytest.raises(MachineError, match=rf"^cannot {op} in state UNCONNECTED$"):
            call()
    with pytest.raises(MachineError, match=r"^cannot write in state UNCONNECTED$"):
        m.write(0.0)
    m.connect()
    with pytest.raises(MachineError, match=r"^cannot connect in state CONNECTED$"):
        m.connect()
    with pytest.raises(MachineError, match=r"^cannot activate in state CONNECTED$"):
        m.activate()
    m.disarm()  # nothing armed: nothing to do
    m.reset()  # nothing latched: nothing to do
    assert m.state is MachineState.CONNECTED
    m.arm(cfg_())
    with pytest.raises(MachineError, match=r"^cannot arm in state ARMED$"):
        m.arm(cfg_())
    with pytest.raises(MachineError, match=r"^cannot write in state ARMED$"):
        m.write(1.0)
    m.activate()
    m.write(1.0)
    m.disarm()
    assert m.state is MachineState.DISARMED and m.last_command == 0.0
    with pytest.raises(MachineError, match=r"^cannot read in state DISARMED$"):
        m.read()
    m.close()
    m.close()  # twice: nothing more
    assert m.state is MachineState.CLOSED
    with pytest.raises(MachineError, match=r"^cannot connect in state CLOSED$"):
        m.connect()


def test_arming_takes_the_sessions_limit_and_starts_from_zero_torque():
    m = active(max_torque=4.0)
    assert m.max_torque == 4.0
    for u, applied in ((9.0, 4.0), (-9.0, -4.0), (4.0, 4.0), (-3.5, -3.5), (0.25, 0.25)):
        m.read()
        m.write(u)
        assert m.last_command == applied
    m.disarm()
    m.arm(cfg_(max_torque=2.0))
    assert m.max_torque == 2.0 and m.last_command == 0.0 and m.state is MachineState.ARMED


@pytest.mark.parametrize(
    ("op", "exc", "reason"),
    [
        ("read", ValueError("garbage on the line"), "read failed: garbage on the line"),
        ("read", MachineError("drive error 0x40"), "drive error 0x40"),
        ("write", OSError("port gone"), "write failed: port gone"),
        ("write", MachineError("watchdog"), "watchdog"),
    ],
)
def test_a_failing_read_or_write_latches_a_fault_with_zero_torque(op, exc, reason):
    m = active()
    m.read()
    m.write(3.0)
    zeros = m.zeros
    m.fail[op] = exc
    with pytest.raises(MachineError) as got:
        m.read() if op == "read" else m.write(2.0)
    assert str(got.value) == reason
    assert m.state is MachineState.FAULT and m.fault_reason == reason
    assert m.last_command == 0.0 and m.zeros == zeros + 1
    with pytest.raises(MachineError, match=r"^cannot read in state FAULT$"):
        m.read()
    with pytest.raises(
        MachineError, match=rf"^cannot arm: latched fault \({reason}\); reset first$"
    ):
        m.arm(cfg_())
    del m.fail[op]
    m.reset()
    assert m.state is MachineState.CONNECTED and m.fault_reason is None
    m.arm(cfg_())  # and it runs again
    m.activate()
    m.read()
    m.write(1.0)


@pytest.mark.parametrize("op", ["connect", "arm"])
@pytest.mark.parametrize(
    ("exc", "reason"),
    [
        (OSError("no such device"), "OSError: no such device"),
        (MachineError("firmware 0.5.2 refused"), "firmware 0.5.2 refused"),
    ],
)
def test_a_failing_connect_or_arm_latches_too(op, exc, reason):
    m = FailingSim()
    m.fail[op] = exc
    if op == "arm":
        m.connect()
    with pytest.raises(MachineError) as got:
        m.connect() if op == "connect" else m.arm(cfg_())
    assert str(got.value) == reason
    assert m.state is MachineState.FAULT and m.fault_reason == reason
    assert m.zeros == 1


def test_a_command_at_or_beyond_1e300_is_a_fault_not_a_clamped_torque():
    for u in (1e300, -1e300):
        m = active()
        with pytest.raises(MachineError, match="non-finite torque command"):
            m.write(u)
        assert m.state is MachineState.FAULT and m.last_command == 0.0
    m = active()
    m.write(9.9e299)  # finite, absurd: clamped like any other
    assert m.last_command == 10.0


def test_the_simulator_has_the_sensor_controller_a_needs():
    m = SimMachine()
    m.connect()
    m.arm(parse_session_config({"duration": 1.0, "controller": {"kind": "measured"}}))
    assert m.state is MachineState.ARMED


def test_close_disarms_an_armed_machine_only():
    m = active()
    m.close()
    assert m.disarms == 1 and m.state is MachineState.CLOSED
    m = FailingSim()
    m.connect()
    m.close()
    assert m.disarms == 0 and m.state is MachineState.CLOSED


def test_the_first_reason_of_a_fault_is_kept_and_a_failed_reset_keeps_it_latched():
    m = active()
    m.fail["read"] = ValueError("first")
    with pytest.raises(MachineError):
        m.read()
    m.fail["reset"] = MachineError("still faulted")
    with pytest.raises(MachineError, match=r"^still faulted$"):
        m.reset()
    assert m.state is MachineState.FAULT and m.fault_reason == "read failed: first"


def test_zero_and_close_never_fail_half_way():
    m = active()
    m.read()
    m.write(3.0)
    m.fail["zero"] = OSError("port gone")
    m.zero()  # never raises: the safe path
    assert m.last_command == 0.0
    m.fail["disarm"] = OSError("port gone")
    m.close()  # a disarm that fails does not stop the close
    assert m.state is MachineState.CLOSED
    m = active()
    m.fail["close"] = OSError("port gone")
    with pytest.raises(OSError):
        m.close()
    assert m.state is MachineState.CLOSED  # closed all the same
    m = active()
    m.fail["disarm"] = RuntimeError("refused")
    with pytest.raises(MachineError, match=r"^RuntimeError: refused$"):
        m.disarm()
    assert m.state is MachineState.FAULT and m.last_command == 0.0
