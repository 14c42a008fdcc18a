"""Sessions for the export tests and benchmarks: a real simulation run (Hill user with noise and
ripple, RISE, brent), and the same telemetry tiled into a long session at full rate."""

from __future__ import annotations

import numpy as np

from sessions.config import SessionConfig
from sessions.simulation import SimulationResult, run_simulation
from sessions.telemetry import INDEX, NAMES


def simulated_session(duration: float = 60.0, seed: int = 1, **user: object) -> SimulationResult:
    """A simulated session with the default controller and seeker; the user is a Hill user
    with 3 % noise and 10 % ripple unless ``user`` says otherwise."""
    traits = {"kind": "hill", "noise": 0.03, "ripple": 0.1} | user
    cfg = SessionConfig.model_validate({"duration": duration, "seed": seed, "user": traits})
    return run_simulation(cfg)


def tiled(rows: np.ndarray, repeats: int) -> dict[str, np.ndarray]:
    """``rows`` (samples, channels) repeated ``repeats`` times end to end as one session's
    columns: time runs on, the angle and the passivity integral continue from where each copy
    ended, the other channels repeat."""
    n = rows.shape[0]
    dt = float(rows[1, INDEX["t"]] - rows[0, INDEX["t"]])
    cols = {name: np.tile(rows[:, INDEX[name]], repeats) for name in NAMES}
    copy = np.repeat(np.arange(repeats), n)
    cols["t"] = np.arange(n * repeats) * dt
    q, W = rows[:, INDEX["q"]], rows[:, INDEX["W"]]
    cols["q"] = cols["q"] + copy * (q[-1] - q[0] + rows[-1, INDEX["w"]] * dt)
    cols["W"] = cols["W"] + copy * W[-1]
    return cols
