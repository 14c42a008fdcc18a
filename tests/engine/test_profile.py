"""The velocity-spectrum test: its plan, and the profile fitted to what real simulated people
(sessions/people.py) produce at isokinetic velocities, against their known truth."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from sessions.config import ControllerConfig, FilterConfig, UserConfig
from sessions.controllers import make_controller
from sessions.filters import TrajectoryFilter
from sessions.limits import Limits
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.profile import (
    ProfileError,
    ProfilePlan,
    StepSamples,
    fit_profile,
    plan_profile,
    step_samples,
)

DT = 1e-3
BRACKET = (1.0, 6.0)


def isokinetic(user: SimulatedUser, plan: ProfilePlan) -> list[StepSamples]:
    """An ideal isokinetic machine: the handle turns at exactly each step's velocity while
    the person's torque (noise, ripple and all) is sampled every period; the person's noise
    runs on through the settling part, which is not kept."""
    steps, q = [], 0.0
    for s in plan.steps:
        skip, n = round((s.settled - s.start) / DT), round((s.end - s.start) / DT)
        tau, qs = np.empty(n - skip), np.empty(n - skip)
        for k in range(n):
            if k >= skip:
                tau[k - skip], qs[k - skip] = user.torque(q, s.velocity), q
            user.advance(DT)
            q += s.velocity * DT
        steps.append(StepSamples(s.velocity, tau, np.full(n - skip, s.velocity), qs))
    return steps


def hill(seed: int = 1, **kw: object) -> SimulatedUser:
    traits = {"kind": "hill", "tau0": 3.0, "wmax": 10.0, "curvature": 0.25} | kw
    return SimulatedUser(UserConfig.model_validate(traits), DT, seed)


def truth(user: SimulatedUser) -> dict[str, float]:
    w_star, p_star = user.optimum()
    return {"tau0": user.tau0, "wmax": user.wmax, "w_opt": w_star, "pmax": p_star}


# -- the plan --------------------------------------------------------------------------------
def test_plan_is_pure_spans_the_bracket_and_steps_follow_each_other() -> None:
    plan = plan_profile(BRACKET, 8, 8.0)
    assert plan == plan_profile(BRACKET, 8, 8.0)
    assert [s.velocity for s in plan.steps] == pytest.approx(np.linspace(1.0, 6.0, 8))
    assert plan.steps[0].start == 0.0
    for a, b in zip(plan.steps, plan.steps[1:], strict=False):
        assert b.start == a.end
    for s in plan.steps:
        assert s.start < s.settled < s.end
        turns = (s.end - s.settled) * s.velocity / (2 * math.pi)
        assert turns == pytest.approx(round(turns), abs=1e-9) and round(turns) >= 1
        assert s.end - s.start >= 8.0 - 1e-9
        assert plan.velocity_at(0.5 * (s.settled + s.end)) == s.velocity
    assert plan.velocity_at(plan.duration) is None
    json.dumps(plan.to_dict())


@pytest.mark.parametrize("filt", [FilterConfig(), FilterConfig(order=3, pole=5.0)])
def test_settling_is_where_the_real_filter_reaches_the_tolerance(filt: FilterConfig) -> None:
    """Independent truth: the trajectory filter (32)/(33) itself, stepped at 1 kHz."""
    tol = 0.02
    plan = plan_profile(BRACKET, 5, 6.0, order="interleaved", tolerance=tol, filt=filt)
    f = TrajectoryFilter(filt.order, filt.pole, DT)
    f.reset(0.0)
    k = 0
    for s in plan.steps:
        inside = None
        while k * DT < s.end - 1e-12:
            if inside is None and k * DT >= s.start and abs(f.wd - s.velocity) <= tol:
                inside = k * DT
            f.step(s.velocity)
            k += 1
        assert inside is not None
        assert inside - s.start == pytest.approx(s.settled - s.start, abs=2 * DT)


def test_orders() -> None:
    v = np.linspace(1.0, 6.0, 7).tolist()

    def velocities(**kw: object) -> list[float]:
        return [s.velocity for s in plan_profile(BRACKET, 7, 6.0, **kw).steps]  # type: ignore[arg-type]

    assert velocities(order="descending") == pytest.approx(v[::-1])
    assert velocities(order="interleaved") == pytest.approx([v[i] for i in (0, 6, 1, 5, 2, 4, 3)])
    r1 = velocities(order="random", seed=4)
    assert r1 == velocities(order="random", seed=4)
    assert sorted(r1) == pytest.approx(v) and r1 != pytest.approx(v)
    assert r1 != velocities(order="random", seed=5)


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"bracket": (6.0, 1.0)}, "bracket"),
        ({"bracket": (2.0, 2.0)}, "bracket"),
        ({"bracket": (math.nan, 3.0)}, "bracket[0]"),
        ({"bracket": (0.0, 3.0)}, "bracket[0]"),
        ({"count": 2}, "count"),
        ({"hold": 0.0}, "hold"),
        ({"order": "sideways"}, "order"),
        ({"tolerance": -1.0}, "tolerance"),
    ],
)
def test_plan_rejects_bad_input(kwargs: dict[str, object], named: str) -> None:
    args = {"bracket": BRACKET} | kwargs
    with pytest.raises(ProfileError, match="^" + re.escape(named)):
        plan_profile(**args)  # type: ignore[arg-type]


# -- the fit: closed forms on noiseless people -----------------------------------------------
def test_linear_user_recovered_exactly_without_noise() -> None:
    """τ = τ0 (1 - w/wmax) with τ0 = 2, wmax = 6 is the paper's surrogate (31): the closed
    form gives τ0, wmax, w_opt = wmax/2 = 3 and Pmax = τ0 wmax/4 = 3 exactly."""
    user = SimulatedUser(UserConfig(kind="linear", tau0=2.0, wmax=6.0), DT, 1)
    fit = fit_profile(isokinetic(user, plan_profile(BRACKET, 6, 4.0)))
    assert fit.model == "linear"
    for name, value in {"tau0": 2.0, "wmax": 6.0, "w_opt": 3.0, "pmax": 3.0}.items():
        est = getattr(fit, name)
        assert est.value == pytest.approx(value, rel=1e-12), name
        assert est.high - est.low == pytest.approx(0.0, abs=1e-9), name


def test_hill_user_recovered_without_noise() -> None:
    user = hill()
    fit = fit_profile(isokinetic(user, plan_profile(BRACKET, 6, 4.0)))
    assert fit.model == "hill"
    assert fit.a is not None and fit.a.value == pytest.approx(0.25, rel=1e-6)
    for name, value in truth(user).items():
        assert getattr(fit, name).value == pytest.approx(value, rel=1e-6), name
    c = fit.curve
    assert c.tau[0] == pytest.approx(3.0, rel=1e-6)
    assert c.power.max() == pytest.approx(fit.pmax.value, rel=1e-4)
    assert c.w[np.argmax(c.power)] == pytest.approx(fit.w_opt.value, abs=c.w[1] - c.w[0])


# -- the fit: real people with noise and ripple ----------------------------------------------
TOLERANCE = {"tau0": 0.05, "wmax": 0.05, "w_opt": 0.02, "pmax": 0.02}  # relative, 3 % noise


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("order", ["ascending", "interleaved"])
def test_hill_user_with_noise_and_ripple_within_tolerances(seed: int, order: str) -> None:
    user = hill(seed, noise=0.03, ripple=0.1)
    fit = fit_profile(isokinetic(user, plan_profile(BRACKET, 8, 6.0, order=order)))  # type: ignore[arg-type]
    assert fit.model == "hill"
    for name, value in truth(user).items():
        assert getattr(fit, name).value == pytest.approx(value, rel=TOLERANCE[name]), name


def test_other_people_and_brackets() -> None:
    """Not the numbers of the issue: a stronger, less curved person on a wider bracket, and
    a linear one (the F-test keeps the straight line)."""
    strong = hill(7, tau0=20.0, wmax=15.0, curvature=0.4, noise=0.03, ripple=0.05)
    fit = fit_profile(isokinetic(strong, plan_profile((2.0, 9.0), 8, 6.0)))
    assert fit.model == "hill"
    for name, value in truth(strong).items():
        assert getattr(fit, name).value == pytest.approx(value, rel=TOLERANCE[name]), name
    lin = SimulatedUser(UserConfig(kind="linear", tau0=10.0, wmax=12.0, noise=0.03), DT, 3)
    fit = fit_profile(isokinetic(lin, plan_profile((1.0, 8.0), 8, 6.0)))
    assert fit.model == "linear" and fit.a is None
    for name, value in truth(lin).items():
        assert getattr(fit, name).value == pytest.approx(value, rel=TOLERANCE[name]), name


def test_the_angle_removes_a_ripple_the_window_does_not_average_out() -> None:
    """Windows of 1.5-5 turns (not whole) under a strong ripple (30 %): the whole-turn cut and
    the first-harmonic regression keep the optimum; the plain mean of the same samples
    (without q) is off by more than 5 %."""
    plan = plan_profile((2.0, 6.0), 8, 8.0, min_revolutions=0)
    for seed in (0, 1, 3):
        user = hill(seed, noise=0.03, ripple=0.3)
        steps = isokinetic(user, plan)
        w_opt = truth(user)["w_opt"]
        assert fit_profile(steps).w_opt.value == pytest.approx(w_opt, rel=TOLERANCE["w_opt"])
        blind = fit_profile([StepSamples(s.velocity, s.tau, s.w) for s in steps])
        assert abs(blind.w_opt.value / w_opt - 1) > 0.05
    short = plan_profile((2.0, 6.0), 4, 4.0, min_revolutions=0)
    fit = fit_profile(isokinetic(hill(1, ripple=0.1), short))
    assert any("less than one turn" in w for w in fit.warnings)


@pytest.mark.slow
def test_confidence_intervals_cover_the_truth_at_the_stated_rate() -> None:
    """100 sessions of a Hill person (3 % band-limited noise, 5 % ripple): each 95 % interval
    covers the truth in 88-99 of them (the binomial's 3σ band around 95 is 88.5-100; 100/100
    would say the intervals are too wide to be honest)."""
    plan = plan_profile(BRACKET, 8, 6.0)
    covered = dict.fromkeys(TOLERANCE, 0)
    runs = 100
    for seed in range(runs):
        user = hill(seed, noise=0.03, ripple=0.05)
        fit = fit_profile(isokinetic(user, plan))
        for name, value in truth(user).items():
            covered[name] += getattr(fit, name).covers(value)
    for name, hits in covered.items():
        assert 88 <= hits <= 99, (name, hits)


def closed_loop(user: SimulatedUser, plan: ProfilePlan) -> dict[str, np.ndarray]:
    """The plan run on the simulated machine (1) with the RISE controller (23) and its torque
    observer (28), the velocity stepping through the trajectory filter (32) as the protocol
    runner feeds it; returns full-rate t, q, w and τ̂."""
    inertia = 0.1
    plant, limits = Plant(inertia), Limits(20.0, 15.0)
    ctrl = make_controller(ControllerConfig(), inertia)
    filt = TrajectoryFilter(4, 3.0, DT)
    filt.reset(0.0)
    ctrl.begin(plant.w - filt.wd, filt.ad)
    n = round(plan.duration / DT)
    out = {k: np.empty(n) for k in ("t", "q", "w", "tau")}
    for k in range(n):
        t = k * DT
        tau = plant.sample_torque(user)
        e = plant.w - filt.wd
        u_cmd = ctrl.command(e, filt.ad, tau)
        u = limits.apply(u_cmd, plant.w)
        out["t"][k], out["q"][k], out["w"][k] = t, plant.q, plant.w
        out["tau"][k] = ctrl.commit(e, filt.ad, tau, u, u_cmd, DT)
        plant.advance(u, DT, user)
        user.advance(DT)
        filt.step(plan.velocity_at(t) or 0.0)
    return out


def test_closed_loop_with_the_torque_observer() -> None:
    """The whole path: the plan through the filter, RISE tracking, τ̂ from the observer, the
    telemetry cut into steps by ``step_samples``; the settling the plan allows is enough."""
    user = hill(11, noise=0.03, ripple=0.1)
    plan = plan_profile(BRACKET, 8, 6.0, order="interleaved")
    run = closed_loop(user, plan)
    steps = step_samples(plan, run["t"], run["tau"], run["w"], run["q"])
    for s, p in zip(steps, plan.steps, strict=True):
        assert np.abs(s.w - p.velocity).max() < 0.1  # isokinetic over the analysed window
    fit = fit_profile(steps)
    assert fit.model == "hill"
    for name, value in truth(user).items():
        assert getattr(fit, name).value == pytest.approx(value, rel=TOLERANCE[name]), name
    json.dumps(fit.to_dict())  # plain data for the API and the store


# -- bad input -------------------------------------------------------------------------------
def _good(n: int = 3) -> list[StepSamples]:
    user = hill()
    return isokinetic(user, plan_profile(BRACKET, max(n, 3), 4.0, min_revolutions=0))[:n]


def _replace(steps: list[StepSamples], i: int, **kw: object) -> list[StepSamples]:
    s = steps[i]
    fields = {"velocity": s.velocity, "tau": s.tau, "w": s.w, "q": s.q} | kw
    return [*steps[:i], StepSamples(**fields), *steps[i + 1 :]]  # type: ignore[arg-type]


def test_bad_steps_give_a_clear_error() -> None:
    good = _good(4)
    nan_tau = good[2].tau.copy()
    nan_tau[17] = math.nan
    cases = [
        (good[:2], r"^steps: need at least 3 steps, got 2"),
        (_replace(good, 2, tau=nan_tau), r"^steps\[2\]\.tau: not finite .* at sample 17"),
        (_replace(good, 1, w=good[1].w[:10]), r"^steps\[1\]\.w: must be 1-D"),
        (_replace(good, 0, velocity=-1.0), r"^steps\[0\]\.velocity"),
        (
            _replace(good, 3, tau=good[3].tau[:20], w=good[3].w[:20], q=None),
            r"^steps\[3\]\.tau: 20",
        ),
        ([good[0], good[0], good[0], good[1]], r"^steps: need at least 3 distinct velocities"),
    ]
    for steps, message in cases:
        with pytest.raises(ProfileError, match=message):
            fit_profile(steps)
    rising = [StepSamples(s.velocity, 1.0 + 0.1 * s.w, s.w) for s in good]
    with pytest.raises(ProfileError, match=r"^steps: torque does not fall with velocity"):
        fit_profile(rising)
    with pytest.raises(ProfileError, match=r"^confidence"):
        fit_profile(good, confidence=1.5)
    with pytest.raises(ProfileError, match=r"^model: Hill's law needs at least 4"):
        fit_profile(good[:3], model="hill")
