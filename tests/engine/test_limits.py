"""Limits enforced in the step, whatever the controller asks for."""

from __future__ import annotations

import pytest

from sessions.config import parse_session_config
from sessions.limits import TORQUE_LIMIT, VELOCITY_LIMIT, Limits
from sessions.loop import Loop
from sessions.passivity import PassivityMonitor


def test_torque_is_clamped_both_ways() -> None:
    lim = Limits(5.0, 10.0)
    assert lim.apply(12.0, 1.0) == 5.0 and lim.flags == TORQUE_LIMIT
    assert lim.apply(-12.0, 1.0) == -5.0 and lim.flags == TORQUE_LIMIT
    assert lim.apply(3.0, 1.0) == 3.0 and lim.flags == 0


def test_overspeed_brakes_harder_the_faster_it_goes() -> None:
    lim = Limits(20.0, 10.0)
    u1 = lim.apply(5.0, 10.1)
    assert lim.flags & VELOCITY_LIMIT and u1 < 0.0
    u2 = lim.apply(5.0, 10.3)
    assert u2 < u1
    assert lim.apply(5.0, 11.0) == -20.0 and lim.flags == VELOCITY_LIMIT | TORQUE_LIMIT
    assert lim.apply(-5.0, -10.5) > 0.0  # reverse overspeed brakes the other way


def test_loop_reports_the_limit_it_hit() -> None:
    loop = Loop(
        parse_session_config({"machine": {"max_velocity": 8.0}, "controller": {"kind": "measured"}})
    )
    loop.begin(0.0, 0.0)
    u = loop.step(0.0, 9.0, 1.0)
    assert loop.flags & VELOCITY_LIMIT and u < 0.0


def test_passivity_breach_is_flagged_below_minus_c2() -> None:
    mon = PassivityMonitor(c2=0.5)
    for _ in range(400):  # the machine drives a pushing user backwards: τ > 0, w < 0
        mon.add(1.0, -1.0, 1e-3)
    assert mon.work == pytest.approx(-0.4) and not mon.breached
    for _ in range(200):
        mon.add(1.0, -1.0, 1e-3)
    assert mon.breached and mon.minimum == pytest.approx(-0.6)
