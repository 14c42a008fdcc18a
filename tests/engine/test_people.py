"""Simulated users know their own truth; the traits behave as specified."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sessions.config import UserConfig
from sessions.objective import surrogate_power
from sessions.people import SimulatedUser


def make(**kw: object) -> SimulatedUser:
    return SimulatedUser(UserConfig(**kw), 1e-3, seed=7)  # type: ignore[arg-type]


def test_linear_user_equals_the_papers_surrogate() -> None:
    user = make(kind="linear", tau0=2.0, wmax=6.0)
    for w in np.linspace(0.1, 5.9, 59):
        assert user.true_power(float(w)) == pytest.approx(surrogate_power(float(w)), abs=1e-12)
    assert user.optimum() == pytest.approx((3.0, 3.0))


@given(
    tau0=st.floats(0.5, 20.0),
    wmax=st.floats(2.0, 30.0),
    a=st.floats(0.1, 1.0),
    rho=st.sampled_from([0.5, 1.0, 2.0]),
)
@settings(max_examples=40, deadline=None)
def test_hill_optimum_is_the_maximum_of_its_power(
    tau0: float, wmax: float, a: float, rho: float
) -> None:
    user = make(kind="hill", tau0=tau0, wmax=wmax, curvature=a)
    w_star, p_star = user.optimum(rho)
    grid = np.linspace(1e-3, wmax, 20001)
    p = np.array([user.true_power(float(w), rho) for w in grid])
    assert p_star >= p.max() - 1e-9 * p.max()
    assert abs(w_star - grid[p.argmax()]) <= 2 * (grid[1] - grid[0]) + 1e-6 * wmax


def test_hill_closed_form_near_031_wmax() -> None:
    user = make(kind="hill", wmax=10.0, curvature=0.25)
    assert user.w_star() == pytest.approx(10.0 * (math.sqrt(0.25**2 + 0.25) - 0.25))
    assert user.w_star() / 10.0 == pytest.approx(0.309, abs=1e-3)


def test_torque_is_clamped_to_zero_and_tau0() -> None:
    user = make(kind="hill", tau0=3.0, wmax=10.0)
    assert user.torque(0.0, -5.0) == pytest.approx(3.0)
    assert user.torque(0.0, 0.0) == pytest.approx(3.0)
    assert user.torque(0.0, 10.0) == 0.0
    assert user.torque(0.0, 25.0) == 0.0


def test_ripple_follows_the_stroke_angle() -> None:
    user = make(kind="linear", tau0=2.0, wmax=6.0, ripple=0.1)
    base = 2.0 * (1 - 3.0 / 6.0)
    assert user.torque(math.pi / 2, 3.0) == pytest.approx(base * 1.1)
    assert user.torque(-math.pi / 2, 3.0) == pytest.approx(base * 0.9)
    assert user.torque(0.0, 3.0) == pytest.approx(base)


def test_noise_has_the_requested_std_and_bandwidth_and_is_seeded() -> None:
    a = SimulatedUser(UserConfig(noise=0.03, noise_bandwidth=5.0), 1e-3, seed=3)
    b = SimulatedUser(UserConfig(noise=0.03, noise_bandwidth=5.0), 1e-3, seed=3)
    xs, ys = [], []
    for _ in range(200_000):
        a.advance(1e-3)
        b.advance(1e-3)
        xs.append(a.noise.value)
        ys.append(b.noise.value)
    x = np.array(xs)
    assert xs == ys  # deterministic for a seed
    assert x.std() == pytest.approx(0.03, rel=0.1)
    lag1 = np.corrcoef(x[1:], x[:-1])[0, 1]
    assert lag1 == pytest.approx(math.exp(-2 * math.pi * 5.0 * 1e-3), abs=0.005)


def test_torque_fatigue_scales_p_star_but_not_w_star() -> None:
    user = make(kind="hill", fatigue_tau=100.0)
    w0, p0 = user.optimum()
    for _ in range(50_000):
        user.advance(1e-3)
    w1, p1 = user.optimum()
    assert w1 == pytest.approx(w0)
    assert p1 / p0 == pytest.approx(math.exp(-0.5), rel=1e-6)
    assert user.optimum(t=100.0)[1] / p0 == pytest.approx(math.exp(-1.0), rel=1e-9)


def test_three_compartment_fatigue_tires_then_settles() -> None:
    user = make(kind="hill", fatigue_model="three-compartment", fatigue_effort=0.5)
    factors = []
    for k in range(600_000):
        user.advance(1e-3)
        if k % 1000 == 0:
            factors.append(user.fatigue.factor)
    f = np.array(factors)
    assert f[0] == pytest.approx(1.0, abs=1e-3)
    assert np.all(np.diff(f) <= 1e-12)  # capacity only falls at constant effort
    # once every unit is recruited, F·MA = R·MF and MA + MF = 1: capacity → R/(F+R) = 1/6
    assert f[-1] == pytest.approx(0.002 / (0.01 + 0.002), rel=0.01)
    fat = user.fatigue
    assert fat.ma + fat.mf + fat.mr == pytest.approx(1.0, abs=1e-9)  # conservation


def test_torque_stays_within_zero_and_tau_max_over_a_long_noisy_run() -> None:
    # 13.3: noise scales τ by (1 + n); at σ = 0.5, 1 + n < 0 in Φ(-2) ≈ 2.3 % of periods.
    # The clamp keeps 0 ≤ τ ≤ τmax at every period (and keeps the mean: it is symmetric).
    user = SimulatedUser(UserConfig(noise=0.5, ripple=0.3), 1e-3, seed=11)
    w = 3.0
    taus = np.empty(300_000)
    for k in range(len(taus)):
        taus[k] = user.torque(0.37 * k * 1e-3 * w, w)
        user.advance(1e-3)
    assert taus.min() >= 0.0
    assert taus.max() <= user.tau_max
    zero = float(np.mean(taus == 0.0))
    assert 0.005 < zero < 0.05  # the clamp acted, about Φ(-2) of the time
    base = 3.0 * user.shape(w)
    assert taus.mean() == pytest.approx(base, rel=0.03)


def test_velocity_fatigue_moves_the_optimum_as_s_of_t() -> None:
    # s(t) = f + (1 - f) exp(-t/T); τ(w, t) = τ0 g(w/s): w*(t) = s(t) w*(0), p* scales by s.
    f, T = 0.8, 40.0
    user = make(kind="hill", velocity_fatigue_tau=T, velocity_fatigue_floor=f)
    w0, p0 = user.optimum()
    for _ in range(60_000):
        user.advance(1e-3)
    s = f + (1 - f) * math.exp(-60.0 / T)
    assert user.speed.factor == pytest.approx(s, rel=1e-9)
    w1, p1 = user.optimum()
    assert w1 == pytest.approx(s * w0, rel=1e-9)
    assert p1 == pytest.approx(s * p0, rel=1e-9)
    # and it is the true maximiser of the power the person produces now
    grid = np.linspace(0.05, 10.0, 20001)
    p = np.array([user.true_power(float(w)) for w in grid])
    assert abs(grid[p.argmax()] - w1) <= 2 * (grid[1] - grid[0])
    # the torque the plant sees follows the same law
    assert user.torque(0.0, s * 2.0) == pytest.approx(3.0 * make(kind="hill").shape(2.0))
    assert user.w_star(t=0.0) == pytest.approx(w0)


def test_a_table_user_equal_to_a_hill_user_has_the_same_optimum() -> None:
    hill = make(kind="hill", tau0=3.0, wmax=10.0, curvature=0.25)
    ws = np.linspace(0.0, 10.0, 201)
    table = make(kind="table", points=[[float(w), float(3.0 * hill.shape(float(w)))] for w in ws])
    w_h, p_h = hill.optimum()
    w_t, p_t = table.optimum()
    assert w_t == pytest.approx(w_h, rel=1e-3)
    assert p_t == pytest.approx(p_h, rel=1e-5)
    for w in (0.3, 2.0, 3.09, 7.7):
        assert table.torque(0.0, w) == pytest.approx(hill.torque(0.0, w), rel=1e-3)


def test_table_is_monotone_between_points_and_zero_past_the_last() -> None:
    pts = [[0.5, 4.0], [2.0, 3.5], [4.0, 1.0], [6.0, 0.8], [8.0, 0.0]]
    user = make(kind="table", points=pts)
    assert user.torque(0.0, 0.0) == 4.0  # below the first point: its torque
    assert user.torque(0.0, 8.0) == 0.0
    assert user.torque(0.0, 9.0) == 0.0  # past the last point: nothing
    grid = np.linspace(0.5, 8.0, 3001)
    tau = np.array([user.torque(0.0, float(w)) for w in grid])
    for (w1, t1), (w2, t2) in itertools.pairwise(pts):
        seg = tau[(grid >= w1) & (grid <= w2)]
        lo, hi = min(t1, t2), max(t1, t2)
        assert seg.min() >= lo - 1e-12 and seg.max() <= hi + 1e-12  # PCHIP: no overshoot


@pytest.mark.parametrize(
    ("field", "value", "reason"),
    [
        ("tau0", 1e308, "less than or equal to 500"),
        ("tau0", -1.0, "greater than 0"),
        ("wmax", 1e6, "less than or equal to 50"),
        ("curvature", 0.0, "greater than"),
        ("noise", 0.9, "less than or equal to 0.5"),
        ("noise_bandwidth", 1e9, "less than or equal to 200"),
        ("fatigue_tau", 0.5, "at least 1 s"),
        ("fatigue_tau", math.inf, "finite"),
        ("fatigue_f", 5.0, "less than or equal to 1"),
        ("velocity_fatigue_tau", 1e9, "less than or equal to 1000000"),
        ("velocity_fatigue_floor", 0.0, "greater than 0"),
        ("velocity_fatigue_floor", 1.5, "less than or equal to 1"),
    ],
)
def test_a_profile_beyond_a_person_is_refused_naming_the_field(
    field: str, value: float, reason: str
) -> None:
    from sessions.config import ScenarioError, parse_session_config

    with pytest.raises(ScenarioError) as err:
        parse_session_config({"user": {field: value}})
    assert f"user.{field}" in str(err.value)
    assert reason in str(err.value)


@pytest.mark.parametrize(
    ("points", "reason"),
    [
        ([[0.0, 3.0], [1.0, 2.0]], "at least 3 points"),
        ([[0.0, 3.0], [2.0, 2.0], [1.0, 0.0]], "w must increase"),
        ([[0.0, 3.0], [1.0, -2.0], [2.0, 0.0]], "τ = -2.0"),
        ([[0.0, 3.0], [1.0, 1e9], [2.0, 0.0]], "τ = 1000000000.0"),
        ([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], "positive somewhere"),
    ],
)
def test_a_bad_table_is_refused_with_its_reason(points: list[list[float]], reason: str) -> None:
    from sessions.config import ScenarioError, parse_session_config

    with pytest.raises(ScenarioError) as err:
        parse_session_config({"user": {"kind": "table", "points": points}})
    assert "user.points" in str(err.value) and reason in str(err.value)
    with pytest.raises(ScenarioError, match="points: required"):
        parse_session_config({"user": {"kind": "table"}})
