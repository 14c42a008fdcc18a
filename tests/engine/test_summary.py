"""A session's summary, from the loop that ran it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from sessions.config import parse_session_config
from sessions.loop import Loop
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.simulation import run_simulation
from sessions.summary import SessionSummary, summarize


def test_summary_of_a_simulated_session_matches_its_record() -> None:
    cfg = parse_session_config({"duration": 40.0, "seeker": {"kind": "brent"}})
    user = SimulatedUser(cfg.user, cfg.dt, cfg.seed)
    plant, loop = Plant(cfg.machine.inertia), Loop(cfg)
    loop.begin(plant.q, plant.w)
    rows = []
    for _ in range(round(cfg.duration * cfg.rate)):
        u = loop.step(plant.q, plant.w, plant.sample_torque(user))
        rows.append(loop.row)
        plant.advance(u, cfg.dt, user)
        user.advance(cfg.dt)
    s = summarize(loop)
    assert s.duration == pytest.approx(40.0)
    assert s.converged and s.seeker == "brent"
    assert s.optimum_w == pytest.approx(user.w_star(), rel=0.05)
    assert s.evaluations == len(loop.seeker.evaluations)
    assert s.work == pytest.approx(rows[-1][8])
    mech = [r[6] * r[2] for r in rows]  # τ̂·w
    assert s.mean_power == pytest.approx(sum(mech) / len(mech))
    assert s.peak_power == pytest.approx(max(mech))
    assert s.regret is None  # a loop without the person's truth: real hardware


def test_regret_and_the_new_fields_against_the_truth_from_telemetry() -> None:
    # regret = 1 - ∫p(w(t),t)dt / ∫p*(t)dt after the start delay, recomputed here from the
    # full-rate telemetry and the user's own curve (the loop samples it every 10 ms)
    cfg = parse_session_config(
        {"duration": 60.0, "user": {"kind": "hill", "fatigue_tau": 300.0}, "seeker": {}}
    )
    r = run_simulation(cfg)
    s = r.summary
    assert s is not None
    t, w = r.column("t"), r.column("w")
    after = t >= cfg.seeker.start_delay
    p = np.array(
        [
            r.user.true_power(float(x), 1.0, float(tt))
            for x, tt in zip(w[after], t[after], strict=True)
        ]
    )
    best = np.array([r.user.optimum(1.0, float(tt))[1] for tt in t[after]])
    assert s.regret == pytest.approx(1.0 - p.sum() / best.sum(), abs=2e-4)
    gamma = r.column("gamma")
    assert s.target_min == pytest.approx(gamma.min()) and s.target_max == pytest.approx(gamma.max())
    assert s.converged and s.at_bound is None
    assert 0.0 < s.t_converged < 60.0
    at = r.user.power_ratio(np.array([s.wd_converged]), np.array([s.t_converged]))[0]
    assert at >= 0.99  # the optimum first found: within the person's 99 % band
    assert s.optimum_t == pytest.approx(60.0)


def test_a_summary_stored_before_the_new_fields_still_parses() -> None:
    old = {
        "optimum_w": 3.1, "optimum_p": 2.86, "converged": True, "seeker": "brent",
        "mean_power": 2.5, "peak_power": 3.0, "work": 150.0, "duration": 60.0,
        "passivity_min": 0.0, "evaluations": 9, "abort_reason": None,
    }  # fmt: skip
    s = SessionSummary.model_validate(old)
    assert s.regret is None and s.at_bound is None and s.t_converged is None
    assert SessionSummary.model_validate_json(s.model_dump_json()) == s  # a round trip


@pytest.mark.parametrize(
    "bad",
    [
        {"duration": -1.0},
        {"optimum_p": math.nan},
        {"mean_power": math.inf},
        {"evaluations": -3},
        {"regret": 1.5},
        {"at_bound": "sideways"},
        {"t_converged": -1.0},
        {"wd_converged": 0.0},
    ],
)
def test_summary_rejects_impossible_values(bad: dict[str, float]) -> None:
    with pytest.raises(ValidationError):
        SessionSummary(**bad)  # type: ignore[arg-type]


def test_regret_is_taken_at_the_actual_velocity() -> None:
    # a person far stronger than the motor (τ0 = 20 N·m against a 1 N·m limit): the handle
    # runs away from wd to where the person's torque falls to the motor's (7.9 rad/s, 2.6 w*).
    # The regret at the actual velocity says so; at wd it would look like a fair session.
    cfg = parse_session_config(
        {"duration": 20.0, "machine": {"max_torque": 1.0}, "user": {"tau0": 20.0, "wmax": 10.0}}
    )
    r = run_simulation(cfg)
    assert r.summary is not None and r.summary.regret is not None
    t, wd = r.column("t"), r.column("wd")
    after = t >= cfg.seeker.start_delay
    at_wd = 1.0 - float(np.mean(r.user.power_ratio(wd[after], t[after])))
    assert r.summary.regret > 0.5
    assert at_wd < 0.3
