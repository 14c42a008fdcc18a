"""Sessions for the export tests and benchmarks: a real simulation run (Hill user with noise and
ripple, RISE, brent), and the same telemetry tiled into a long session at full rate."""

from __future__ import annotations

import math
from datetime import datetime
from typing import Any

import fitdecode
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


def decode_fit(data: bytes) -> dict[str, list[dict[str, Any]]]:
    """Every data message of a FIT file by name, fields by name (developer fields included),
    read by fitdecode (an independent decoder) with the header's and the file's CRC checked."""
    out: dict[str, list[dict[str, Any]]] = {}
    with fitdecode.FitReader(data, check_crc=fitdecode.CrcCheck.RAISE) as reader:
        for frame in reader:
            if isinstance(frame, fitdecode.FitDataMessage):
                out.setdefault(frame.name, []).append({f.name: f.value for f in frame.fields})
    return out


def record_bins(t: np.ndarray, start: datetime, interval: int = 1) -> list[tuple[int, np.ndarray]]:
    """docs/exports.md's rule, sample by sample: the record stamped T (POSIX s) holds the
    samples whose absolute time lies in [T - interval, T), boundaries counted from the start's
    whole second, a sample within 1 µs below a boundary counting as after it."""
    base = math.floor(start.timestamp())
    k = np.floor((start.timestamp() + t - base) / interval + 1e-6).astype(int) + 1
    return [(base + int(rec) * interval, k == rec) for rec in np.unique(k)]
