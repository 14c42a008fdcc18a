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


def test_rise_loop_starts_from_zero_torque_with_an_initial_error() -> None:
    cfg = parse_session_config({"controller": {"kind": "rise"}})
    loop = Loop(cfg)
    loop.begin(0.0, 2.0)
    loop.seeker.filter.reset(0.5)  # a reference away from the machine's velocity
    loop.seeker.wd = loop.reference.wd = 0.5  # the loop reads the runner's reference
    loop.controller.begin(2.0 - 0.5, 0.0)
    assert loop.step(0.0, 2.0) == pytest.approx(0.0, abs=1e-12)


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
