"""Simulated people, the users a session runs against: the torque τ(q, w, t) a person
applies to the handle.

    τ(q, w, t) = clamp(T(t)·g(w / s(t))·(1 + n(t))·(1 + r sin q), 0, τmax)

- g, the torque-velocity curve at the start of the session (clamped to [0, g(0)] for the laws):
  - ``linear``: g(w) = τ0 (1 - w/wmax). τ0 = 2, wmax = 6 gives exactly the surrogate (31).
  - ``hill``:   g(w) = τ0 (wmax - w) / (wmax + w/a), a the curvature; w* ≈ 0.31 wmax for
    a = 0.25.
  - ``table``:  measured points [w, τ] interpolated by PCHIP (Fritsch-Carlson, scipy's
    ``PchipInterpolator``: monotone between points, no overshoot, so τ ≥ 0 wherever the
    points are), τ = g(w₀) below the first point, 0 past the last one. Any measured person's
    curve can be replayed.
- T(t) ∈ (0, 1]: torque fatigue (τ0 falling), :mod:`sessions.fatigue`.
- s(t) ∈ (0, 1]: velocity fatigue, the velocity axis shrinking (s = 1 without it).
- n: a band-limited multiplicative fluctuation, a first-order Gauss-Markov process with the
  given relative std and corner frequency; a person never pushes evenly. The factor 1 + n is
  clamped to [0, 2] (symmetric, so its mean stays 1), so τ never goes negative: the paper's
  0 ≤ τ ≤ τmax holds at every period, with τmax = 2 (1 + r) max g.
- ripple: τ·(1 + r sin q), the stroke-angle dependence of limb geometry.

A user knows its own truth, so a session can be scored: the true modified power
p(w, t) = T(t)·g(w/s(t))·w^ρ (4) without noise or ripple (both average out), its maximiser
w*(t) = s(t)·x* (x* the maximiser of g(x)·x^ρ) and maximum p*(t) = T(t)·s(t)^ρ·g(x*)·x*^ρ.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable

import numpy as np

from sessions.config import UserConfig
from sessions.fatigue import (
    ExponentialFatigue,
    Fatigue,
    NoFatigue,
    ThreeCompartmentFatigue,
    VelocityFatigue,
)


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


def _golden_max(f: Callable[[float], float], lo: float, hi: float, tol: float = 1e-10) -> float:
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


class Table:
    """A measured curve τ(w): PCHIP through the points, evaluated without scipy on the 1 kHz
    path (the piecewise cubic's coefficients, found by bisection)."""

    __slots__ = ("xs", "coef", "first", "last")

    def __init__(self, points: tuple[tuple[float, float], ...]) -> None:
        from scipy.interpolate import PchipInterpolator

        x = np.array([p[0] for p in points], dtype=float)
        y = np.array([p[1] for p in points], dtype=float)
        pp = PchipInterpolator(x, y, extrapolate=False)
        self.xs = x.tolist()
        self.coef = [tuple(float(v) for v in pp.c[:, i]) for i in range(len(x) - 1)]
        self.first = float(y[0])
        self.last = float(y[-1])

    def __call__(self, w: float) -> float:
        xs = self.xs
        if w <= xs[0]:
            return self.first
        if w >= xs[-1]:
            return self.last if w == xs[-1] else 0.0
        i = bisect.bisect_right(xs, w) - 1
        c3, c2, c1, c0 = self.coef[i]
        d = w - xs[i]
        v = ((c3 * d + c2) * d + c1) * d + c0
        return v if v > 0.0 else 0.0

    @property
    def top(self) -> float:
        return self.xs[-1]


class SimulatedUser:
    """A deterministic (seeded) simulated person. One :meth:`advance` per loop period."""

    def __init__(self, cfg: UserConfig, dt: float, seed: int) -> None:
        self.cfg = cfg
        self.kind = cfg.kind
        self.wmax = cfg.wmax
        self.inv_a = 1.0 / cfg.curvature
        self.ripple = cfg.ripple
        self.table = Table(cfg.points) if cfg.kind == "table" and cfg.points else None
        # the laws are normalised to τ0 = 1 and scaled by τ0; a table is in N·m already
        self.tau0 = 1.0 if self.table is not None else cfg.tau0
        self.noise = BandLimitedNoise(cfg.noise, cfg.noise_bandwidth, dt, seed)
        self.fatigue: Fatigue
        if cfg.fatigue_model == "three-compartment":
            self.fatigue = ThreeCompartmentFatigue(cfg.fatigue_effort, cfg.fatigue_f, cfg.fatigue_r)
        elif cfg.fatigue_tau > 0:
            self.fatigue = ExponentialFatigue(cfg.fatigue_tau)
        else:
            self.fatigue = NoFatigue()
        self.speed: VelocityFatigue | NoFatigue = (
            VelocityFatigue(cfg.velocity_fatigue_tau, cfg.velocity_fatigue_floor)
            if cfg.velocity_fatigue_tau > 0
            else NoFatigue()
        )
        peak = max(p[1] for p in cfg.points) if self.table is not None and cfg.points else 1.0
        self.tau_max = 2.0 * (1.0 + self.ripple) * self.tau0 * peak  # τmax of 0 ≤ τ ≤ τmax
        self.t = 0.0
        self._x_star: dict[float, float] = {}
        # held over one loop period (noise and fatigue are slow): T(t)·τ0·(1 + n), 1/s(t)
        self.scale = self.tau0 * _noise_factor(self.noise.value)
        self.inv_s = 1.0
        self.torque = self._make_torque()

    # -- torque-velocity curve at t = 0, normalised to τ0 = 1 for the laws ------------------
    def shape(self, w: float) -> float:
        if self.table is not None:
            return self.table(w)
        wmax = self.wmax
        if w >= wmax:
            return 0.0
        if w <= 0.0:
            return 1.0
        if self.kind == "linear":
            return 1.0 - w / wmax
        return (wmax - w) / (wmax + w * self.inv_a)

    def shapes(self, w: np.ndarray) -> np.ndarray:
        """:meth:`shape` over an array."""
        if self.table is not None:
            return np.array([self.table(float(x)) for x in np.ravel(w)]).reshape(np.shape(w))
        x = np.clip(w, 0.0, self.wmax)
        if self.kind == "linear":
            return 1.0 - x / self.wmax
        return (self.wmax - x) / (self.wmax + x * self.inv_a)

    def _make_torque(self) -> Callable[[float, float], float]:
        """τ(q, w) at the current time, as a closure: it runs four times a loop period."""
        user, wmax, inv_a, r, sin = self, self.wmax, self.inv_a, self.ripple, math.sin
        table = self.table
        if table is not None:

            def torque_table(q: float, w: float) -> float:
                s = table(w * user.inv_s)
                if r:
                    return user.scale * s * (1.0 + r * sin(q))
                return user.scale * s

            return torque_table
        hill = self.kind == "hill"

        def torque(q: float, w: float) -> float:
            w *= user.inv_s
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
            self.scale = self.tau0 * fatigue.factor * _noise_factor(noise.value)
        else:
            self.scale = self.tau0 * _noise_factor(noise.value)
        speed = self.speed
        if speed.time_varying:
            speed.advance(dt)
            self.inv_s = 1.0 / speed.factor

    # -- truth, for scoring --------------------------------------------------------------
    def tau0_at(self, t: float | None = None) -> float:
        """T(t)·τ0 (T(t) alone for a table)."""
        if t is None:
            return self.tau0 * self.fatigue.factor
        return self.tau0 * self.fatigue.factor_at(t)

    def speed_at(self, t: float | None = None) -> float:
        """s(t): how far the velocity axis has shrunk (1 without velocity fatigue)."""
        return self.speed.factor if t is None else self.speed.factor_at(t)

    def true_power(self, w: float, rho: float = 1.0, t: float | None = None) -> float:
        """p(w, t) = T(t)·g(w/s(t))·w^ρ (4), without noise or ripple, at time t (default: now)."""
        if w <= 0.0:
            return 0.0
        return self.tau0_at(t) * self.shape(w / self.speed_at(t)) * w**rho

    def x_star(self, rho: float = 1.0) -> float:
        """The maximiser of g(x)·x^ρ, the optimum at t = 0 (cached: it never changes)."""
        x = self._x_star.get(rho)
        if x is None:
            x = self._x_star[rho] = self._maximise(rho)
        return x

    def _maximise(self, rho: float) -> float:
        if self.table is None:
            if self.kind == "linear":
                return rho * self.wmax / (1.0 + rho)
            if rho == 1.0:
                a = self.cfg.curvature
                return self.wmax * (math.sqrt(a * a + a) - a)
            return _golden_max(lambda w: self.shape(w) * w**rho, 0.0, self.wmax)
        # a measured curve need not be unimodal: a dense grid, then golden section around
        # its best point
        top = self.table.top
        grid = np.linspace(0.0, top, 4001)
        p = self.shapes(grid) * grid**rho
        i = int(np.argmax(p))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        return _golden_max(lambda w: self.shape(w) * w**rho, float(lo), float(hi))

    def w_star(self, rho: float = 1.0, t: float | None = None) -> float:
        """w*(t) = s(t)·x*: torque fatigue scales p and never moves it; velocity fatigue does."""
        return self.speed_at(t) * self.x_star(rho)

    def optimum(self, rho: float = 1.0, t: float | None = None) -> tuple[float, float]:
        """(w*, p*) at time t (default: now)."""
        w = self.w_star(rho, t)
        return w, self.true_power(w, rho, t)

    def power_ratio(self, w: np.ndarray, t: np.ndarray, rho: float = 1.0) -> np.ndarray:
        """p(w(t), t) / p*(t) over arrays (torque fatigue cancels; velocity fatigue does not)."""
        w = np.asarray(w, dtype=float)
        t = np.asarray(t, dtype=float)
        x = self.x_star(rho)
        top = self.shape(x) * x**rho
        if self.speed.time_varying:
            s = np.array([self.speed.factor_at(float(v)) for v in np.ravel(t)]).reshape(t.shape)
        else:
            s = np.ones_like(t)
        xw = np.where(w > 0, w / s, 0.0)
        return self.shapes(xw) * np.where(xw > 0, xw, 0.0) ** rho / top


def _noise_factor(n: float) -> float:
    """1 + n, clamped to [0, 2]: a person pushes, never pulls (13.3), and the clamp is
    symmetric so that the mean stays 1."""
    f = 1.0 + n
    return 0.0 if f < 0.0 else (2.0 if f > 2.0 else f)
