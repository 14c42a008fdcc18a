"""Simulated people, the users a session runs against: the torque τ(q, w, t) a person
applies to the handle.

A user knows its own truth, so a session can be scored: the true modified power
p(w) = τ̄(w)·w^ρ (4) with τ̄ the torque without noise or ripple (both average out), its
maximiser w* and maximum p*, at any time (fatigue moves p*, never w*).

Torque-velocity laws, clamped to [0, τ0] (Assumption 3 of the paper):
- ``linear``: τ = τ0 (1 - w/wmax). τ0 = 2, wmax = 6 gives exactly the surrogate (31).
- ``hill``:   τ = τ0 (wmax - w) / (wmax + w/a), a the curvature; w* ≈ 0.31 wmax for a = 0.25.
Traits:
- noise: a band-limited multiplicative fluctuation (1 + n), n a first-order Gauss-Markov
  process with the given relative std and corner frequency; a person never pushes evenly.
- ripple: τ·(1 + r sin q), the stroke-angle dependence of limb geometry.
- fatigue: see :mod:`sessions.fatigue`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from sessions.config import UserConfig
from sessions.fatigue import ExponentialFatigue, Fatigue, NoFatigue, ThreeCompartmentFatigue


class BandLimitedNoise:
    """n(t): AR(1) discretisation of a first-order Gauss-Markov process, stationary std σ.

    n[k] = a n[k-1] + b ε[k], a = exp(-2π fc dt), b = σ sqrt(1 - a²). Generated a block at a
    time with numpy (n[k] = aᵏ (n[0] + b Σⱼ a⁻ʲ ε[j])), the block short enough that a⁻ᴮ stays
    far from overflow; seeded, so a user is reproducible."""

    def __init__(self, std: float, bandwidth_hz: float, dt: float, seed: int) -> None:
        self.std = std
        self.a = math.exp(-2.0 * math.pi * bandwidth_hz * dt)
        self.b = std * math.sqrt(1.0 - self.a * self.a)
        self.rng = np.random.default_rng(seed)
        self.block = max(1, min(4096, int(25.0 / max(-math.log(self.a), 1e-12))))
        self.value = float(self.rng.normal(0.0, std)) if std > 0 else 0.0
        self._values: list[float] = []
        self._i = 0

    def _refill(self) -> None:
        k = np.arange(1, self.block + 1)
        eps = self.rng.standard_normal(self.block)
        ak = self.a**k
        self._values = (ak * (self.value + self.b * np.cumsum(eps / ak))).tolist()
        self._i = 0

    def advance(self) -> None:
        if self._i >= len(self._values):
            self._refill()
        self.value = self._values[self._i]
        self._i += 1


def _golden_max(f, lo: float, hi: float, tol: float = 1e-10) -> float:
    """Maximiser of a unimodal f on [lo, hi] by golden-section search."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc > fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(d)
    return 0.5 * (a + b)


class SimulatedUser:
    """A deterministic (seeded) simulated person. One :meth:`advance` per loop period."""

    def __init__(self, cfg: UserConfig, dt: float, seed: int) -> None:
        self.cfg = cfg
        self.kind = cfg.kind
        self.tau0 = cfg.tau0
        self.wmax = cfg.wmax
        self.inv_a = 1.0 / cfg.curvature
        self.ripple = cfg.ripple
        self.noise = BandLimitedNoise(cfg.noise, cfg.noise_bandwidth, dt, seed)
        self.fatigue: Fatigue
        if cfg.fatigue_model == "three-compartment":
            self.fatigue = ThreeCompartmentFatigue(cfg.fatigue_effort, cfg.fatigue_f, cfg.fatigue_r)
        elif cfg.fatigue_tau > 0:
            self.fatigue = ExponentialFatigue(cfg.fatigue_tau)
        else:
            self.fatigue = NoFatigue()
        self.t = 0.0
        # τ0·f(t)·(1 + n(t)): held over one loop period (noise and fatigue are slow).
        self.scale = self.tau0 * (1.0 + self.noise.value)
        self.torque = self._make_torque()

    # -- torque-velocity law, normalised to τ0 = 1 ------------------------------------
    def shape(self, w: float) -> float:
        wmax = self.wmax
        if w >= wmax:
            return 0.0
        if w <= 0.0:
            return 1.0
        if self.kind == "linear":
            return 1.0 - w / wmax
        return (wmax - w) / (wmax + w * self.inv_a)

    def _make_torque(self) -> Callable[[float, float], float]:
        """τ(q, w) at the current time, as a closure: it runs four times a loop period."""
        user, wmax, inv_a, r, sin = self, self.wmax, self.inv_a, self.ripple, math.sin
        hill = self.kind == "hill"

        def torque(q: float, w: float) -> float:
            if w >= wmax:
                return 0.0
            if w <= 0.0:
                s = 1.0
            elif hill:
                s = (wmax - w) / (wmax + w * inv_a)
            else:
                s = 1.0 - w / wmax
            if r:
                return user.scale * s * (1.0 + r * sin(q))
            return user.scale * s

        return torque

    def advance(self, dt: float) -> None:
        self.t += dt
        noise = self.noise
        if noise.std:
            noise.advance()
        fatigue = self.fatigue
        if fatigue.time_varying:
            fatigue.advance(dt)
            self.scale = self.tau0 * fatigue.factor * (1.0 + noise.value)
        else:
            self.scale = self.tau0 * (1.0 + noise.value)

    # -- truth, for scoring --------------------------------------------------------------
    def tau0_at(self, t: float | None = None) -> float:
        if t is None:
            return self.tau0 * self.fatigue.factor
        return self.tau0 * self.fatigue.factor_at(t)

    def true_power(self, w: float, rho: float = 1.0, t: float | None = None) -> float:
        """p(w) = τ̄(w)·w^ρ (4), without noise or ripple, at time t (default: now)."""
        if w <= 0.0:
            return 0.0
        return self.tau0_at(t) * self.shape(w) * w**rho

    def w_star(self, rho: float = 1.0) -> float:
        """The maximiser of p; fatigue scales p and so never moves it."""
        if self.kind == "linear":
            return rho * self.wmax / (1.0 + rho)
        if rho == 1.0:
            a = self.cfg.curvature
            return self.wmax * (math.sqrt(a * a + a) - a)
        return _golden_max(lambda w: self.shape(w) * w**rho, 0.0, self.wmax)

    def optimum(self, rho: float = 1.0, t: float | None = None) -> tuple[float, float]:
        """(w*, p*) at time t (default: now)."""
        w = self.w_star(rho)
        return w, self.true_power(w, rho, t)
