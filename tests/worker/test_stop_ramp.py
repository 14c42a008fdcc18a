"""The controlled stop's torque, period by period, against its closed form
(sessions/worker/supervisor.py, StopRamp): u_k = u0 (1 - k/N), N = round(duration/dt), only
while it resists the motion; the velocity governor still brakes; over when the ramp is at zero
and the handle within the velocity limit, or at the latest after the grace period.
In-process, with the engine's real limits (test_session.py checks the same in the worker)."""

from __future__ import annotations

import pytest

from sessions.limits import Limits
from sessions.worker.supervisor import StopRamp

DT = 0.001


def limits() -> Limits:
    return Limits(max_torque=20.0, max_velocity=10.0)


def test_the_torque_ramps_linearly_to_zero_and_then_it_is_over() -> None:
    u0, n = -8.0, 500  # 0.5 s at 1 kHz
    ramp = StopRamp(u0, 0.5, DT, limits())
    assert (ramp.steps, ramp.max_steps, ramp.k, ramp.done) == (n, n + 2000, 0, False)
    for k in range(1, n):
        u = ramp.command(3.0)  # the handle moves forward; u0 < 0 resists it
        assert u == pytest.approx(u0 * (1 - k / n), abs=1e-12), k
        assert not ramp.done
    assert ramp.command(3.0) == 0.0 and ramp.done  # k = N: zero, within the limit: over
    assert ramp.k == n


def test_a_ramp_that_would_drive_the_handle_is_zero() -> None:
    ramp = StopRamp(8.0, 0.5, DT, limits())
    assert ramp.command(3.0) == 0.0  # u0 > 0 along w > 0: the motor never pushes
    assert ramp.command(-3.0) == pytest.approx(8.0 * (1 - 2 / 500))  # against w < 0: resists
    assert ramp.command(0.0) == pytest.approx(8.0 * (1 - 3 / 500))  # a still handle: held
    assert not ramp.done


def test_the_governor_still_brakes_an_overspeed_handle() -> None:
    lim = limits()
    ramp = StopRamp(-1.0, 0.5, DT, lim)
    w = lim.max_velocity + 0.25
    u = ramp.command(w)
    assert u == pytest.approx(-lim.gain * 0.25) and u < -1.0  # more braking than the ramp
    u = ramp.command(-w)
    assert u == pytest.approx(lim.gain * 0.25)  # the other way round, too
    assert abs(ramp.command(100.0)) == lim.max_torque  # and the torque clamp holds


def test_the_stop_waits_for_the_handle_to_slow_down_within_the_grace() -> None:
    lim = limits()
    ramp = StopRamp(-2.0, 0.01, DT, lim, grace=0.02)  # N = 10, at most 30 periods
    fast = lim.max_velocity + 1.0
    for _ in range(10):
        ramp.command(fast)
    assert not ramp.done  # the ramp is at zero but the handle is still over the limit
    assert ramp.command(fast) < 0.0  # the governor keeps braking meanwhile
    # ... and only the governor: the ramp at zero adds nothing, whichever way the handle turns
    # (a past-the-end ramp u0·s, s < 0, would add 2·0.2 = 0.4 N·m here: more than the governor)
    back = lim.max_velocity + 0.005
    assert ramp.command(-back) == pytest.approx(lim.gain * 0.005) and lim.gain * 0.005 < 0.4
    assert ramp.command(lim.max_velocity) == 0.0 and ramp.done  # |w| <= limit: over


def test_the_grace_period_bounds_the_stop() -> None:
    lim = limits()
    ramp = StopRamp(-2.0, 0.01, DT, lim, grace=0.02)
    for k in range(1, 30):
        ramp.command(lim.max_velocity * 2)
        assert not ramp.done, k
    assert ramp.command(lim.max_velocity * 2) == 0.0 and ramp.done  # k = 30: over, zero


def test_a_zero_duration_is_one_period() -> None:
    ramp = StopRamp(-5.0, 0.0, DT, limits(), grace=0.0)
    assert (ramp.steps, ramp.max_steps) == (1, 1)
    assert ramp.command(1.0) == 0.0 and ramp.done
    half = StopRamp(-5.0, 0.0026, DT, limits())  # rounded to the nearest period
    assert half.steps == 3 and half.max_steps == 3 + 2000
