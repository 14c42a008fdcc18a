"""The paper's two experiments (Section VI) as session configurations.

Both: J = 0.1 kg·m², controller B (RISE), filter (32), a 1.5 s start delay, the numerical
seeker of Appendix A.
- Exp. 1: bracket 1, 2.5, 4; the seeker is fed the surrogate (31), maximal at 3 rad/s; the
  person on the handle is the linear user τ = 2(1 - w/6), whose true power *is* (31).
  Gains ks = 1, β1+β2 = 0.05, αr = 0.05.
- Exp. 2: bracket 1, 3.5, 6; the seeker is fed τ̂·wd from the observer (28); the person is a
  Hill user (τ0 = 3 N·m, wmax = 10 rad/s, a = 0.25: w* ≈ 3.09 rad/s). Gains ks = 2,
  β1+β2 = 0.1, αr = 0.1.
``paper=True`` uses the paper's gains and its measurement (13), p = τ̂·wd^ρ at the mean of wd,
and stops when the search does (no track phase), as the paper did; otherwise ergoseek's default
controller gains, measurement and seeker settings, with the experiment's bracket, filter and
delay.
"""

from __future__ import annotations

from typing import Any, Literal

from sessions.config import ControllerConfig, SessionConfig, parse_session_config

ExperimentName = Literal["exp1", "exp2"]

PAPER_GAINS: dict[str, dict[str, float]] = {
    "exp1": {"ks": 1.0, "beta": 0.05, "alpha_r": 0.05},
    "exp2": {"ks": 2.0, "beta": 0.1, "alpha_r": 0.1},
}
USERS: dict[str, dict[str, Any]] = {
    "exp1": {"kind": "linear", "tau0": 2.0, "wmax": 6.0},
    "exp2": {"kind": "hill", "tau0": 3.0, "wmax": 10.0, "curvature": 0.25},
}
BRACKETS: dict[str, list[float]] = {"exp1": [1.0, 2.5, 4.0], "exp2": [1.0, 3.5, 6.0]}


def experiment(
    name: ExperimentName, *, paper: bool = True, seeker: str = "parabolic", duration: float = 60.0
) -> SessionConfig:
    gains = (
        PAPER_GAINS[name]
        if paper
        else ControllerConfig().model_dump(include={"ks", "beta", "alpha_r"})
    )
    return parse_session_config(
        {
            "duration": duration,
            "rate": 1000.0,
            "seed": 1,
            "machine": {"inertia": 0.1},
            "user": USERS[name],
            "controller": {"kind": "rise", **gains},
            "seeker": {
                "kind": seeker,
                "bracket": BRACKETS[name],
                "objective": "surrogate" if name == "exp1" else "power",
                "filter": {"order": 4, "pole": 3.0},
                "start_delay": 1.5,
                **({"measure": "desired", "track": False} if paper else {}),
            },
        }
    )
