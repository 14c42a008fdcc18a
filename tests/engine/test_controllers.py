"""Controllers A (7) and B (23) with the observer (28), against the paper's closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sessions.config import UserConfig, parse_session_config
from sessions.controllers import MeasuredTorqueController, RiseController
from sessions.loop import Loop
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.simulation import run_simulation


@pytest.mark.parametrize("kind", ["hill", "linear"])
@pytest.mark.parametrize("k", [0.5, 1.0, 3.0])
def test_controller_a_error_decays_as_equation_9(kind: str, k: float) -> None:
    # (8): J ė = -k e, so e(t) = e(0) exp(-k t / J), whatever the user torque (it is cancelled).
    J, dt, wd = 0.1, 1e-3, 3.0
    user = SimulatedUser(UserConfig(kind=kind), dt, seed=0)
    plant = Plant(J, w0=wd + 1.5)
    ctrl = MeasuredTorqueController(k, J)
    e0 = plant.w - wd
    worst = 0.0
    for n in range(1000):
        tau = plant.sample_torque(user)
        e = plant.w - wd
        worst = max(worst, abs(e - e0 * math.exp(-k * n * dt / J)))
        plant.advance(ctrl.command(e, 0.0, tau), dt, user)
    # the only departure is the zero-order hold of u: O(k dt / J) of e(0)
    assert worst <= 0.6 * (k * dt / J) * abs(e0) + 1e-12


@given(
    e0=st.floats(-5, 5), ad0=st.floats(-10, 10), ks=st.floats(0.1, 20), alpha=st.floats(0.01, 10)
)
@settings(max_examples=60, deadline=None)
def test_rise_starts_from_zero_torque(e0: float, ad0: float, ks: float, alpha: float) -> None:
    # The bracket of (23) makes u(t0) = 0 for any initial error and acceleration.
    ctrl = RiseController(ks, 0.1, alpha, 0.1)
    ctrl.begin(e0, ad0)
    assert ctrl.command(e0, ad0, math.nan) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("kind", ["sweep", "brent", "perturbation", "fixed"])
def test_loop_begin_makes_rise_start_from_zero_torque(
    kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Through Loop.begin, whatever the seeker's reference at t0: a seeker that starts in
    # motion (wd ≠ w0, ad ≠ 0) must still give u(t0) = 0, the bracket of (23) taking e(t0)
    # and ad(t0) from the seeker as it began.
    cfg = parse_session_config({"controller": {"kind": "rise"}, "seeker": {"kind": kind}})
    loop = Loop(cfg)
    seeker = loop.seeker
    plain = type(seeker).begin

    def in_motion(self, w0: float) -> None:
        plain(self, w0)
        self.wd, self.ad = 0.5, 1.3

    monkeypatch.setattr(type(seeker), "begin", in_motion)
    loop.begin(0.0, 2.0)
    assert loop.step(0.0, 2.0) == pytest.approx(0.0, abs=1e-12)
    assert loop.value("wd") == 0.5 and loop.value("ad") == 1.3  # the step saw the motion


@pytest.mark.parametrize("ad", [-2.0, 1.5, 4.0])
def test_controller_a_tracks_an_accelerating_reference_as_equation_9(ad: float) -> None:
    # (7) u = -k e + J ad - τ: the J·ad term makes J ė = -k e hold while wd accelerates, so
    # e(t) = e(0) exp(-k t / J) along a ramp too (a sign error in J·ad leaves e → ∓2J ad/k).
    J, dt, k = 0.1, 1e-3, 1.0
    user = SimulatedUser(UserConfig(kind="linear", tau0=2.0, wmax=40.0), dt, seed=0)
    wd0 = 8.0
    plant = Plant(J, w0=wd0 + 0.5)
    ctrl = MeasuredTorqueController(k, J)
    worst = 0.0
    for n in range(1500):
        t = n * dt
        wd = wd0 + ad * t
        tau = plant.sample_torque(user)
        e = plant.w - wd
        worst = max(worst, abs(e - 0.5 * math.exp(-k * t / J)))
        plant.advance(ctrl.command(e, ad, tau), dt, user)
    assert worst <= 0.6 * (k * dt / J) * 0.5 + 0.5 * abs(ad) * dt + 1e-9


def test_rise_anti_windup_holds_the_integral_while_the_torque_is_clamped() -> None:
    # The applied u is clamped below the command: the integrals must not grow further in
    # the direction that pushed it there (else u stays saturated long after the error clears).
    ctrl = RiseController(4.0, 0.5, 4.0, 0.1)
    ctrl.begin(0.0, 0.0)
    dt = 1e-3
    e = 1.0  # w above wd: (23) commands braking, more and more as the integral grows
    for _ in range(2000):
        u_cmd = ctrl.command(e, 0.0, math.nan)
        u = max(u_cmd, -2.0)  # the torque limit
        ctrl.commit(e, 0.0, math.nan, u, u_cmd, dt)
    held = ctrl.integral
    assert ctrl.command(e, 0.0, math.nan) == pytest.approx(-5.0 - held)
    # clamped from the first period on, so the integral never grew towards more braking
    assert held == pytest.approx(0.0, abs=1e-12)
    # without the clamp it grows by (ks+1)αr e + β per second
    free = RiseController(4.0, 0.5, 4.0, 0.1)
    free.begin(0.0, 0.0)
    for _ in range(1000):
        u_cmd = free.command(e, 0.0, math.nan)
        free.commit(e, 0.0, math.nan, u_cmd, u_cmd, dt)
    assert free.integral == pytest.approx(5.0 * 4.0 * 1.0 + 0.5, rel=1e-9)


@pytest.mark.parametrize("gains", [(4.0, 0.5, 4.0), (2.0, 0.1, 0.1)])
def test_rise_observer_converges_to_the_user_torque(gains: tuple[float, float, float]) -> None:
    # Lemma 1: τ - τ̂ → 0. Hold a setpoint and compare τ̂ with the true τ at the end.
    ks, beta, alpha = gains
    cfg = parse_session_config(
        {
            "duration": 40.0,
            "controller": {"kind": "rise", "ks": ks, "beta": beta, "alpha_r": alpha},
            "seeker": {"kind": "fixed", "setpoint": 3.0},
        }
    )
    result = run_simulation(cfg)
    last = slice(-2000, None)  # the last 2 s
    w = result.column("w")[last]
    tau_true = np.array([result.user.torque(0.0, float(x)) for x in w])
    err = result.column("tau")[last] - tau_true
    assert abs(err.mean()) < 1e-4 * tau_true.mean()
    # what remains is the chatter of the sgn integral: τ - τ̂ = J ė, small with β
    assert np.abs(err).max() < 0.01 * beta + 1e-4
    assert np.abs(w - 3.0).max() < 1e-3  # and e → 0 (Theorem 3)
