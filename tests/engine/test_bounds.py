"""The trainer's bracket is a hard bound, an edge is not an optimum, and nothing non-finite
reaches a target: for every seeker, over random people, brackets and optima."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sessions.config import parse_session_config
from sessions.loop import Loop
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.simulation import run_simulation, score

SEEKERS = ["sweep", "brent", "parabolic", "perturbation"]
HILL_77 = {"kind": "hill", "tau0": 3.0, "wmax": 7.7 / 0.30902}  # w* = 7.7 rad/s


def table(w_star: float, width: float, skew: float) -> list[list[float]]:
    """A measured-looking curve: power exp(-x²/2s²) on x = ln(w/w*), s = width (·skew above)."""
    w = np.linspace(0.15, 3.0, 40) * w_star
    x = np.log(w / w_star)
    s = np.where(x < 0, width, width * skew)
    tau = 4.0 * np.exp(-(x**2) / (2 * s**2)) / w * w_star
    return [[0.0, float(tau[0])]] + [[float(a), float(b)] for a, b in zip(w, tau, strict=True)]


@st.composite
def sessions_(draw: st.DrawFn) -> dict:
    w_star = draw(st.floats(1.5, 8.0))
    user = {
        "kind": "table",
        "points": table(w_star, draw(st.floats(0.15, 0.8)), draw(st.floats(0.4, 2.5))),
        "noise": draw(st.floats(0.0, 0.06)),
        "ripple": draw(st.floats(0.0, 0.2)),
    }
    lo = draw(st.floats(0.3, 10.0))
    hi = lo * draw(st.floats(1.15, 4.0))
    guess = lo + (hi - lo) * draw(st.floats(0.02, 0.98))
    return {
        "duration": 25.0,
        "rate": 250.0,
        "seed": draw(st.integers(0, 1000)),
        "machine": {"max_velocity": max(15.0, 1.2 * hi)},
        "user": user,
        "seeker": {"bracket": [lo, guess, hi], "start_delay": 1.0},
    }


@pytest.mark.parametrize("seeker", SEEKERS)
@given(data=sessions_())
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_targets_never_leave_the_bracket(seeker: str, data: dict) -> None:
    data["seeker"]["kind"] = seeker
    cfg = parse_session_config(data)
    lo, _, hi = cfg.seeker.bracket
    result = run_simulation(cfg)
    gamma, wd = result.column("gamma"), result.column("wd")
    assert gamma.min() >= lo - 1e-9 and gamma.max() <= hi + 1e-9
    assert wd.max() <= hi + 1e-9  # the reference too: it rises from rest towards the bracket
    s = score(result)
    assert lo - 1e-9 <= s["target_min"] <= s["target_max"] <= hi + 1e-9
    if s["at_bound"] is not None:
        assert not s["converged"]


@pytest.mark.parametrize("seeker", SEEKERS)
@pytest.mark.parametrize(
    ("user", "bracket", "side", "edge"),
    [
        (HILL_77, [1.0, 3.5, 6.0], "upper", 6.0),  # the case: parabolic went to 7.72
        (HILL_77, [1.0, 2.0, 3.0], "upper", 3.0),
        ({"kind": "hill"}, [5.0, 6.0, 9.0], "lower", 5.0),  # w* = 3.09 below the bracket
    ],
)
def test_an_optimum_beyond_the_bracket_is_reported_at_the_bound(
    seeker: str, user: dict, bracket: list[float], side: str, edge: float
) -> None:
    cfg = parse_session_config(
        {
            "duration": 90.0,
            "rate": 500.0,
            "user": user,
            "seeker": {"kind": seeker, "bracket": bracket},
        }
    )
    result = run_simulation(cfg)
    s = score(result)
    assert s["target_max"] <= bracket[2] + 1e-9 and s["target_min"] >= bracket[0] - 1e-9
    assert s["at_bound"] == side, s["stop_reason"]
    assert not s["converged"]  # an edge is never stored as the user's optimum
    # (14)'s θ stays one dither amplitude inside, so that wd = θ + ae sin ωt never leaves
    dither = cfg.seeker.amplitude if seeker == "perturbation" else 0.0
    assert s["optimum_w"] == pytest.approx(edge, abs=0.03 * edge + dither)


def test_expand_moves_the_bound_in_steps_up_to_its_limit() -> None:
    cfg = parse_session_config(
        {
            "duration": 120.0,
            "rate": 500.0,
            "user": HILL_77,
            "seeker": {"bracket": [1.0, 3.5, 6.0], "expand": True, "expand_limit": [1.0, 9.0]},
        }
    )
    s = score(run_simulation(cfg))
    assert s["at_bound"] is None and s["converged"]
    assert s["target_max"] <= 9.0 + 1e-9
    assert s["optimum_w"] == pytest.approx(7.7, rel=0.03)
    # a limit short of the optimum: the search ends at the limit, and says so
    tight = cfg.model_copy(
        update={"seeker": cfg.seeker.model_copy(update={"expand_limit": (1.0, 7.0)})}
    )
    s = score(run_simulation(tight))
    assert s["target_max"] <= 7.0 + 1e-9
    assert s["at_bound"] == "upper" and s["optimum_w"] == pytest.approx(7.0, rel=0.01)


def test_expand_needs_a_limit_that_contains_the_bracket() -> None:
    from sessions.config import ScenarioError

    with pytest.raises(ScenarioError, match=r"seeker\.expand_limit: required"):
        parse_session_config({"seeker": {"expand": True}})
    with pytest.raises(ScenarioError, match=r"seeker\.expand_limit: must contain"):
        parse_session_config({"seeker": {"expand": True, "expand_limit": [2.0, 5.0]}})


@pytest.mark.parametrize("seeker", SEEKERS)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_power_never_reaches_a_target(seeker: str, bad: float) -> None:
    cfg = parse_session_config(
        {
            "duration": 20.0,
            "rate": 500.0,
            "controller": {"kind": "measured"},  # (7) uses the measured τ: p = τ·w^ρ
            "seeker": {"kind": seeker},
        }
    )
    lo, _, hi = cfg.seeker.bracket
    user = SimulatedUser(cfg.user, cfg.dt, cfg.seed)
    plant, loop = Plant(cfg.machine.inertia), Loop(cfg)
    loop.begin(plant.q, plant.w)
    for k in range(round(cfg.duration * cfg.rate)):
        tau = plant.sample_torque(user)
        if 3000 <= k < 3050 or k % 997 == 0:  # a burst, then now and then
            tau = bad  # a broken torque sensor: τ, and so p, non-finite
        u = loop.step(plant.q, plant.w, tau)
        assert math.isfinite(u)
        s = loop.seeker
        assert math.isfinite(s.target) and lo <= s.target <= hi
        assert all(math.isfinite(v) for v in (s.wd, s.ad, s.jd))
        plant.advance(u, cfg.dt, user)
        user.advance(cfg.dt)
    assert loop.fault is not None and "non-finite" in loop.fault
    assert loop.seeker.nonfinite > 0
