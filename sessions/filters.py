"""Trajectory filters (32) and (33): a candidate γ in, a smooth wd, ad, jd out.

    wd = pⁿ/(s+p)ⁿ γ,   ad = pⁿ s/(s+p)ⁿ γ,   jd = pⁿ s²/(s+p)ⁿ γ
n = 4, p = 3 is the paper's (32): 81/(s⁴ + 12s³ + 54s² + 108s + 81). n = 3 is (33) with
ς1 = p³, ς2 = 3p, ς3 = 3p², ς4 = p³ (a repeated pole; the paper leaves the ς free).

Realised as a cascade of n identical lags p/(s+p): yᵢ' = p (yᵢ₋₁ - yᵢ), y₀ = γ, wd = yₙ. Then
    ad = p (yₙ₋₁ - yₙ),    jd = p² (yₙ₋₂ - 2 yₙ₋₁ + yₙ)
are states, not differences, and consistent by construction. γ is piecewise constant (a seeker
changes it between samples), so the deviations dᵢ = yᵢ - γ obey d' = A d with A one Jordan
block, whose exponential is known in closed form: with E = e^{-p dt}, h = p dt,
    dᵢ⁺ = E Σⱼ≤ᵢ hⁱ⁻ʲ/(i-j)! dⱼ.
The discretisation is therefore exact, at a dozen multiplications a period.
"""

from __future__ import annotations

import math


class TrajectoryFilter:
    """Exact discrete form of (32)/(33) at a fixed period. Read wd, ad, jd; then :meth:`step`."""

    __slots__ = (
        "order",
        "pole",
        "dt",
        "E",
        "h1",
        "h2",
        "h3",
        "y1",
        "y2",
        "y3",
        "y4",
        "wd",
        "ad",
        "jd",
    )

    def __init__(self, order: int, pole: float, dt: float) -> None:
        if order not in (3, 4):
            raise ValueError("filter order must be 3 (33) or 4 (32)")
        self.order = order
        self.pole = pole
        self.dt = dt
        h = pole * dt
        self.E = math.exp(-h)
        self.h1, self.h2, self.h3 = h, h * h / 2.0, h * h * h / 6.0
        self.reset(0.0)

    def reset(self, value: float) -> None:
        """Rest at ``value``: wd = value, ad = jd = 0 (a bumpless start from the current w)."""
        self.y1 = self.y2 = self.y3 = self.y4 = value
        self.wd, self.ad, self.jd = value, 0.0, 0.0

    def step(self, gamma: float) -> None:
        """Advance one period with the candidate γ held."""
        E, h1, h2, p = self.E, self.h1, self.h2, self.pole
        d1, d2, d3 = self.y1 - gamma, self.y2 - gamma, self.y3 - gamma
        if self.order == 4:
            d4 = E * (self.y4 - gamma + h1 * d3 + h2 * d2 + self.h3 * d1)
            d3 = E * (d3 + h1 * d2 + h2 * d1)
            d2 = E * (d2 + h1 * d1)
            d1 = E * d1
            self.y4 = wd = d4 + gamma
            self.ad = p * (d3 - d4)
            self.jd = p * p * (d2 - 2.0 * d3 + d4)
        else:  # three lags: y3 is the output
            d3 = E * (d3 + h1 * d2 + h2 * d1)
            d2 = E * (d2 + h1 * d1)
            d1 = E * d1
            wd = d3 + gamma
            self.ad = p * (d2 - d3)
            self.jd = p * p * (d1 - 2.0 * d2 + d3)
        self.y1, self.y2, self.y3 = d1 + gamma, d2 + gamma, d3 + gamma
        self.wd = wd
