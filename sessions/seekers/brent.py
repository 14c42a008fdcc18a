"""A safeguarded Brent maximiser, run online one measurement at a time.

Two phases, the pairing Numerical Recipes recommends (mnbrak, then brent), kept inside the
hard bounds [γ1, γ3]:

1. **Bracketing from the best guess.** Measure γ2, then γ2 ± h (h = ``step``, default 5 % of
   the bracket; first towards the wider side, towards the slower speed on a tie: a person is
   safer probed slower), then step on in the uphill direction, the stride growing by the
   golden ratio while the power keeps rising, until a point is worse than the best by more
   than k standard errors of the difference (noise alone does not close a bracket) or a bound
   is reached. As in mnbrak, a parabola guides the stride: once the three best points are
   concave beyond the noise, the next probe goes no further than their vertex (and at least h
   past the current point, to see the descent). Every probe stays near the last good one: a
   person spends the search close to their best power.
2. **Brent's localmin** (Algorithms for Minimization without Derivatives, 1973, ch. 5) on -p
   inside that bracket: parabolic interpolation through the three best points when the step is
   acceptable, a golden-section step otherwise, never a step shorter than tol1 (so no point is
   measured twice) and never a point outside the bracket.

Noise-aware stop: tol1 = max(min_step, δn) with δn = sqrt(k·σ/|c|), σ the standard error of
the measurements and c the curvature of p near the best point (from the parabola through the
three best points, trusted only when it stands out of the noise by two standard errors).
Two candidates closer than δn differ in true power by less than k·σ, so they cannot be told
apart by measurement: the search stops instead of chasing noise. The final
setpoint is the vertex of that parabola when it is a maximum inside the final bracket, else the
best point measured.
"""

from __future__ import annotations

import math
from collections.abc import Generator

from sessions.seekers.base import Evaluation, FilteredSeeker, Plan
from sessions.seekers.fit import final_estimate, rms_stderr, top_curvature
from sessions.seekers.parabolic import curvature, parabola_vertex

GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))  # 0.381966…, the golden-section fraction
PHI = 0.5 * (1.0 + math.sqrt(5.0))  # 1.618…, the bracketing growth


