"""The machine lifecycle and the simulated machine.

Independent truths: the engine's own :func:`run_simulation` (the sim backend driven through
read → step → write must be the same computation, bit for bit), and the plant's equation (1)
integrated by hand for the torque clamp.
"""

from __future__ import annotations

import math
import signal
import subprocess
import sys

import numpy as np
import pytest

from sessions.config import parse_session_config
from sessions.loop import Loop
from sessions.machine import MachineError, MachineSpec, MachineState, make_machine
from sessions.machine.sim import HUGE_TORQUE, SimMachine
from sessions.machine.spec import SimFault
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.protocol.cues import CuedPerson
from sessions.simulation import run_simulation


def cfg_(**over):
    return parse_session_config({"duration": 2.0, "user": {"noise": 0.03, "ripple": 0.1}, **over})


def test_lifecycle_order_is_enforced():
    m = SimMachine()
    with pytest.raises(MachineError, match="cannot arm in state UNCONNECTED"):
        m.arm(cfg_())
    m.connect()
    assert m.state is MachineState.CONNECTED
    with pytest.raises(MachineError, match="cannot write"):
        m.write(0.0)
    m.arm(cfg_())
    assert m.state is MachineState.ARMED
    m.read()  # reading an armed machine is allowed: the loop starts from its state
    with pytest.raises(MachineError, match="cannot write"):
        m.write(0.0)
    m.activate()
    m.write(0.0)
    m.disarm()
    assert m.state is MachineState.DISARMED
    m.arm(cfg_())  # a disarmed machine can be armed for the next session
    m.close()
    assert m.state is MachineState.CLOSED
    with pytest.raises(MachineError):
        m.read()


def test_sim_backend_is_the_simulation_step_for_step():
    cfg = cfg_()
    ref = run_simulation(cfg)
    m = make_machine(MachineSpec(kind="sim"))
    m.connect()
    m.arm(cfg)
    loop = Loop(cfg)
    q0, w0, _ = m.read()
    loop.begin(q0, w0)
    m.activate()
    rows = []
    for _ in range(round(cfg.duration * cfg.rate)):
        q, w, tau = m.read()
        m.write(loop.step(q, w, tau))
        rows.append(loop.row)
    np.testing.assert_array_equal(np.array(rows), ref.telemetry)


def test_torque_is_clamped_by_the_machine_itself():
    cfg = cfg_(machine={"max_torque": 2.0}, user={"kind": "linear", "tau0": 1.0, "wmax": 5.0})
    m = SimMachine()
    m.connect()
    m.arm(cfg)
    m.activate()
    plant = Plant(cfg.machine.inertia)
    user = SimulatedUser(cfg.user, cfg.dt, cfg.seed)
    for u in (50.0, -50.0, 1.5):
        m.read()
        m.write(u)
        plant.sample_torque(user)
        plant.advance(max(-2.0, min(2.0, u)), cfg.dt, user)
        user.advance(cfg.dt)
        assert m.last_command == max(-2.0, min(2.0, u))
    assert m.plant is not None
    assert m.plant.w == plant.w and m.plant.q == plant.q


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_command_is_a_latched_fault(bad):
    m = SimMachine()
    m.connect()
    m.arm(cfg_())
    m.activate()
    with pytest.raises(MachineError, match="non-finite"):
        m.write(bad)
    assert m.state is MachineState.FAULT
    assert m.last_command == 0.0
    with pytest.raises(MachineError, match="latched fault"):
        m.arm(cfg_())
    m.reset()
    assert m.state is MachineState.CONNECTED and m.fault_reason is None
    m.arm(cfg_())


def test_measured_controller_needs_a_torque_sensor():
    cfg = cfg_(controller={"kind": "measured"})
    assert MachineSpec(kind="sim").has_torque_sensor
    spec = MachineSpec(kind="odrive", device="/dev/null", torque_constant=0.1)
    assert not spec.has_torque_sensor
    m = make_machine(spec)
    m.state = MachineState.CONNECTED  # arming is refused before any I/O
    with pytest.raises(ValueError, match=r"^the odrive machine has no torque sensor"):
        m.arm(cfg)


