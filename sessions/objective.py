"""What the seekers maximise."""

from __future__ import annotations


def modified_power(tau: float, w: float, rho: float) -> float:
    """p = τ·w^ρ (4), the user's modified power; 0 when w ≤ 0 (wd > 0 by assumption)."""
    if w <= 0.0:
        return 0.0
    return tau * w if rho == 1.0 else tau * w**rho


def surrogate_power(wd: float) -> float:
    """The paper's Exp. 1 surrogate: p = 3 - (wd - 3)²/3 (31), maximal at wd = 3 rad/s."""
    return 3.0 - (wd - 3.0) ** 2 / 3.0
