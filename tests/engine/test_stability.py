"""Gains the discrete loop can hold (issue 13.1): the bounds of sessions/stability.py against
the loop as implemented — the validator refuses what the loop cannot hold, with the bound in
the message; the largest gain it accepts settles in simulation; the unmargined limit is the
true one (just inside settles, just outside chatters at the torque limit).

The bounds here are written out independently of the module (the formulas of its docstring):
(ks + 1)·dt/J < 4/(2 − αr·dt) and αr·dt < 1 for RISE, k·dt/J < 2 for controller A, each with a
gain margin of 2.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sessions import stability
from sessions.config import ScenarioError, UserConfig, load_scenario
from sessions.config import parse_session_config as parse
from sessions.controllers import MeasuredTorqueController, RiseController, make_controller
from sessions.limits import TORQUE_LIMIT, VELOCITY_LIMIT, Limits
from sessions.loop import Loop
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.simulation import run_simulation

J = 0.1
RATES = [50.0, 1000.0, 5000.0]
MAX_TORQUE = 20.0


def linear_user(tau0: float, wmax: float) -> UserConfig:
    """τ = τ0 (1 − w/wmax): dτ/dw = −τ0/wmax. Built without validation: these are laboratory
    users (no slope, or a steep one), outside the range a stored profile allows."""
    return UserConfig.model_construct(
        **{**UserConfig().model_dump(), "kind": "linear", "tau0": tau0, "wmax": wmax}
    )


# a user whose torque does not depend on w (dτ/dw ≈ 0): the worst case of (S4)
FLAT = linear_user(2.0, 1e9)


def settle(ctrl, rate: float, *, e0: float = 1.0, seconds: float = 3.0, user=FLAT):
    """The controller on the plant with the loop's limits, wd = 3.5 rad/s held, starting
    e0 away from it. Returns (e, u) per period. 3 s: RISE's slow pole, ≈ e^{−αr·dt}, has
    decayed by e^{−6} when the second half begins."""
    dt, wd = 1.0 / rate, 3.5
    person = SimulatedUser(user, dt, seed=0)
    plant = Plant(J, w0=wd + e0)
    limits = Limits(MAX_TORQUE, 15.0, stability.deadbeat_gain(J, dt))
    ctrl.begin(e0, 0.0)
    n = round(seconds * rate)
    es, us = np.empty(n), np.empty(n)
    for i in range(n):
        tau = plant.sample_torque(person)
        e = plant.w - wd
        u_cmd = ctrl.command(e, 0.0, tau)
        u = limits.apply(u_cmd, plant.w)
        ctrl.commit(e, 0.0, tau, u, u_cmd, dt)
        plant.advance(u, dt, person)
        es[i], us[i] = e, u
    return es, us


def assert_settles(es: np.ndarray, us: np.ndarray, *, tol: float = 0.01) -> None:
    n = len(es)
    late = slice(n // 2, None)
    assert np.abs(es[late]).max() <= tol * abs(es[0]), "the error does not decay"
    assert np.all(np.abs(us[late]) < MAX_TORQUE), "chatter at the torque limit"


def assert_chatters(es: np.ndarray, us: np.ndarray) -> None:
    late = slice(len(es) // 2, None)
    assert np.abs(us[late]).max() >= MAX_TORQUE, "the torque never reaches the limit"
    assert np.abs(es[late]).max() > abs(es[0]), "the error does not grow"


def largest_accepted(make: dict, key: str, lo: float = 1e-6, hi: float = 1e6) -> float:
    """Bisect SessionConfig's acceptance of controller.<key>."""

    def ok(v: float) -> bool:
        try:
            parse({**make, "controller": {**make["controller"], key: v}})
        except ScenarioError:
            return False
        return True

    assert ok(lo)
    assert not ok(hi), f"controller.{key} = {hi:g} is accepted: nothing bounds it"
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def bound_in(message: str, key: str) -> float:
    m = re.search(rf"{key} ≤ ([0-9.e+-]+)", message)
    assert m, message
    return float(m.group(1))


def refusal(data: dict) -> str:
    with pytest.raises(ScenarioError) as exc:
        parse(data)
    return str(exc.value)


