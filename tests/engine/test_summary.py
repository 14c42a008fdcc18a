"""A session's summary, from the loop that ran it."""

from __future__ import annotations

import math

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
    # the same session through run_simulation gives the same record
    again = run_simulation(cfg)
    assert again.column("W")[-1] == pytest.approx(s.work)


@pytest.mark.parametrize(
    "bad",
    [{"duration": -1.0}, {"optimum_p": math.nan}, {"mean_power": math.inf}, {"evaluations": -3}],
)
def test_summary_rejects_impossible_values(bad: dict[str, float]) -> None:
    with pytest.raises(ValidationError):
        SessionSummary(**bad)  # type: ignore[arg-type]
