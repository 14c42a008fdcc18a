"""Trajectory filters (32)/(33): exact against the closed-form step response."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sessions.filters import TrajectoryFilter


def step_response(n: int, p: float, t: float) -> tuple[float, float, float]:
    """Step response of pⁿ/(s+p)ⁿ and its first two derivatives (closed form)."""
    x = p * t
    y = 1.0 - math.exp(-x) * sum(x**k / math.factorial(k) for k in range(n))
    h = p**n * t ** (n - 1) * math.exp(-x) / math.factorial(n - 1)  # impulse response
    dh = h * ((n - 1) / t - p) if t > 0 else (p**2 if n == 2 else 0.0)
    return y, h, dh


@pytest.mark.parametrize("order", [3, 4])
@pytest.mark.parametrize("pole", [3.0, 10.0])
def test_step_response_and_derivatives_are_exact(order: int, pole: float) -> None:
    dt, gamma = 1e-3, 2.5
    f = TrajectoryFilter(order, pole, dt)
    f.reset(0.0)
    worst = 0.0
    for k in range(1, 6001):
        f.step(gamma)
        y, h, dh = step_response(order, pole, k * dt)
        worst = max(
            worst,
            abs(f.wd - gamma * y),
            abs(f.ad - gamma * h) / pole,
            abs(f.jd - gamma * dh) / pole**2,
        )
    assert worst < 1e-9


def test_dc_gain_is_one() -> None:
    f = TrajectoryFilter(4, 3.0, 1e-3)
    f.reset(1.0)
    for _ in range(20_000):
        f.step(4.0)
    assert f.wd == pytest.approx(4.0, abs=1e-12)
    assert abs(f.ad) < 1e-12 and abs(f.jd) < 1e-12


@pytest.mark.parametrize(("order", "omega"), [(4, 0.5), (4, 1.5), (4, 6.0), (3, 2.0)])
def test_frequency_response_is_that_of_equation_32(order: int, omega: float) -> None:
    # (32): wd/γ = 81 / (s⁴ + 12 s³ + 54 s² + 108 s + 81) = 3⁴/(s + 3)⁴, evaluated at s = jω
    # from its printed coefficients; the filter's steady response to sin ωt must have that
    # gain and phase (a wrong pole, order or step would not).
    coeffs = {4: [1, 12, 54, 108, 81], 3: [1, 9, 27, 27]}[order]
    s = 1j * omega
    h = coeffs[-1] / np.polyval(coeffs, s)
    dt = 1e-3
    f = TrajectoryFilter(order, 3.0, dt)
    f.reset(0.0)
    n = round(40.0 / dt)
    t = np.arange(n) * dt
    y = np.empty(n)
    for k in range(n):
        f.step(math.sin(omega * t[k]))
        y[k] = f.wd
    late = t > 20.0  # transients gone (e^{-3·20})
    tt = t[late] + dt  # the output after a step belongs to the end of the period
    # least squares for A sin + B cos: the measured gain and phase
    m = np.column_stack((np.sin(omega * tt), np.cos(omega * tt)))
    (a, b), *_ = np.linalg.lstsq(m, y[late], rcond=None)
    measured = complex(a, b)
    # zero-order-hold input: the exact discretisation sees the held sine, a lag of dt/2
    assert abs(measured) == pytest.approx(abs(h), rel=2e-3)
    assert np.angle(measured) == pytest.approx(np.angle(h) - omega * dt / 2, abs=2e-3)


def test_derivative_outputs_are_consistent_with_wd() -> None:
    dt = 1e-3
    f = TrajectoryFilter(4, 3.0, dt)
    f.reset(0.0)
    wd, ad, jd = [], [], []
    for k in range(4000):
        f.step(1.0 if k < 1500 else 3.0)
        wd.append(f.wd)
        ad.append(f.ad)
        jd.append(f.jd)
    wd_, ad_, jd_ = map(np.array, (wd, ad, jd))
    assert np.max(np.abs(np.gradient(wd_, dt)[5:-5] - ad_[5:-5])) < 2e-3
    assert np.max(np.abs(np.gradient(ad_, dt)[5:-5] - jd_[5:-5])) < 2e-2


def test_reset_is_bumpless() -> None:
    f = TrajectoryFilter(4, 3.0, 1e-3)
    f.reset(2.0)
    f.step(2.0)
    assert (f.wd, f.ad, f.jd) == pytest.approx((2.0, 0.0, 0.0), abs=1e-15)