# -- the validator: the issue's examples, every entry point --------------------------------------
@pytest.mark.parametrize(
    ("data", "key", "bound"),
    [
        ({"rate": 1000.0, "controller": {"kind": "rise", "ks": 250.0}}, "ks", 99.20),
        ({"rate": 50.0, "controller": {"kind": "rise", "ks": 12.0}}, "ks", 4.208),
        ({"rate": 1000.0, "controller": {"kind": "measured", "k": 250.0}}, "k", 100.0),
    ],
)
def test_the_gains_of_the_issue_are_refused_with_the_bound(data: dict, key: str, bound: float):
    msg = refusal(data)
    assert msg.startswith(f"controller.{key}: ")
    assert f"at {data['rate']:g} Hz with J = 0.1 kg·m²" in msg
    assert bound_in(msg, key) == pytest.approx(bound, abs=1e-3)


def test_a_toml_scenario_is_refused_the_same_way(tmp_path) -> None:
    path = tmp_path / "fast.toml"
    path.write_text("rate = 50.0\n[controller]\nkind = 'rise'\nks = 12.0\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match=r"^controller\.ks: 12 is more than .* ks ≤ 4\.208"):
        load_scenario(path)


@pytest.mark.parametrize("rate", [50.0, 63.0, 100.0, 500.0, 1000.0, 5000.0, 20000.0])
@pytest.mark.parametrize("seeker", ["brent", "perturbation", "fixed"])
def test_the_defaults_hold_at_every_rate_with_poles_inside_the_margin(rate: float, seeker: str):
    cfg = parse({"rate": rate, "seeker": {"kind": seeker}})
    c, dt = cfg.controller, cfg.dt
    # RISE's poles from the loop's one-period map (see test below) are well inside the circle
    roots = np.roots([1.0, *stability.rise_characteristic(c.ks, c.alpha_r, J, dt)])
    assert np.abs(roots).max() < 1.0
    # and doubling ks + 1 (the margin) still holds, by the independent closed form
    assert 2.0 * (c.ks + 1.0) * dt / J < 4.0 / (2.0 - c.alpha_r * dt)
    assert 2.0 * c.alpha_r * dt < 1.0 and 2.0 * c.k * dt / J < 2.0
    parse({"rate": rate, "controller": {"kind": "measured"}, "seeker": {"kind": seeker}})


def test_the_default_ks_is_the_stiff_one_or_the_most_a_slower_loop_holds() -> None:
    # (S5) written out: (ks + 1)·dt/J ≤ 2/(2 − αr·dt), at 50 Hz ks ≤ 4.208
    assert parse({}).controller.ks == 20.0
    slow = parse({"rate": 50.0}).controller
    assert slow.ks == pytest.approx(2.0 / (2.0 - 4.0 / 50.0) * J * 50.0 - 1.0, abs=1e-3)
    assert slow.ks <= 2.0 / (2.0 - 4.0 / 50.0) * J * 50.0 - 1.0
    # what a person sets is kept (and refused if the loop cannot hold it)
    assert parse({"rate": 50.0, "controller": {"ks": 3.0}}).controller.ks == 3.0
    assert parse(parse({"rate": 50.0}).model_dump()).controller.ks == slow.ks


def test_the_default_rise_holds_a_person_whose_torque_rises_with_the_velocity() -> None:
    """A torque rising by s = 15 N·m·s/rad (the low flank of a sharp top): RISE's error needs
    (ks + 1)(1 − αr·dt) > s (S3). The default holds the handle on wd; ks = 4, the default
    before, let it swing by ±2 rad/s around a 1.5 rad/s setpoint."""
    ramp = [[1.0 + 0.1 * i, 2.0 + 1.5 * i] for i in range(11)]  # dτ/dw = 15 from 1 to 2 rad/s
    user = {"kind": "table", "points": [[0.0, 2.0], *ramp, [3.0, 5.0], [4.0, 0.0]]}
    seeker = {"kind": "fixed", "setpoint": 1.5, "bracket": [0.5, 1.5, 3.5]}
    spread = {}
    for ks in (None, 4.0):
        ctl = {} if ks is None else {"ks": ks}
        cfg = parse({"duration": 6.0, "user": user, "controller": ctl, "seeker": seeker})
        res = run_simulation(cfg)
        t, e = res.column("t"), res.column("w") - res.column("wd")
        spread[ks] = float(np.abs(e[t > 4.0]).max())
    assert (20.0 + 1.0) * (1.0 - 4.0 / 1000.0) > 15.0 > (4.0 + 1.0)
    assert spread[None] < 0.01
    assert spread[4.0] > 0.5


# -- the bound is the loop's: the closed form against the implemented one-period map -------------
def one_period_map(ctrl, rate: float, user: UserConfig, w: float, integral: float | None):
    dt = 1.0 / rate
    person = SimulatedUser(user, dt, seed=0)
    plant = Plant(J, w0=w)
    if integral is not None:
        ctrl.integral = integral
    tau = plant.sample_torque(person)
    e = plant.w - 1.0
    u = ctrl.command(e, 0.0, tau)
    ctrl.commit(e, 0.0, tau, u, u, dt)
    plant.advance(u, dt, person)
    return plant.w if integral is None else (plant.w, ctrl.integral)


@given(
    rate=st.floats(50.0, 20000.0),
    g=st.floats(0.01, 2.5),
    h=st.floats(0.001, 1.2),
    slope_dt=st.floats(0.0, 0.1),
)
@settings(max_examples=80, deadline=None)
def test_rise_poles_are_those_of_the_implemented_loop(rate, g, h, slope_dt) -> None:
    # A linear user τ = τ0 (1 - w/wmax) has dτ/dw = -τ0/wmax: choose it so that λ·dt = -slope_dt.
    dt = 1.0 / rate
    wmax = 10.0
    user = linear_user(max(slope_dt * J / dt * wmax, 1e-9), wmax)
    slope = -user.tau0 / wmax
    ks, alpha_r = g * J / dt - 1.0, h / dt
    ctrl = RiseController(ks, 0.0, alpha_r, J)  # β = 0: the linear part
    ctrl.begin(0.0, 0.0)
    x0, i0, d = 1.0, 0.0, 1e-3  # around w = 1 rad/s, inside the linear law
    base = np.array(one_period_map(ctrl, rate, user, x0, i0))
    cols = [
        (np.array(one_period_map(ctrl, rate, user, x0 + d, i0)) - base) / d,
        (np.array(one_period_map(ctrl, rate, user, x0, i0 + d)) - base) / d,
    ]
    measured = np.sort_complex(np.linalg.eigvals(np.column_stack(cols)))
    closed = np.sort_complex(
        np.roots([1.0, *stability.rise_characteristic(ks, alpha_r, J, dt, slope)])
    )
    # RK4 stands in for e^{λ dt}: (λ dt)⁵/120 ≤ 1e-7
    np.testing.assert_allclose(measured, closed, atol=1e-5)
    a1, a0 = stability.rise_characteristic(ks, alpha_r, J, dt, slope)
    assert stability.schur_stable(a1, a0) == (np.abs(closed).max() < 1.0)


@given(rate=st.floats(50.0, 20000.0), g=st.floats(0.01, 2.5), slope_dt=st.floats(0.0, 0.1))
@settings(max_examples=60, deadline=None)
def test_controller_a_pole_is_that_of_the_implemented_loop(rate, g, slope_dt) -> None:
    dt, wmax = 1.0 / rate, 10.0
    user = linear_user(max(slope_dt * J / dt * wmax, 1e-9), wmax)
    k = g * J / dt
    ctrl = MeasuredTorqueController(k, J)
    d = 1e-3
    pole = (
        one_period_map(ctrl, rate, user, 1.0 + d, None)
        - one_period_map(ctrl, rate, user, 1.0, None)
    ) / d
    assert pole == pytest.approx(stability.measured_pole(k, J, dt, -user.tau0 / wmax), abs=1e-4)


@given(
    g=st.floats(0.01, 3.0),
    h=st.floats(0.001, 0.99),
    y=st.floats(-0.5, 0.5).filter(lambda v: v != 0),
)
@settings(max_examples=200, deadline=None)
def test_the_user_slope_only_relaxes_the_rise_bound(g: float, h: float, y: float) -> None:
    # (S4): stable at s = 0 implies stable at any slope with ks + 1 > s/(1 - h)
    dt = 1e-3
    ks = g * J / dt - 1.0
    slope = 2.0 * y * J / dt
    if slope > 0 and (ks + 1.0) * (1.0 - h) <= slope:
        return
    if stability.schur_stable(*stability.rise_characteristic(ks, h / dt, J, dt)):
        assert stability.schur_stable(*stability.rise_characteristic(ks, h / dt, J, dt, slope))


# -- just inside the accepted bound settles; just outside is refused ------------------------------
@pytest.mark.parametrize("rate", RATES)
def test_the_largest_accepted_ks_settles_and_the_next_is_refused(rate: float) -> None:
    base = {"rate": rate, "controller": {"kind": "rise"}}
    ks = largest_accepted(base, "ks")
    dt = 1.0 / rate
    h = 4.0 * dt
    assert ks == pytest.approx(2.0 / (2.0 - h) * J / dt - 1.0, rel=1e-6)  # (S5)
    cfg = parse({**base, "controller": {"kind": "rise", "ks": ks}})
    assert_settles(*settle(make_controller(cfg.controller, J), rate))
    msg = refusal({**base, "controller": {"kind": "rise", "ks": ks * 1.001}})
    assert msg.startswith("controller.ks: ") and "(ks + 1)·dt/J ≤ 2/(2 − αr·dt)" in msg
    assert bound_in(msg, "ks") == pytest.approx(ks, rel=1e-3) and bound_in(msg, "ks") <= ks


@pytest.mark.parametrize("rate", RATES)
def test_the_largest_accepted_k_settles_and_the_next_is_refused(rate: float) -> None:
    base = {"rate": rate, "controller": {"kind": "measured"}}
    k = largest_accepted(base, "k")
    assert k == pytest.approx(J * rate, rel=1e-6)  # k·dt/J ≤ 1
    cfg = parse({**base, "controller": {"kind": "measured", "k": k}})
    assert_settles(*settle(make_controller(cfg.controller, J), rate))
    msg = refusal({**base, "controller": {"kind": "measured", "k": k * 1.001}})
    assert msg.startswith("controller.k: ") and "k·dt/J ≤ 1" in msg
    assert bound_in(msg, "k") == pytest.approx(k, rel=1e-3)


@pytest.mark.parametrize("rate", RATES)
def test_the_largest_accepted_gains_run_a_whole_session(rate: float) -> None:
    # through the loop itself: the seeker, the filter, the observer, the limits
    ks = largest_accepted({"rate": rate, "controller": {"kind": "rise"}}, "ks")
    cfg = parse(
        {"rate": rate, "duration": 12.0, "controller": {"kind": "rise", "ks": ks}, "seed": 3}
    )
    res = run_simulation(cfg)
    t, u = res.column("t"), res.column("u")
    e = res.column("w") - res.column("wd")
    assert np.abs(u).max() < MAX_TORQUE
    assert np.abs(e[t > 3.0]).max() < 0.1  # within ē1 once τ̂ has converged


# -- the unmargined limit is the true discrete limit ----------------------------------------------
@pytest.mark.parametrize("rate", RATES)
def test_rise_just_inside_the_discrete_limit_settles_and_just_outside_chatters(rate: float):
    dt = 1.0 / rate
    alpha_r, beta = 4.0, 0.5
    limit = 4.0 / (2.0 - alpha_r * dt) * J / dt - 1.0  # (S4), s = 0
    assert stability.ks_limit(alpha_r, J, dt) == pytest.approx(limit)
    seconds = 600 / rate + 3.0  # the fast pole near −1, the slow one near e^{−αr·dt}
    inside = RiseController((limit + 1.0) * 0.97 - 1.0, beta, alpha_r, J)
    assert_settles(*settle(inside, rate, seconds=seconds))  # from 1 rad/s: clamped at first
    outside = RiseController((limit + 1.0) * 1.03 - 1.0, beta, alpha_r, J)
    assert_chatters(*settle(outside, rate, e0=0.01, seconds=seconds))


@pytest.mark.parametrize("rate", RATES)
def test_controller_a_just_inside_the_discrete_limit_settles_and_just_outside_chatters(rate):
    limit = 2.0 * J * rate  # (S2), s = 0
    assert stability.k_limit(J, 1.0 / rate) == pytest.approx(limit)
    inside, outside = (
        MeasuredTorqueController(0.97 * limit, J),
        MeasuredTorqueController(1.03 * limit, J),
    )
    assert_settles(*settle(inside, rate, seconds=1000 / rate))
    assert_chatters(*settle(outside, rate, e0=0.01, seconds=1000 / rate))


@pytest.mark.parametrize("rate", RATES)
def test_alpha_r_is_held_up_to_the_rate_and_refused_past_half_of_it(rate: float) -> None:
    dt = 1.0 / rate
    ks = J / dt - 1.0  # g = 1
    # β small: the sign integral's chatter grows as 1/(1 − αr·dt) (S6)
    assert_settles(*settle(RiseController(ks, 1e-3, 0.95 / dt, J), rate, seconds=400 * dt))
    assert_chatters(
        *settle(RiseController(ks, 1e-3, 1.05 / dt, J), rate, e0=0.01, seconds=400 * dt)
    )
    base = {"rate": rate, "controller": {"kind": "rise", "ks": 1.0}}
    assert largest_accepted(base, "alpha_r") == pytest.approx(0.5 * rate, rel=1e-6)
    msg = refusal({**base, "controller": {"kind": "rise", "ks": 1.0, "alpha_r": 0.51 * rate}})
    assert msg.startswith("controller.alpha_r: ") and "αr·dt ≤ 0.5" in msg


# -- the sign integral's chatter (S6) -------------------------------------------------------------
def ripple(es: np.ndarray, us: np.ndarray) -> tuple[float, float]:
    late = slice(len(es) * 3 // 4, None)
    return np.ptp(es[late]) / 2.0, np.ptp(us[late]) / 2.0


@pytest.mark.parametrize("rate", RATES)
@pytest.mark.parametrize("ks", [1.0, 4.0])
def test_the_sign_integral_chatters_as_its_describing_function_says(rate: float, ks: float):
    beta, alpha_r = 20.0, 4.0
    dt = 1.0 / rate
    e_amp, u_amp = ripple(*settle(RiseController(ks, beta, alpha_r, J), rate, e0=0.05))
    e_df, u_df = stability.sign_chatter(beta, ks, alpha_r, J, dt)
    assert e_df == pytest.approx(4 * beta * dt / (math.pi * (ks + 1) * (1 - alpha_r * dt)))
    assert 0.7 * e_df <= e_amp <= 1.5 * e_df
    assert 0.7 * u_df <= u_amp <= 1.5 * u_df


@pytest.mark.parametrize("rate", RATES)
def test_the_largest_accepted_beta_keeps_its_ripple_far_from_the_clamp(rate: float) -> None:
    base = {"rate": rate, "controller": {"kind": "rise", "ks": 4.0}}
    beta = largest_accepted(base, "beta")
    es, us = settle(RiseController(4.0, beta, 4.0, J), rate, e0=0.05)
    u_amp = ripple(es, us)[1]
    assert u_amp <= 1.5 / 20.0 * MAX_TORQUE  # 1/20 of the limit, within the DF's accuracy
    assert np.all(np.abs(us[len(us) // 2 :]) < MAX_TORQUE)
    msg = refusal({**base, "controller": {"kind": "rise", "ks": 4.0, "beta": beta * 1.01}})
    assert msg.startswith("controller.beta: ") and "1/20 of machine.max_torque" in msg
    assert bound_in(msg, "beta") == pytest.approx(beta, rel=1e-3)
    # ten times more: a ripple of half the limit, the validator's reason
    assert ripple(*settle(RiseController(4.0, 10 * beta, 4.0, J), rate, e0=0.05))[1] > 5.0


# -- the velocity governor is a gain too ----------------------------------------------------------
def test_the_governor_brakes_an_overspeed_at_50_hz_without_chatter() -> None:
    # a person pushing 10 N·m past the velocity limit, the controller asking for nothing
    cfg = parse({"rate": 50.0, "machine": {"max_velocity": 15.0}})
    limits = Loop(cfg).limits
    user = SimulatedUser(linear_user(10.0, 1e9), cfg.dt, seed=0)
    plant = Plant(J, w0=14.0)
    us = []
    for _ in range(100):
        plant.sample_torque(user)
        u = limits.apply(0.0, plant.w)
        plant.advance(u, cfg.dt, user)
        us.append(u)
    late = np.array(us[50:])
    assert limits.flags & VELOCITY_LIMIT and not limits.flags & TORQUE_LIMIT
    assert np.ptp(late) < 1e-6  # a steady braking torque, not 0 / -20 N·m every other period
    assert late[-1] == pytest.approx(-10.0)  # holding the person's push
    assert plant.w - 15.0 == pytest.approx(10.0 / stability.deadbeat_gain(J, cfg.dt), rel=1e-6)


def test_the_governor_keeps_its_span_where_the_loop_is_fast_enough() -> None:
    limits = Loop(parse({"rate": 1000.0})).limits
    assert limits.gain == pytest.approx(MAX_TORQUE / 0.5)  # 40 < J/dt = 100


# -- the reference: filter pole, perturbation (14) ------------------------------------------------
@pytest.mark.parametrize("order", [3, 4])
def test_the_filter_pole_is_bounded_by_the_feedforward_torque(order: int) -> None:
    # c_n: the peak of ad for a unit step, measured on the implemented filter
    from sessions.filters import TrajectoryFilter

    f = TrajectoryFilter(order, 10.0, 1e-5)
    peak = 0.0
    for _ in range(200_000):
        f.step(1.0)
        peak = max(peak, f.ad)
    assert stability.filter_peak(order) == pytest.approx(peak / 10.0, rel=1e-4)
    top = 6.0
    p_max = 0.5 * MAX_TORQUE / (J * peak / 10.0 * top)
    base = {"seeker": {"filter": {"order": order}, "bracket": (1.0, 3.5, top)}}
    parse({"seeker": {**base["seeker"], "filter": {"order": order, "pole": 0.999 * p_max}}})
    msg = refusal({"seeker": {**base["seeker"], "filter": {"order": order, "pole": 1.01 * p_max}}})
    assert msg.startswith("seeker.filter.pole: ")
    assert bound_in(msg, "pole") == pytest.approx(p_max, rel=1e-3)


def test_the_feedforward_bound_keeps_the_reference_off_the_clamp() -> None:
    # the largest pole accepted, on a session from rest to γ3: the motor is never saturated
    top = 6.0
    p_max = 0.5 * MAX_TORQUE / (J * stability.filter_peak(4) * top)
    cfg = parse(
        {
            "duration": 3.0,
            "controller": {"kind": "measured"},
            "seeker": {"kind": "fixed", "setpoint": top, "filter": {"pole": 0.999 * p_max}},
        }
    )
    u = run_simulation(cfg).column("u")
    assert np.abs(u).max() < MAX_TORQUE


@pytest.mark.parametrize("key", ["alpha0", "kf2", "alpha_f"])
@pytest.mark.parametrize("rate", RATES)
def test_the_perturbation_rates_are_held_by_forward_euler(key: str, rate: float) -> None:
    base = {"rate": rate, "seeker": {"kind": "perturbation"}}
    parse({**base, "seeker": {"kind": "perturbation", key: rate}})  # r·dt = 1
    msg = refusal({**base, "seeker": {"kind": "perturbation", key: 1.01 * rate}})
    assert msg.startswith(f"seeker.{key}: ") and f"{key} ≤ {rate:g}" in msg
    # the same value is no concern of a seeker that does not use it
    parse({"rate": rate, "seeker": {"kind": "brent", key: 10 * rate}})


def test_the_dither_must_lie_inside_the_tracking_bandwidth() -> None:
    cfg = {"controller": {"kind": "rise", "ks": 1.0, "alpha_r": 0.05}}  # the paper's Exp. 1
    # τ̂/τ = T(s) = 2(s + 0.05)/(0.1 s² + 2 s + 0.1) ≈ 20/(s + 20): 30° near ω = 20·tan 30°
    w_max = stability.max_omega("rise", 1.0, 0.05, J, 1e-3)
    assert w_max == pytest.approx(20.0 * math.tan(math.radians(30.0)), rel=0.03)
    parse({**cfg, "seeker": {"kind": "perturbation", "omega": 0.99 * w_max, "amplitude": 0.1}})
    msg = refusal(
        {**cfg, "seeker": {"kind": "perturbation", "omega": 1.01 * w_max, "amplitude": 0.1}}
    )
    assert msg.startswith("seeker.omega: ") and bound_in(msg, "omega") <= w_max


def test_the_dither_stays_below_the_velocity_limit() -> None:
    msg = refusal(
        {"seeker": {"kind": "perturbation", "bracket": (1.0, 3.0, 14.0), "amplitude": 1.5}}
    )
    assert msg.startswith("seeker.amplitude: γ3 + ae = 15.5")
