"""The perturbation seeker is eq. (14): checked against an independent integration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sessions.config import SeekerConfig
from sessions.seekers import make_seeker
from sessions.seekers.perturbation import PerturbationSeeker


def power(w: float) -> float:
    return 3.0 - (w - 3.0) ** 2 / 3.0  # the surrogate (31), a static map p(wd)


@pytest.mark.parametrize("alpha_f", [0.0, 0.05])
def test_theta_follows_equation_14_integrated_independently(alpha_f: float) -> None:
    dt = 1e-3
    cfg = SeekerConfig(
        kind="perturbation",
        bracket=(1.0, 2.0, 6.0),
        start_delay=0.0,
        alpha_f=alpha_f,
        max_evaluations=1000,
        saturation=4.0,  # sat(p) = 4 tanh(p/4): a saturation that bends at these powers
    )
    seeker = make_seeker(cfg, dt, 15.0)
    assert isinstance(seeker, PerturbationSeeker)
    seeker.begin(2.0)  # at rest at γ2: (14) starts at once
    n = int(60.0 / dt)
    theta = np.empty(n)
    for k in range(n):
        t = k * dt
        seeker.tell(t, 0.0, power(seeker.wd), 0.0)
        theta[k] = seeker.theta
    t0, period = seeker.t_es, seeker.period
    ae, w, big = cfg.amplitude, cfg.omega, cfg.saturation

    def amp(t: float) -> float:
        x = min(max((t - t0) / period, 0.0), 1.0)
        return ae * x * x * (3.0 - 2.0 * x)  # the ramp-in over one period

    def rhs(t: float, y: np.ndarray) -> list[float]:
        th, kappa, eta = y
        d = amp(t) * math.sin(w * (t - t0))
        sp = big * math.tanh(power(th + d) / big)
        return [
            -cfg.alpha_f * th + kappa,
            -cfg.alpha0 * kappa + cfg.alpha0 * cfg.kf1 * (sp - eta) * d,
            -cfg.kf2 * eta + cfg.kf2 * sp,
        ]

    y0 = [2.0, 0.0, big * math.tanh(power(2.0) / big)]
    ts = np.arange(n) * dt + dt  # θ after the step at t is θ(t + dt)
    sol = solve_ivp(rhs, (0.0, ts[-1]), y0, t_eval=ts, rtol=1e-9, atol=1e-11, max_step=0.01)
    assert sol.success
    assert np.max(np.abs(theta - sol.y[0])) < 2e-3  # forward Euler at 1 kHz: O(dt)
    assert abs(theta[-1] - 2.0) > 0.2  # and θ did move: the comparison is not of constants