def test_machine_spec_validation():
    with pytest.raises(ValueError, match="device"):
        MachineSpec(kind="odrive")
    with pytest.raises(ValueError, match="watchdog_timeout must exceed"):
        MachineSpec(
            kind="odrive",
            device="/dev/x",
            torque_constant=0.1,
            watchdog_timeout=0.01,
            reply_timeout=0.02,
        )
    with pytest.raises(ValueError):
        MachineSpec(kind="odrive", device="/dev/x", torque_constant=0.1, direction=2)


def _readings(m: SimMachine, cfg, n: int) -> list[tuple[float, float, float]]:  # type: ignore[no-untyped-def]
    m.connect()
    m.arm(cfg)
    m.activate()
    out = []
    for _ in range(n):
        out.append(m.read())
        m.write(0.5)
    return out


@pytest.mark.parametrize(
    ("kind", "bad"),
    [("nan-angle", 0), ("nan-velocity", 1), ("nan-torque", 2), ("huge-torque", 2)],
)
def test_an_injected_fault_starts_at_its_period_and_spoils_only_its_reading(kind, bad):
    # independent truth: the same simulator without the fault, period by period
    cfg = cfg_()
    clean = _readings(SimMachine(), cfg, 600)
    m = SimMachine(SimFault(kind=kind, at=0.25))
    got = _readings(m, cfg, 600)
    at = round(0.25 / cfg.dt)
    assert got[:at] == clean[:at]  # nothing before its start
    for k in range(at, 600):
        for i in range(3):
            if i != bad:
                assert got[k][i] == clean[k][i]  # the other readings are the plant's own
        if kind == "huge-torque":
            assert got[k][bad] == HUGE_TORQUE
        else:
            assert math.isnan(got[k][bad])
    assert m.steps == 600 and m.dt == cfg.dt and m.fault_step == at
    m.disarm()
    m.arm(cfg)  # the next session starts clean and faults at the same session time
    assert m.steps == 0 and m.fault_step == at and m.read() == clean[0]


def test_an_injected_exit_ends_the_caller_at_its_period_with_its_reason():
    cfg = cfg_()
    m = SimMachine(SimFault(kind="worker-exit", at=0.01))
    m.connect()
    m.arm(cfg)
    m.activate()
    for _ in range(10):
        m.read()
        m.write(0.0)
    with pytest.raises(SystemExit, match=r"^injected fault worker-exit at t = 0.01 s$"):
        m.read()


ABORT_AT = """
from sessions.config import parse_session_config
from sessions.machine.sim import SimMachine
from sessions.machine.spec import SimFault

cfg = parse_session_config({"duration": 1.0})
m = SimMachine(SimFault(kind="worker-abort", at=%r))
m.connect()
m.arm(cfg)
m.activate()
for k in range(30):
    print(k, flush=True)
    m.read()
    m.write(0.0)
"""


@pytest.mark.parametrize(("at", "period"), [(0.0, 0), (0.01, 10)])
def test_an_injected_abort_kills_the_process_at_its_period(at, period):
    # the process dies of SIGABRT in its read of the fault's period (1 kHz: t = at), with no
    # word and no exception (a child: it would take pytest with it)
    done = subprocess.run(
        [sys.executable, "-c", ABORT_AT % at],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == -signal.SIGABRT, done.stderr
    assert done.stdout.split() == [str(k) for k in range(period + 1)]
    assert "Traceback" not in done.stderr


def test_a_new_simulator_has_no_session_and_the_person_follows_the_cues():
    m = SimMachine()
    assert (m.plant, m.user, m.dt, m.fault, m.steps, m.fault_step) == (None, None, 0.0, None, 0, -1)
    assert m.truth() is None
    cfg = cfg_()
    loop = Loop(cfg)
    m.follow(loop.reference)
    m.connect()
    m.arm(cfg)
    assert isinstance(m.user, CuedPerson) and m.truth() is m.user
    assert m.plant is not None and cfg.machine.inertia == m.plant.inertia
    m.close()
    assert m.plant is None and m.user is None
    plain = SimMachine()
    plain.connect()
    plain.arm(cfg)
    assert isinstance(plain.user, SimulatedUser)
    assert plain.fault_step == -1  # armed without a fault: none (-1), as before
