"""Where the measurements say the peak is: a weighted least-squares quadratic through all of
them, with a linear drift in time when the data can tell it apart.

Single measurements are noisy, and the best one is biased upwards (the winner's curse): a
search that trusts its luckiest point ends there. A person also tires (or warms up) during the
search, so that earlier measurements read high. The fit
    p ≈ a + b (g - ḡ) + c (g - ḡ)² + d (t - t̄),   weights 1/σᵢ²
uses every measurement at once; its vertex ḡ - b/(2c) is the estimate, trusted only when the
curvature is negative by more than two standard errors, and kept within the points measured.
The drift term is fitted only with at least six points and when it is not confounded with the
velocity terms (condition number of the scaled design below 100).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

import numpy as np

from sessions.seekers.base import Evaluation


def quadratic_peak(evs: Sequence[Evaluation], lo: float, hi: float) -> float | None:
    """The fitted peak within [lo, hi], or None when the measurements do not show one."""
    found = _quadratic(evs, lo, hi)
    return None if found is None else found[0]


def _quadratic(evs: Sequence[Evaluation], lo: float, hi: float) -> tuple[float, float] | None:
    """(peak, d²p/dw²) of the fit, or None."""
    pts = [ev for ev in evs if lo <= ev.candidate <= hi and math.isfinite(ev.power)]
    if len({ev.candidate for ev in pts}) < 3:
        return None
    g = np.array([ev.candidate for ev in pts])
    p = np.array([ev.power for ev in pts])
    t = np.array([ev.t for ev in pts])
    se = np.array([ev.stderr if 0 < ev.stderr < math.inf else np.nan for ev in pts])
    # statistics, not np.nanmedian: that loads numpy.ma on first use, a stall in the loop
    known = [ev.stderr for ev in pts if 0 < ev.stderr < math.inf]
    floor = statistics.median(known) if known else 1.0
    se = np.where(np.isfinite(se), np.maximum(se, 0.25 * floor), floor)
    wts = 1.0 / se
    gs, ts = g.std() or 1.0, t.std() or 1.0
    x = (g - g.mean()) / gs
    cols = [np.ones_like(x), x, x * x]
    if len(pts) >= 6:
        drift = np.column_stack([*cols, (t - t.mean()) / ts]) * wts[:, None]
        if np.linalg.cond(drift) < 100.0:
            cols.append((t - t.mean()) / ts)
    a = np.column_stack(cols) * wts[:, None]
    coef, *_ = np.linalg.lstsq(a, p * wts, rcond=None)
    dof = len(pts) - len(cols)
    if dof > 0:
        resid = a @ coef - p * wts
        scale = max(float(resid @ resid) / dof, 1.0)
    else:
        scale = 1.0
    cov = np.linalg.pinv(a.T @ a) * scale
    c, c_err = coef[2], math.sqrt(max(cov[2, 2], 0.0))
    if not c < -2.0 * c_err:
        return None
    peak = float(g.mean() - coef[1] / (2.0 * c) * gs)
    return min(max(peak, float(g.min())), float(g.max())), float(2.0 * c / (gs * gs))


def top_curvature(evs: Sequence[Evaluation]) -> float | None:
    """d²p/dw² of the fit through the measurements near the top, when it shows a maximum."""
    found = _quadratic(_top(evs), -math.inf, math.inf) if evs else None
    return None if found is None else found[1]


def _top(evs: Sequence[Evaluation]) -> list[Evaluation]:
    top = max(ev.power for ev in evs)
    floor = top - max(0.05 * abs(top), 3.0 * rms_stderr(evs))
    return [ev for ev in evs if ev.power >= floor]


def rms_stderr(evs: Sequence[Evaluation]) -> float:
    """Root-mean-square standard error of the measurements (0 when none is known)."""
    errs = [ev.stderr for ev in evs if math.isfinite(ev.stderr)]
    return math.sqrt(sum(e * e for e in errs) / len(errs)) if errs else 0.0


def final_estimate(evs: Sequence[Evaluation], lo: float, hi: float, fallback: float) -> float:
    """The fitted peak of the measurements near the top, else ``fallback``.

    "Near the top" is within 5 % (or three standard errors) of the best power: there p is
    close to a parabola even for a skewed Hill curve, and there are enough points to average
    out one lucky measurement."""
    if not evs:
        return fallback
    peak = quadratic_peak(_top(evs), lo, hi)
    return fallback if peak is None else peak
