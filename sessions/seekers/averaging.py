"""Measuring p at one candidate: how long to average, and how sure the mean is.

The paper leaves the averaging open. A person's power is not steady: it fluctuates (noise)
and varies with the stroke angle (ripple, one cycle per revolution). The window therefore
  - lasts at least ``window`` seconds;
  - ends there if p is already steady (relative std ≤ ``quiet``): a clean signal is not
    averaged for longer than needed;
  - otherwise ends on a whole revolution of the handle, so any stroke-angle ripple averages
    out exactly (power over whole revolutions = work per revolution / time);
  - never lasts longer than ``max_window`` seconds.
The mean is the constant term of a least-squares fit p ≈ c0 + c1 sin q + c2 cos q when the
window spans most of a revolution (it removes the ripple's first harmonic), else the plain mean.
Its standard error comes from batch means of the residuals (up to 8 contiguous batches):
band-limited noise makes neighbouring samples far from independent, and batches much longer
than its correlation time are not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TWO_PI = 2.0 * math.pi
BATCHES = 8
MIN_BATCH = 25  # samples


@dataclass(frozen=True, slots=True)
class Measurement:
    mean: float
    stderr: float
    duration: float
    samples: int
    velocity: float  # mean desired velocity over the window: where p was measured


def summarise(q: np.ndarray, p: np.ndarray, duration: float, velocity: float) -> Measurement:
    n = len(p)
    if n == 0:
        return Measurement(math.nan, math.inf, duration, 0, velocity)
    span = float(q[-1] - q[0]) if n > 1 else 0.0
    if n >= 8 and span >= 0.75 * TWO_PI:
        x = np.column_stack((np.ones(n), np.sin(q), np.cos(q)))
        coef, *_ = np.linalg.lstsq(x, p, rcond=None)
        mean = float(coef[0])
        resid = p - x @ coef
    else:
        mean = float(p.mean())
        resid = p - mean
    batches = min(BATCHES, n // MIN_BATCH)
    if batches < 2:
        return Measurement(mean, math.inf, duration, n, velocity)
    means = np.array([b.mean() for b in np.array_split(resid, batches)])
    stderr = float(means.std(ddof=1) / math.sqrt(batches))
    return Measurement(mean, stderr, duration, n, velocity)


class PowerAverager:
    """Accumulates (q, p) one sample at a time and decides when the window is complete."""

    __slots__ = ("window", "max_window", "quiet2", "t0", "q0", "qs", "ps", "s1", "s2", "sw", "revs")

    def __init__(self, window: float, max_window: float, quiet: float) -> None:
        self.window = window
        self.max_window = max_window
        self.quiet2 = quiet * quiet
        self.start(0.0, 0.0)

    def start(self, t: float, q: float) -> None:
        self.t0 = t
        self.q0 = q
        self.qs: list[float] = []
        self.ps: list[float] = []
        self.s1 = 0.0
        self.s2 = 0.0
        self.sw = 0.0
        self.revs = -1  # whole revolutions counted once the shortest window has passed

    def add(self, t: float, q: float, p: float, w: float) -> bool:
        """Take one sample of p, taken at angle q and velocity w; True when the window is
        complete (the sample included)."""
        self.sw += w
        self.qs.append(q)
        self.ps.append(p)
        self.s1 += p
        self.s2 += p * p
        elapsed = t - self.t0
        if elapsed < self.window:
            return False
        if elapsed >= self.max_window:
            return True
        revs = int((q - self.q0) / TWO_PI) if q > self.q0 else 0
        if self.revs < 0:  # first sample past the shortest window
            self.revs = revs
        elif revs > self.revs:
            return True  # on a whole revolution: stroke-angle ripple averages out
        n = len(self.ps)
        mean = self.s1 / n
        var = self.s2 / n - mean * mean
        return var <= self.quiet2 * mean * mean

    def result(self, t: float) -> Measurement:
        n = len(self.ps)
        velocity = self.sw / n if n else math.nan
        return summarise(np.asarray(self.qs), np.asarray(self.ps), t - self.t0, velocity)
