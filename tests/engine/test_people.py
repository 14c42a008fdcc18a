"""Simulated users know their own truth; the traits behave as specified."""

from __future__ import annotations

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


def test_exponential_fatigue_scales_p_star_but_not_w_star() -> None:
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
