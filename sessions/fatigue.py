"""Fatigue of a simulated user: how strength and speed fall during a session.

Torque fatigue: both models give a factor f(t) ∈ (0, 1] with τ0(t) = τ0·f(t). It scales the
whole torque-velocity curve, so it lowers p* but leaves w* where it was.

Velocity fatigue (:class:`VelocityFatigue`): real fatigue also lowers the maximal shortening
velocity, so the velocity axis shrinks by s(t) = f + (1 − f)·exp(−t/T) and
τ(w, t) = τ0(t)·g(w / s(t)): the optimum moves, w*(t) = s(t)·w*(0).
"""

from __future__ import annotations

import math

import numpy as np


class NoFatigue:
    factor = 1.0
    time_varying = False

    def advance(self, dt: float) -> None:
        pass

    def factor_at(self, t: float) -> float:
        return 1.0


class ExponentialFatigue:
    """τ0(t) = τ0·exp(-t/T)."""

    time_varying = True

    def __init__(self, time_constant: float) -> None:
        self.time_constant = time_constant
        self.t = 0.0
        self.factor = 1.0
        self._dt = 0.0
        self._decay = 1.0

    def advance(self, dt: float) -> None:
        if dt != self._dt:
            self._dt, self._decay = dt, math.exp(-dt / self.time_constant)
        self.t += dt
        self.factor *= self._decay

    def factor_at(self, t: float) -> float:
        return math.exp(-t / self.time_constant)


class ThreeCompartmentFatigue:
    """Xia & Frey Law (2008), J. Biomech. 41: motor units active (MA), fatigued (MF), resting (MR).

    dMA/dt = C(t) - F·MA;  dMF/dt = F·MA - R·MF;  dMR/dt = -C(t) + R·MF, with the
    recruitment drive C(t) tracking a target load TL (the user's effort):
      MA < TL and MR > TL - MA:  C = LD·(TL - MA)
      MA < TL and MR ≤ TL - MA:  C = LD·MR
      MA ≥ TL:                   C = LR·(TL - MA)
    The strength left, 1 - MF (active plus resting capacity), scales τ0.
    """

    LD = 10.0
    LR = 10.0
    time_varying = True

    def __init__(self, effort: float, f: float, r: float) -> None:
        self.tl = effort
        self.f = f
        self.r = r
        self.ma = 0.0
        self.mf = 0.0
        self.mr = 1.0
        self.t = 0.0
        self.factor = 1.0
        self._hist_t: list[float] = [0.0]
        self._hist_f: list[float] = [1.0]

    def _rates(self, ma: float, mf: float, mr: float) -> tuple[float, float, float]:
        tl = self.tl
        if ma < tl:
            c = self.LD * (tl - ma) if mr > tl - ma else self.LD * mr
        else:
            c = self.LR * (tl - ma)
        return c - self.f * ma, self.f * ma - self.r * mf, -c + self.r * mf

    def advance(self, dt: float) -> None:
        # Heun's method: LD·dt ≤ 0.01 at 1 kHz, far inside its stability region.
        a1, f1, r1 = self._rates(self.ma, self.mf, self.mr)
        ma, mf, mr = self.ma + dt * a1, self.mf + dt * f1, self.mr + dt * r1
        a2, f2, r2 = self._rates(ma, mf, mr)
        self.ma += 0.5 * dt * (a1 + a2)
        self.mf += 0.5 * dt * (f1 + f2)
        self.mr += 0.5 * dt * (r1 + r2)
        self.t += dt
        self.factor = 1.0 - self.mf
        if self.t - self._hist_t[-1] >= 0.1:
            self._hist_t.append(self.t)
            self._hist_f.append(self.factor)

    def factor_at(self, t: float) -> float:
        """The factor at any time: the past from a 0.1 s record, the future by integrating
        a copy forward from now."""
        if t <= self.t:
            return float(np.interp(t, self._hist_t, self._hist_f))
        probe = ThreeCompartmentFatigue(self.tl, self.f, self.r)
        probe.ma, probe.mf, probe.mr, probe.t = self.ma, self.mf, self.mr, self.t
        step = 0.01
        while probe.t < t - 1e-12:
            probe.advance(min(step, t - probe.t))
        return probe.factor


class VelocityFatigue:
    """s(t) = f + (1 - f)·exp(-t/T): the factor by which the velocity axis has shrunk."""

    time_varying = True

    def __init__(self, time_constant: float, floor: float) -> None:
        self.time_constant = time_constant
        self.floor = floor
        self.t = 0.0
        self.factor = 1.0
        self._excess = 1.0 - floor  # s(t) - f, decays exponentially
        self._dt = 0.0
        self._decay = 1.0

    def advance(self, dt: float) -> None:
        if dt != self._dt:
            self._dt, self._decay = dt, math.exp(-dt / self.time_constant)
        self.t += dt
        self._excess *= self._decay
        self.factor = self.floor + self._excess

    def factor_at(self, t: float) -> float:
        return self.floor + (1.0 - self.floor) * math.exp(-t / self.time_constant)


Fatigue = NoFatigue | ExponentialFatigue | ThreeCompartmentFatigue
