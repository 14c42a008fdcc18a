"""Sessions in the real-time worker process, through the parent's handle.

Independent truth: the engine's offline simulation. The sim backend advances the plant one
period per cycle, so a live session is the same computation as ``run_simulation`` with the
same config, whatever the scheduling: the ring must hold exactly its telemetry, the events
exactly its evaluations, the summary exactly what ``summarize`` gives for the same loop.
"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from sessions.codes import FLAG_STOPPING, TORQUE_LIMIT
from sessions.config import ScenarioError
from sessions.loop import Loop
from sessions.machine import MachineSpec
from sessions.machine.sim import SimMachine
from sessions.protocol.config import REST_VELOCITY, STOP_DECELERATION
from sessions.simulation import run_simulation
from sessions.summary import summarize
from sessions.worker import COLUMNS, Worker, WorkerError, WorkerOptions
from sessions.worker.ring import INDEX
from testing.live import follow, scenario

NCH = 10  # the engine's telemetry channels come first in a ring record


def offline_summary(cfg):
    """The worker's session offline: the duration, then the wind-down to rest."""
    m = SimMachine()
    loop = Loop(cfg)
    m.connect()
    m.follow(loop.reference)
    m.arm(cfg)
    m.activate()
    loop.attach_truth(m.truth())  # as the worker: the simulated person scores the regret
    loop.begin(0.0, 0.0)
    n = round(cfg.duration * cfg.rate)
    while not loop.finished:
        q, w, tau = m.read()
        m.write(loop.step(q, w, tau))
        if loop.k == n:
            loop.wind_down()
    return summarize(loop)


def test_live_session_is_the_offline_simulation(worker):
    cfg = scenario(duration=4.0, user={"kind": "hill", "noise": 0.03, "ripple": 0.1})
    ref = run_simulation(cfg)
    reader = worker.open_reader()
    worker.start_session(cfg, "equal")
    got = follow(worker, reader)
    reader.close()
    end = got.end
    assert end is not None and end.status == "completed" and end.reason == "duration reached"
    assert got.missed == 0
    assert got.kinds()[0] == "session_started"
    started = got.of("session_started")[0]
    assert got.seq[0] == started.first_seq and got.seq[-1] == end.last_seq
    assert np.all(np.diff(got.seq) == 1)
    n = len(ref.telemetry)
    run = got.data[:n]
    np.testing.assert_array_equal(run[:, :NCH], ref.telemetry)
    assert np.all(run[:, INDEX["phase"]] >= 0)
    np.testing.assert_array_equal(run[:, INDEX["u_out"]], ref.column("u"))
    evs = [(e.session_t, e.candidate, e.power) for e in got.of("evaluation")]
    assert evs == [(e.t, e.candidate, e.power) for e in ref.evaluations]
    assert end.summary == offline_summary(cfg)
    assert end.timing.cycles == len(got.seq) and end.timing.rate_hz == 1000.0
    assert worker.status().state == "idle" and worker.status().session_id is None


def test_the_end_brings_the_handle_to_rest_then_ramps_torque_out_and_never_drives(worker):
    # At the duration the handle turns at ~3 rad/s: the reference winds down to rest under
    # control (never faster than the stop's deceleration), the person is asked to relax, and
    # only once the handle is still is the torque ramped out, resisting only.
    cfg = scenario(duration=3.0)
    reader = worker.open_reader()
    worker.start_session(cfg, "ramp")
    got = follow(worker, reader)
    reader.close()
    d = got.data
    t, w, phase = d[:, INDEX["t"]], d[:, INDEX["w"]], d[:, INDEX["phase"]]
    n = round(cfg.duration * cfg.rate)
    assert w[n - 1] > 2.0  # moving when the duration was reached
    # the wind-down, under the loop's control: period n still ran on the reference computed
    # before the duration was found reached; the stop's reference drives from n + 1 on
    wind = d[n + 1 :][phase[n + 1 :] >= 0]
    stop = d[phase < 0]  # the torque ramp
    assert len(wind) > 0 and np.all(wind[:, INDEX["stage"]] == 1)  # the closing stop phase
    assert np.all(np.diff(wind[:, INDEX["wd"]]) <= 1e-12)  # the reference only slows
    assert np.all(wind[:, INDEX["ad"]] >= -STOP_DECELERATION * (1 + 1e-6))
    assert np.all(np.abs(stop[:, INDEX["w"]]) < REST_VELOCITY)  # at rest when torque goes
    opts = WorkerOptions()
    assert len(stop) == pytest.approx(opts.stop_ramp * cfg.rate, abs=2)
    assert np.all(stop[:, INDEX["flags"]].astype(int) & FLAG_STOPPING)
    u = stop[:, INDEX["u_out"]]
    assert np.all(u * stop[:, INDEX["w"]] <= 0.0)  # the motor only resists during a stop
    assert np.abs(u).max() < 0.05 * np.abs(d[n - 1, INDEX["u"]])  # the relaxed person's torque
    assert u[-1] == 0.0
    assert got.of("stopping")[0].reason == "duration reached"
    stages = got.of("stage")
    assert [(s.stage.kind, s.stage.role) for s in stages] == [
        ("seek", "seek"),
        ("stop", "stop"),
        ("stop", "relax"),
    ]
    assert stages[1].stage.start == pytest.approx(cfg.duration + 1 / cfg.rate)  # period n + 1
    assert got.end is not None and got.end.status == "completed"
    assert got.end.summary.duration == pytest.approx(t[-1] - len(stop) / 1e3, abs=2e-3)
    assert got.end.summary.abort_reason is None  # a completed session has no abort reason
    # every event of the session names it (the server files them under its session)
    assert {e.session_id for e in got.events if hasattr(e, "session_id")} == {"ramp"}


