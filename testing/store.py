"""Data for the store tests: deterministic telemetry and a fast (but real) password hasher."""

from __future__ import annotations

import numpy as np
from argon2 import PasswordHasher

from sessions.telemetry import INDEX, WIDTH

# A real argon2id hasher with small costs: the tests hash many passwords.
FAST_HASHER = PasswordHasher(time_cost=1, memory_cost=1024, parallelism=1)


def telemetry(seconds: float, rate: float = 1000.0, t0: float = 0.0) -> np.ndarray:
    """Deterministic rows (n, WIDTH) that look like a session: smooth channels with noise,
    a growing angle and work, time k/rate."""
    n = round(seconds * rate)
    k = np.arange(n) + round(t0 * rate)
    t = k / rate
    rng = np.random.default_rng(7 + int(t0 * rate))
    out = np.empty((n, WIDTH))
    out[:, INDEX["t"]] = t
    out[:, INDEX["w"]] = 3 + 0.4 * np.sin(0.9 * t) + 0.05 * rng.standard_normal(n)
    out[:, INDEX["q"]] = 3 * t + 0.4 * (1 - np.cos(0.9 * t)) / 0.9
    out[:, INDEX["wd"]] = 3 + 0.4 * np.sin(0.9 * t)
    out[:, INDEX["ad"]] = 0.36 * np.cos(0.9 * t)
    out[:, INDEX["u"]] = -2 + 0.3 * np.sin(5 * t) + 0.02 * rng.standard_normal(n)
    out[:, INDEX["tau"]] = 2 + 0.3 * np.sin(5 * t + 1) + 0.02 * rng.standard_normal(n)
    out[:, INDEX["p"]] = out[:, INDEX["tau"]] * out[:, INDEX["wd"]]
    out[:, INDEX["W"]] = np.cumsum(out[:, INDEX["tau"]] * out[:, INDEX["w"]]) / rate - 0.5
    out[:, INDEX["gamma"]] = 3.0 + np.floor(t / 2.0) * 0.1
    return out
