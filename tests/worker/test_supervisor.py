"""The supervisor's decisions, in-process, period by period: the same read → step → check →
write order as the worker's cycle (:mod:`sessions.worker.cycle`), on the real loop and the
real simulated machine, with the worker process replaced by a host that keeps what it is told.

Independent truths: the loop's own flags and figures at the period a decision fell (the
velocity, the work W, the torque clamp), the summary :func:`sessions.summary.summarize` gives
for the same loop, and the period count of the session's duration. The worker's tests
(test_safety, test_session) check the same decisions through the process and its ring.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sessions.codes import (
    FLAG_ESTOP,
    FLAG_PASSIVITY,
    STATE_ESTOPPED,
    STATE_FAULTED,
    TORQUE_LIMIT,
    VELOCITY_LIMIT,
)
from sessions.config import SessionConfig, parse_session_config
from sessions.loop import Loop
from sessions.machine.sim import SimMachine
from sessions.summary import summarize
from sessions.worker.messages import (
    EStop,
    EStopped,
    Faulted,
    LimitHit,
    Rejected,
    Reset,
    Shutdown,
    StartSession,
    Stop,
    Stopping,
)
from sessions.worker.supervisor import End, Supervisor
from testing.live import OVERSPEED, PASSIVITY_BREACH, STRONG, scenario

RAMP = 0.5  # s: the stop ramp's duration (WorkerOptions' default)
CLOCK = 1000.0  # the host's monotonic clock at session time 0


@dataclass
class Host:
    """The worker process as the supervisor sees it (:class:`sessions.worker.supervisor.Host`)."""

    machine: SimMachine
    terminated: bool = False
    shutdown: bool = False
    exit_reason: str = ""
    events: list[object] = field(default_factory=list)
    stopping: int = 0  # times the worker was told it is stopping

    def emit(self, ev: object) -> None:
        self.events.append(ev)

    def enter_stopping(self) -> None:
        self.stopping += 1

    def of(self, cls: type) -> list:  # type: ignore[type-arg]
        return [e for e in self.events if isinstance(e, cls)]


def session(cfg: SessionConfig) -> tuple[Host, Supervisor]:
    m = SimMachine()
    loop = Loop(cfg)
    m.connect()
    m.follow(loop.reference)
    m.arm(cfg)
    m.activate()
    loop.attach_truth(m.truth())
    loop.begin(0.0, 0.0)
    host = Host(m)
    return host, Supervisor(host, loop, "s", round(cfg.duration * cfg.rate), RAMP)


@dataclass
class Run:
    u: list[float] = field(default_factory=list)
    w: list[float] = field(default_factory=list)
    loop_flags: list[int] = field(default_factory=list)
    added: list[int] = field(default_factory=list)  # what check() returned
    told_k: int | None = None  # the loop's period count when the first Stopping was emitted


def run(host: Host, sup: Supervisor, max_steps: int = 20_000) -> Run:
    """Periods until the controlled stop begins (the ramp exists), as the cycle runs them."""
    m, loop, out = host.machine, sup.loop, Run()
    for _ in range(max_steps):
        q, w, tau = m.read()
        u = loop.step(q, w, tau)
        out.added.append(sup.check(u, w, CLOCK + loop.elapsed))
        out.u.append(u)
        out.w.append(w)
        out.loop_flags.append(loop.flags)
        m.write(u)
        if out.told_k is None and host.of(Stopping):
            out.told_k = loop.k
        if sup.ramp is not None:
            return out
    raise AssertionError("no stop began")


def test_the_duration_winds_down_to_rest_then_ramps_the_torque_out():
    cfg = scenario(duration=1.0)
    host, sup = session(cfg)
    got = run(host, sup)
    loop = sup.loop
    n = round(cfg.duration * cfg.rate)
    assert got.told_k == n < len(got.u)  # wound down from the last period on; part of it
    stops = host.of(Stopping)
    assert [(e.session_id, e.reason) for e in stops] == [("s", "duration reached")]  # said once
    assert host.stopping == 2  # the wind-down, then the ramp
    assert sup.ending == End("completed", "duration reached")
    assert sup.stop_end == End("completed", "duration reached")
    assert sup.summary == summarize(loop) and sup.summary.abort_reason is None
    ramp = sup.ramp
    assert ramp is not None and ramp.u0 == got.u[-1] and ramp.steps == round(RAMP / loop.dt)
    assert set(got.added) == {0}
    assert isinstance(stops[0].t, float) and sup.ramp.limits is loop.limits  # type: ignore[union-attr]
    sup.begin_stop("aborted", "later")  # once begun, a stop is not begun again
    assert sup.ramp is ramp and sup.stop_end == End("completed", "duration reached")


def test_a_protocol_that_ends_by_itself_completes():
    # warm-up and cool-down: the protocol brings the handle to rest before the duration
    cfg = parse_session_config(
        {
            "user": {"noise": 0.0},
            "protocol": {
                "phases": [{"kind": "warmup", "duration": 2, "ramp": 1}, {"kind": "cooldown"}]
            },
        }
    )
    host, sup = session(cfg)
    got = run(host, sup, 200_000)
    assert len(got.u) < round(cfg.duration * cfg.rate)
    assert sup.ending is None  # no wind-down was asked: the protocol's own end
    assert sup.stop_end == End("completed", "protocol finished")
    assert [e.reason for e in host.of(Stopping)] == ["protocol finished"]
    assert sup.summary == summarize(sup.loop) and sup.summary.abort_reason is None


def test_a_stop_begun_without_a_torque_ramps_from_the_last_command():
    host, sup = session(scenario(duration=5.0))
    for _ in range(300):
        q, w, tau = host.machine.read()
        host.machine.write(sup.loop.step(q, w, tau))
    last = host.machine.last_command
    assert last != 0.0
    sup.begin_stop("stopped", "asked")
    assert sup.ramp is not None and sup.ramp.u0 == last
    assert [(e.session_id, e.reason) for e in host.of(Stopping)] == [("s", "asked")]
    assert sup.summary == summarize(sup.loop, "asked") and sup.stop_end == End("stopped", "asked")


def test_velocity_over_the_limit_aborts_with_a_controlled_stop():
    cfg = scenario(**OVERSPEED)
    host, sup = session(cfg)
    got = run(host, sup)
    w = got.w[-1]
    assert abs(w) > 4.0 and all(abs(x) <= 4.0 for x in got.w[:-1])  # the first period over
    hit = host.of(LimitHit)
    assert [(e.limit, e.value, e.session_id) for e in hit] == [("velocity", abs(w), "s")]
    assert hit[0].session_t == sup.loop.row[0] and hit[0].t == CLOCK + sup.loop.elapsed
    reason = f"velocity over the limit: |w| = {abs(w):.2f} > 4 rad/s"
    assert [e.reason for e in host.of(Stopping)] == [reason]
    assert sup.stop_end == End("aborted", reason) and sup.summary.abort_reason == reason
    assert sup.ending is None and host.stopping == 1
    assert isinstance(host.of(Stopping)[0].t, float)
    assert sup.ramp is not None and sup.ramp.u0 == got.u[-1]  # from this period's torque


def test_a_torque_limit_is_an_event_each_time_the_clamp_begins():
    cfg = scenario(**STRONG)
    host, sup = session(cfg)
    got = run(host, sup)
    clamped = (np.array(got.loop_flags) & TORQUE_LIMIT) != 0
    rises = int(clamped[0]) + int(np.count_nonzero(np.diff(clamped.astype(int)) == 1))
    torque = [e for e in host.of(LimitHit) if e.limit == "torque"]
    assert clamped[0] and len(torque) == rises
    first = torque[0]
    assert first.value == abs(got.u[0]) == 20.0 and first.session_t == 0.0  # the period it began
    assert first.t == CLOCK + 0.001 and first.session_id == "s"


def test_a_limit_event_is_said_when_its_limit_begins_whatever_the_others_do():
    host, sup = session(scenario(duration=5.0))
    # the loop's flags over five periods: torque, torque+velocity, velocity, both, neither
    for k, lf in enumerate((TORQUE_LIMIT, TORQUE_LIMIT | VELOCITY_LIMIT, VELOCITY_LIMIT, 3, 0)):
        sup._limit_events(lf, 20.0 + k, 5.0 + k, CLOCK + k)
    assert [(e.t, e.limit, e.value) for e in host.of(LimitHit)] == [
        (CLOCK, "torque", 20.0),
        (CLOCK + 1, "velocity", 6.0),
        (CLOCK + 3, "torque", 23.0),
    ]
    assert sup.prev_flags == 0


def test_a_passivity_breach_aborts_at_its_period_and_flags_it():
    cfg = scenario(**PASSIVITY_BREACH)
    host, sup = session(cfg)
    got = run(host, sup)
    work = sup.loop.passivity.work
    assert work < -1e-3 and got.added[-1] == FLAG_PASSIVITY and set(got.added[:-1]) == {0}
    hit = [e for e in host.of(LimitHit) if e.limit == "passivity"]
    assert [(e.value, e.session_id, e.session_t) for e in hit] == [(work, "s", sup.loop.row[0])]
    reason = f"passivity breached: W = {work:.3g} J < -c² = -0.001 J"
    assert [e.reason for e in host.of(Stopping)] == [reason]
    assert hit[0].t == CLOCK + sup.loop.elapsed
    assert sup.ramp is not None and sup.ramp.u0 == got.u[-1]  # from this period's torque
    assert sup.stop_end == End("aborted", reason) and sup.summary.abort_reason == reason


def test_a_fault_or_a_loop_error_ends_the_session_saying_why():
    host, sup = session(scenario(duration=5.0))
    assert sup.fault("drive error", 7.0) == End("faulted", "drive error", STATE_FAULTED)
    assert host.events == [Faulted(7.0, "s", "drive error")]
    assert sup.summary.abort_reason == "drive error"

    host, sup = session(scenario(duration=5.0))
    assert sup.loop_error("non-finite u = nan", False, 8.0) == End("aborted", "non-finite u = nan")
    assert host.events == [] and sup.summary.abort_reason == "non-finite u = nan"
    host, sup = session(scenario(duration=5.0))
    end = sup.loop_error("non-finite measured w = nan", True, 9.0)
    assert end == End("faulted", "non-finite measured w = nan", STATE_FAULTED)
    assert host.events == [Faulted(9.0, "s", "non-finite measured w = nan")]


def test_upstream_ends_the_session_only_when_the_worker_was_told_to_go():
    host, sup = session(scenario(duration=5.0))
    host.machine.write(3.0)
    assert sup.upstream() is None and host.machine.last_command == 3.0
    host.terminated = True
    assert sup.upstream() == End("aborted", "terminated (SIGTERM)")
    assert host.machine.last_command == 0.0 and host.exit_reason == "terminated (SIGTERM)"
    host, sup = session(scenario(duration=5.0))
    host.machine.write(3.0)
    host.terminated, host.exit_reason = True, "parent died"
    assert sup.upstream() == End("aborted", "parent died") and host.machine.last_command == 0.0
    assert host.exit_reason == "parent died"


def test_each_command_during_a_session():
    host, sup = session(scenario(duration=5.0))
    host.machine.write(3.0)
    end, flags = sup.command(EStop(), 1.0)
    assert (end, flags) == (End("stopped", "e-stop", STATE_ESTOPPED), FLAG_ESTOP)
    (ev,) = host.events
    assert isinstance(ev, EStopped) and ev.session_id == "s" and ev.t == ev.zero_at > 0
    assert host.machine.last_command == 0.0

    host, sup = session(scenario(duration=5.0))
    assert sup.command(Stop(), 2.0) == (None, 0)  # winds down to rest first
    assert [e.reason for e in host.of(Stopping)] == ["stopped by the operator"]
    assert sup.ending == End("stopped", "stopped by the operator") and host.stopping == 1
    host.machine.write(3.0)
    assert sup.command(Stop(), 2.5) == (End("stopped", "stopped at once by the operator"), 0)
    assert host.machine.last_command == 0.0  # a second stop: at once
    host, sup = session(scenario(duration=5.0))
    assert sup.command(Stop(reason="the trainer's"), 2.0) == (None, 0)
    assert sup.ending == End("stopped", "the trainer's")
    host, sup = session(scenario(duration=5.0))
    host.machine.write(3.0)
    assert sup.command(Stop(immediate=True, reason="now"), 2.0) == (End("stopped", "now"), 0)
    assert host.machine.last_command == 0.0 and host.events == []

    host, sup = session(scenario(duration=5.0))
    host.machine.write(3.0)
    assert sup.command(Shutdown(), 3.0) == (End("stopped", "worker shut down"), 0)
    assert host.shutdown and host.exit_reason == "shutdown" and host.machine.last_command == 0.0

    host, sup = session(scenario(duration=5.0))
    assert sup.command(StartSession(scenario(), "other"), 4.0) == (None, 0)
    assert sup.command(Reset(), 5.0) == (None, 0)
    assert host.events == [
        Rejected(4.0, "start", "a session is running"),
        Rejected(5.0, "reset", "a session is running; stop it first"),
    ]
    assert sup.command(object(), 6.0) == (None, 0) and len(host.events) == 2  # unknown: ignored
