"""The machine model (1) integrated by RK4, against closed-form solutions."""

from __future__ import annotations

import math

import pytest

from sessions.config import UserConfig
from sessions.people import SimulatedUser
from sessions.plant import Plant


def linear_user(tau0: float = 2.0, wmax: float = 6.0) -> SimulatedUser:
    return SimulatedUser(UserConfig(kind="linear", tau0=tau0, wmax=wmax), 1e-3, seed=0)


@pytest.mark.parametrize("u", [-1.0, -0.5, 0.0])
def test_linear_user_matches_the_exponential_solution(u: float) -> None:
    # J w' = τ0 (1 - w/wmax) + u is linear: w(t) = w∞ + (w0 - w∞) exp(-t τ0 / (wmax J)).
    J, tau0, wmax, w0, dt = 0.1, 2.0, 6.0, 1.0, 1e-3
    user = linear_user(tau0, wmax)
    plant = Plant(J, w0=w0)
    w_inf = wmax * (1.0 + u / tau0)
    rate = tau0 / (wmax * J)
    worst = 0.0
    for k in range(1, 2001):
        plant.sample_torque(user)
        plant.advance(u, dt, user)
        exact = w_inf + (w0 - w_inf) * math.exp(-rate * k * dt)
        worst = max(worst, abs(plant.w - exact))
    assert worst < 1e-9


def test_position_and_true_work_follow_the_same_solution() -> None:
    # q(t) = w∞ t + (w0 - w∞)(1 - e^{-rt})/r and W = ∫ τ w dt, both in closed form.
    J, tau0, wmax, w0, dt, u = 0.1, 2.0, 6.0, 0.5, 1e-3, -1.0
    user = linear_user(tau0, wmax)
    plant = Plant(J, w0=w0)
    w_inf = wmax * (1.0 + u / tau0)
    r = tau0 / (wmax * J)
    n = 1500
    for _ in range(n):
        plant.sample_torque(user)
        plant.advance(u, dt, user)
    t = n * dt
    q_exact = w_inf * t + (w0 - w_inf) * (1.0 - math.exp(-r * t)) / r
    assert plant.q == pytest.approx(q_exact, abs=1e-9)
    # τ w = τ0 (w - w²/wmax); integrate the exact w(t) numerically on a fine grid
    m = 200_000
    h = t / m
    work = 0.0
    for i in range(m):
        s = (i + 0.5) * h
        w = w_inf + (w0 - w_inf) * math.exp(-r * s)
        work += tau0 * (w - w * w / wmax) * h
    assert plant.user_work == pytest.approx(work, rel=1e-7)


def test_constant_velocity_needs_exactly_the_user_torque_back() -> None:
    # u = -τ(w) holds w: an invariant of (1) whatever the user law.
    user = SimulatedUser(UserConfig(kind="hill"), 1e-3, seed=0)
    plant = Plant(0.1, w0=3.0)
    for _ in range(1000):
        tau = plant.sample_torque(user)
        plant.advance(-tau, 1e-3, user)
    assert plant.w == pytest.approx(3.0, abs=1e-9)
    assert plant.q == pytest.approx(3.0, abs=1e-9)
