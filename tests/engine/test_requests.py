"""The trainer's request → session policy (sessions/requests.py), against the rules it states:
the bracket [0.6 v, v, 1.5 v] around a stored optimum v, every bracket and setpoint it picks
below 90 % of the velocity limit, limits that a request may lower and never raise, and a
controller the machine can run."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from sessions.config import MachineConfig, SeekerConfig
from sessions.requests import (
    RequestError,
    Rig,
    SessionStart,
    auto_bracket,
    session_config,
)

HEADROOM = 0.9  # the rule: every bracket and setpoint chosen stays below 90 % of w_max
SIM = Rig("sim", MachineConfig(), 1000.0, has_torque_sensor=True)
ODRIVE = Rig("odrive", MachineConfig(), 1000.0, has_torque_sensor=False)


def test_the_bracket_is_around_the_stored_optimum() -> None:
    cfg = session_config(SessionStart(user_id=1, seed=1), SIM, optimum=3.0)
    assert cfg.seeker.bracket == pytest.approx((0.6 * 3.0, 3.0, 1.5 * 3.0))


def test_without_an_optimum_the_default_bracket_fits_a_slow_machine() -> None:
    default = SeekerConfig().bracket
    fast = session_config(SessionStart(user_id=1, seed=1), SIM)
    assert fast.seeker.bracket == default
    slow = session_config(SessionStart(user_id=1, seed=1, limits={"max_velocity": 5.0}), SIM)
    lo, mid, hi = slow.seeker.bracket
    assert hi == pytest.approx(HEADROOM * 5.0)
    assert (lo / hi, mid / hi) == pytest.approx((default[0] / default[2], default[1] / default[2]))


@given(
    optimum=st.one_of(st.none(), st.floats(0.01, 200.0)),
    max_velocity=st.floats(0.5, 100.0),
)
def test_a_chosen_bracket_is_increasing_and_below_the_headroom(
    optimum: float | None, max_velocity: float
) -> None:
    (lo, mid, hi), _ = auto_bracket(optimum, max_velocity)
    assert 0 < lo < mid < hi <= HEADROOM * max_velocity * (1 + 1e-12)


def test_a_given_bracket_is_kept_and_checked_against_the_lowered_limit() -> None:
    given_bracket = {"bracket": [1.0, 2.0, 4.0]}
    req = SessionStart(user_id=1, seed=1, seeker=given_bracket)
    assert session_config(req, SIM, optimum=3.0).seeker.bracket == (1.0, 2.0, 4.0)
    low = SessionStart(user_id=1, seed=1, seeker=given_bracket, limits={"max_velocity": 3.0})
    with pytest.raises(RequestError) as refused:
        session_config(low, SIM)
    assert refused.value.field == "seeker.bracket"


def test_limits_may_be_lowered_never_raised() -> None:
    cfg = session_config(SessionStart(user_id=1, seed=1, limits={"max_torque": 7.5}), SIM)
    assert cfg.machine.max_torque == 7.5
    assert cfg.machine.max_velocity == SIM.machine.max_velocity
    with pytest.raises(RequestError) as refused:
        session_config(SessionStart(user_id=1, limits={"max_torque": 20.5}), SIM)
    assert refused.value.field == "limits.max_torque"
    assert "20 N·m" in refused.value.reason


def test_the_fixed_seeker_holds_the_stored_optimum_within_the_headroom() -> None:
    req = SessionStart(user_id=1, seed=1, seeker={"kind": "fixed"})
    assert session_config(req, SIM, optimum=3.1).seeker.setpoint == pytest.approx(3.1)
    assert session_config(req, SIM, optimum=40.0).seeker.setpoint == pytest.approx(
        HEADROOM * SIM.machine.max_velocity
    )


def test_a_controller_the_machine_cannot_run_is_refused() -> None:
    req = SessionStart(user_id=1, controller={"kind": "measured"})
    assert session_config(req, SIM).controller.kind == "measured"
    with pytest.raises(RequestError) as refused:
        session_config(req, ODRIVE)
    assert refused.value.field == "controller.kind"
    assert "torque sensor" in refused.value.reason
