"""A non-finite value anywhere in the loop ends the session with zero torque and says which
value it was; it never reaches a torque command, a target or the summary.

The NaN comes through the real data path: the simulator's fault injection makes its sensors
read NaN (angle, velocity, torque) or a finite torque so large (1e308 N·m) that the loop's
own products overflow (power, work). Truth: the ring's record of every period (the torque
actually written, the flags) and the fault's known start (session time 1 s = period 1000).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sessions.codes import FLAG_FAULT
from sessions.loop import Loop
from sessions.machine import MachineSpec, SimFault
from sessions.machine.sim import SimMachine
from sessions.worker import Worker
from sessions.worker.ring import INDEX
from sessions.worker.supervisor import Supervisor
from testing.live import follow, scenario, worker_options

AT = 3.0  # s: the fault's start (after all of the next session: 0.2 s, then its wind-down)


def _run(kind: str, **cfg: object):
    spec = MachineSpec(kind="sim", sim_fault=SimFault(kind=kind, at=AT))
    with Worker(spec, worker_options()) as worker:
        worker.start()
        reader = worker.open_reader()
        worker.start_session(scenario(duration=30.0, **cfg), kind)
        got = follow(worker, reader, timeout=20)
        reader.close()
        after = worker.status().state
        # the worker is alive and well: after a reset (if latched) it runs the next session
        if after == "faulted":
            worker.reset()
            follow(worker, until="reset")
        worker.start_session(scenario(duration=0.2), "next")
        nxt = follow(worker, timeout=20).end
    return got, after, nxt


@pytest.mark.parametrize(
    ("kind", "controller", "what"),
    [
        ("nan-angle", "rise", "angle q = nan"),
        ("nan-velocity", "rise", "velocity w = nan"),
        ("nan-torque", "measured", "torque τ = nan"),
    ],
)
def test_a_nan_measurement_is_a_latched_fault_with_zero_torque(kind, controller, what):
    got, after, nxt = _run(kind, controller={"kind": controller})
    end = got.end
    assert end is not None and end.status == "faulted"
    assert end.reason == f"non-finite measured {what}", end.reason
    faults = got.of("fault")  # the fault event: whose session, why, when
    assert [(f.session_id, f.reason) for f in faults] == [(kind, end.reason)]
    assert faults[0].t <= end.t
    assert after == "faulted" and end.state_after == "faulted"
    d = got.data
    assert len(d) == int(AT * 1000) + 1  # every period before the fault, then the zero record
    last = d[-1]
    assert last[INDEX["u_out"]] == 0.0 and int(last[INDEX["flags"]]) & FLAG_FAULT
    # the NaN never entered the loop: every record before it is finite, torque and target too
    engine = ["t", "q", "w", "wd", "ad", "u", "tau", "p", "W", "gamma", "u_out"]
    assert np.isfinite(d[:-1][:, [INDEX[c] for c in engine]]).all()
    assert math.isfinite(end.summary.mean_power) and end.summary.duration == pytest.approx(AT)
    assert end.summary.abort_reason == end.reason  # the summary says why it ended
    assert nxt is not None and nxt.status == "completed"


def test_an_overflow_inside_the_loop_aborts_the_session_with_zero_torque():
    # controller A feeds the measured 1e308 N·m through: τ·wd^ρ overflows to inf
    got, after, nxt = _run("huge-torque", controller={"kind": "measured"})
    end = got.end
    assert end is not None and end.status == "aborted"
    assert end.reason.startswith("non-finite "), end.reason
    assert "= inf" in end.reason or "= nan" in end.reason or "= -inf" in end.reason
    assert after == "idle" and end.state_after == "idle"  # the machine is fine: nothing latched
    d = got.data
    u_out = d[:, INDEX["u_out"]]
    assert np.isfinite(u_out).all()  # never a non-finite command
    assert u_out[-1] == 0.0 and int(d[-1, INDEX["flags"]]) & FLAG_FAULT
    assert np.isfinite(d[:-2][:, INDEX["gamma"]]).all()  # no target went non-finite
    assert len(d) <= int(AT * 1000) + 2  # it ended on the period the overflow appeared
    for field in ("mean_power", "peak_power", "work", "duration", "passivity_min"):
        assert math.isfinite(getattr(end.summary, field)), field
    assert end.summary.abort_reason == end.reason  # the summary says why it ended
    assert not end.summary.converged
    assert nxt is not None and nxt.status == "completed"


def test_a_summary_with_a_non_finite_figure_keeps_what_is_finite():
    # The loop's own checks stop a non-finite value before it reaches a figure; if one got
    # there all the same (a broken integral), the session still gets a summary: the finite
    # figures as they are, the others 0, the reason kept, frozen once.
    cfg = scenario(duration=5.0)
    m, loop = SimMachine(), Loop(cfg)
    m.connect()
    m.follow(loop.reference)
    m.arm(cfg)
    m.activate()
    loop.begin(0.0, 0.0)
    for _ in range(2500):  # to the seeker's first measurements
        q, w, tau = m.read()
        m.write(loop.step(q, w, tau))
    loop.passivity.work = math.inf
    sup = Supervisor(None, loop, "s", 5000, 0.5)  # type: ignore[arg-type]  # freeze: no host
    summary = sup.freeze("aborted", "why it ended")
    assert summary.abort_reason == "why it ended" and not summary.converged
    assert summary.work == 0.0 and summary.duration == loop.elapsed == pytest.approx(2.5)
    assert summary.evaluations == len(loop.seeker.evaluations) > 0
    assert summary.mean_power == loop.mean_power > 0 and summary.seeker == loop.seeker.kind
    assert sup.freeze("completed", "another") is summary  # frozen once
    done = Supervisor(None, loop, "s", 5000, 0.5).freeze("completed", "duration reached")  # type: ignore[arg-type]
    assert done.abort_reason is None and done.work == 0.0


@pytest.mark.parametrize(
    ("figures", "kept"),
    [
        # (power_sum, peak_power, work, minimum) -> (mean_power, peak_power, work, passivity_min)
        ((math.inf, math.nan, -0.1, -0.25), (0.0, 0.0, -0.1, -0.25)),
        ((None, None, -0.1, -math.inf), (None, None, -0.1, 0.0)),
        ((None, None, math.nan, math.nan), (None, None, 0.0, 0.0)),
    ],
)
def test_the_fallback_summary_keeps_each_finite_figure_and_zeroes_the_others(figures, kept):
    loop = Loop(scenario(duration=5.0))
    loop.begin(0.0, 0.0)
    for k in range(300):
        loop.step(0.003 * k, 3.0, 2.0)
    before = (loop.mean_power, loop.peak_power)
    power_sum, peak, work, minimum = figures
    if power_sum is not None:
        loop.power_sum, loop.peak_power = power_sum, peak
    loop.passivity.work, loop.passivity.minimum = work, minimum
    s = Supervisor(None, loop, "s", 5000, 0.5).freeze("aborted", "why")  # type: ignore[arg-type]
    want = tuple(b if k is None else k for b, k in zip((*before, 0, 0), kept, strict=True))
    assert (s.mean_power, s.peak_power, s.work, s.passivity_min) == want