class BrentSeeker(FilteredSeeker):
    kind = "brent"
    __slots__ = ("noise_tol",)

    def _concave(self, pts: list[tuple[float, float]]) -> tuple[float, float] | None:
        """(curvature, σ) of three distinct points when they are concave by more than two
        standard errors of the curvature, else None (a curvature lost in the noise)."""
        if len({g for g, _ in pts}) != 3:
            return None
        (g1, p1), (g2, p2), (g3, p3) = sorted(pts)
        c = curvature(g1, p1, g2, p2, g3, p3)
        # c is linear in the p's: c = Σ wᵢ pᵢ, so its standard error is σ·sqrt(Σ wᵢ²).
        w1 = 1.0 / ((g2 - g1) * (g3 - g1))
        w3 = 1.0 / ((g3 - g2) * (g3 - g1))
        sigma = rms_stderr(self.evaluations)
        c_err = sigma * math.sqrt(w1 * w1 + (w1 + w3) ** 2 + w3 * w3)
        return (c, sigma) if c < -2.0 * c_err else None

    def _tol(self, pts: list[tuple[float, float]]) -> float:
        """tol1: the minimum step, widened to the noise resolution near the best point."""
        cfg = self.cfg
        if cfg.noise_k > 0.0:
            concave = self._concave(pts)
            if concave is not None:  # else keep the last estimate
                c, sigma = concave
                self.noise_tol = math.sqrt(cfg.noise_k * sigma / -c)
        return max(cfg.min_step, self.noise_tol)

    def _stride(self, anchor: float, direction: float, step: float, h: float) -> float:
        """The next bracketing stride: ``step``, cut to the vertex of the three best points
        when they show a maximum (but at least ``h``)."""
        top = sorted(self.evaluations, key=lambda m: -m.power)[:3]
        pts = [(m.candidate, m.power) for m in top]
        if len(pts) < 3 or self._concave(pts) is None:
            return step
        (g1, p1), (g2, p2), (g3, p3) = sorted(pts)
        v = parabola_vertex(g1, p1, g2, p2, g3, p3)
        if v is None:
            return step
        return min(step, max(h, (v - anchor) * direction))

    def _final(self, best: float) -> float:
        return final_estimate(self.evaluations, self.lo, self.hi, best)

    def curvature_hint(self) -> float | None:
        return top_curvature(self.evaluations)

    def plan(self, lo: float, guess: float, hi: float) -> Plan:
        """1. bracket the maximum from the best guess; 2. Brent's localmin inside it."""
        self.noise_tol = 0.0
        yield from self._bracketing(lo, guess, hi)
        return (yield from self._localmin(lo, hi))

    def _bracketing(self, lo: float, guess: float, hi: float) -> Generator[float, Evaluation, None]:
        """Step from the guess, uphill with a lengthening stride, until a point is clearly
        worse than the best (or a bound or a known point closes the bracket)."""
        cfg = self.cfg
        budget = cfg.max_evaluations
        h = cfg.step if cfg.step is not None else 0.05 * (hi - lo)

        def clamp(g: float) -> float:
            return min(max(g, lo), hi)

        start: Evaluation = yield guess
        down = (guess - lo) >= (hi - guess)
        probe: Evaluation = yield clamp(guess - h if down else guess + h)
        if probe.power > start.power:  # uphill: carry on past the probe
            anchor, direction = probe, math.copysign(1.0, probe.candidate - start.candidate)
        else:  # downhill: cross back over the guess to its other side
            anchor, direction = start, math.copysign(1.0, start.candidate - probe.candidate)
        step = h
        while len(self.evaluations) < budget:
            c = clamp(
                anchor.candidate + direction * self._stride(anchor.candidate, direction, step, h)
            )
            if any(abs(c - ev.candidate) < 0.5 * cfg.min_step for ev in self.evaluations):
                break  # a bound, or a point already known, closes the bracket
            ev: Evaluation = yield c
            best = max(self.evaluations, key=lambda m: m.power)
            margin = cfg.noise_k * math.hypot(ev.stderr, best.stderr)
            if ev.power < best.power - (margin if math.isfinite(margin) else 0.0):
                break  # clearly worse than the best: the maximum is behind us
            if ev.power > anchor.power:
                step *= PHI  # still climbing: lengthen the stride
            anchor = ev

    def _localmin(self, lo: float, hi: float) -> Plan:
        """Brent's localmin on f = -p inside the bracket around the best point so far."""
        budget = self.cfg.max_evaluations
        ranked = sorted(self.evaluations, key=lambda m: -m.power)
        best_g = ranked[0].candidate
        left = max((m.candidate for m in ranked if m.candidate < best_g), default=lo)
        right = min((m.candidate for m in ranked if m.candidate > best_g), default=hi)
        x, fx = best_g, -ranked[0].power
        w, fw = (ranked[1].candidate, -ranked[1].power) if len(ranked) > 1 else (x, fx)
        v, fv = (ranked[2].candidate, -ranked[2].power) if len(ranked) > 2 else (w, fw)
        d = e = right - left  # lets the first step be parabolic
        tol1 = self._tol([(x, -fx), (w, -fw), (v, -fv)])
        while True:
            self.bracket = (left, right)
            xm = 0.5 * (left + right)
            tol2 = 2.0 * tol1
            if abs(x - xm) <= tol2 - 0.5 * (right - left):
                return self._final(x), "bracket within the tolerance"
            if len(self.evaluations) >= budget:
                return self._final(x), "evaluation budget spent"
            golden = True
            if abs(e) > tol1:  # try a parabolic step through x, w, v
                r = (x - w) * (fx - fv)
                q = (x - v) * (fx - fw)
                p = (x - v) * q - (x - w) * r
                q = 2.0 * (q - r)
                if q > 0.0:
                    p = -p
                q = abs(q)
                e_old, e = e, d
                if abs(p) < abs(0.5 * q * e_old) and q * (left - x) < p < q * (right - x):
                    d = p / q
                    u = x + d
                    golden = False
                    if u - left < tol2 or right - u < tol2:
                        d = tol1 if xm >= x else -tol1
            if golden:
                e = (left - x) if x >= xm else (right - x)
                d = GOLDEN * e
            u = x + (d if abs(d) >= tol1 else math.copysign(tol1, d if d != 0.0 else 1.0))
            ev = yield u
            u, fu = ev.candidate, -ev.power
            if fu <= fx:
                if u >= x:
                    left = x
                else:
                    right = x
                v, fv, w, fw, x, fx = w, fw, x, fx, u, fu
            else:
                if u < x:
                    left = u
                else:
                    right = u
                if fu <= fw or w == x:
                    v, fv, w, fw = w, fw, u, fu
                elif fu <= fv or v in (x, w):
                    v, fv = u, fu
            tol1 = self._tol([(x, -fx), (w, -fw), (v, -fv)])
