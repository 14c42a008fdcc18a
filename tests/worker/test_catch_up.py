"""A caught-up period (docs/engine.md, missed periods) is stepped with the torque the drive
held over it: the observer (28) τ̂ = -u + J·ad uses that torque, not a command nobody sent,
and RISE's integrals of (23) grow as they would have with the period on time.

Truth: equation (28) evaluated by hand, and a twin loop stepped on time for comparison.
"""

from __future__ import annotations

import pytest

from sessions.loop import Loop
from sessions.telemetry import INDEX
from testing.live import scenario


def _loops() -> tuple[Loop, Loop]:
    cfg = scenario(duration=5.0, controller={"kind": "rise"})
    a, b = Loop(cfg), Loop(cfg)
    for loop in (a, b):
        loop.begin(0.0, 0.0)
        for k in range(600):  # past the start delay: the reference moves
            loop.step(0.001 * k, 1.0 + 0.0005 * k)
    return a, b


def test_a_held_step_records_and_observes_the_held_torque():
    on_time, caught = _loops()
    held = 1.25
    u_cmd = on_time.step(0.6, 1.3)
    caught.step(0.6, 1.3, held=held)
    r = caught.row
    J = caught.cfg.machine.inertia
    assert r[INDEX["u"]] == held
    assert r[INDEX["tau"]] == pytest.approx(-held + J * r[INDEX["ad"]], rel=1e-12)  # (28)
    assert on_time.row[INDEX["tau"]] == pytest.approx(-u_cmd + J * on_time.row[INDEX["ad"]])
    assert held != pytest.approx(u_cmd)  # the held torque is not what the loop would command
    # the integral of (23) grew by the same (ks+1)·αr·e·dt + β·sgn(e)·dt either way
    assert caught.controller.integral == pytest.approx(on_time.controller.integral, rel=1e-12)
    # the next command is the same: the held step changed what was observed, not the control
    assert caught.step(0.601, 1.3) == pytest.approx(on_time.step(0.601, 1.3), rel=1e-12)