def test_operator_stop_ends_the_session_early(worker):
    worker.start_session(scenario(duration=30.0), "stopme")
    follow(worker, until="session_started")
    follow(worker, until="timing")
    worker.stop()
    got = follow(worker, timeout=10)
    end = got.end
    assert end is not None and end.status == "stopped"
    assert 0.5 < end.summary.duration < 10.0
    assert end.summary.abort_reason == "stopped by the operator"


def test_a_stop_during_the_wind_down_or_an_immediate_one_zeroes_the_torque_at_once(worker):
    # a first stop winds the handle down to rest; a second one while it does ends the session
    # at once, zero torque, as does a stop asked immediate from the start
    for name, stops in (("twice", [(False, None), (False, None)]), ("now", [(True, "drill")])):
        reader = worker.open_reader()
        worker.start_session(scenario(duration=30.0), name)
        follow(worker, until="timing")
        for i, (immediate, reason) in enumerate(stops):
            if i:
                follow(worker, until="stopping")
            worker.stop(immediate=immediate, reason=reason)
        got = follow(worker, reader, timeout=10)
        reader.close()
        end = got.end
        assert end is not None and end.status == "stopped"
        assert end.reason == ("drill" if name == "now" else "stopped at once by the operator")
        assert got.data[-1, INDEX["u_out"]] == 0.0
        assert int(got.data[-1, INDEX["flags"]]) & TORQUE_LIMIT == 0  # no limit claimed there
        assert not (got.data[:-1, INDEX["phase"]] < 0).any()  # no torque ramp: zero at once
        assert worker.state == "idle"


def test_bad_requests_are_refused_where_they_are_made(worker):
    with pytest.raises(ScenarioError, match="duration"):
        worker.start_session({"duration": -1}, "bad")
    with pytest.raises(ValueError, match="session_id"):
        worker.start_session(scenario(), "")
    worker.start_session(scenario(duration=5.0), "busy")
    with pytest.raises(WorkerError, match=r"already|running"):
        worker.start_session(scenario(), "second")
    follow(worker, until="session_started")
    with pytest.raises(WorkerError, match="running"):
        worker.start_session(scenario(), "third")
    worker.stop(immediate=True)
    end = follow(worker).end
    assert end is not None and end.status == "stopped"
    assert worker.state == "idle"
    odrive = Worker(MachineSpec(kind="odrive", device="/dev/null", torque_constant=0.1))
    with pytest.raises(ValueError, match="torque sensor"):
        odrive.start_session(scenario(controller={"kind": "measured"}), "x")


def test_events_as_an_async_stream(worker):
    async def consume():
        kinds = []
        worker.start_session(scenario(duration=0.5), "async")
        async for ev in worker.events(interval=0.01):
            kinds.append(ev.kind)
            d = ev.to_dict()
            assert d["kind"] == ev.kind
            if ev.kind == "session_ended":
                assert 0.5 < d["summary"]["duration"] < 0.5 + 8.0  # and the wind-down
                return kinds
        return kinds

    kinds = asyncio.run(asyncio.wait_for(consume(), 30))
    assert kinds[0] == "session_started" and kinds[-1] == "session_ended"
    assert "stopping" in kinds


def test_status_is_plain_data(worker):
    st = worker.status()
    assert st.state == "idle" and st.machine == "sim" and st.pid == worker.pid
    assert st.heartbeat_age is not None and st.heartbeat_age < 1.0
    assert st.realtime is not None
    assert worker.ring_info.columns == COLUMNS
