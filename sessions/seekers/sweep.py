"""The sweep seeker: learn p(w) from every sample while the candidate moves, not only from
settled windows.

A numerical seeker of Appendix A spends ~4 s of a person's effort per candidate (the filter
settles, then at least a revolution is averaged) and throws away what it saw in between. The
sweep keeps every sample: the loop's (t, q, p, w) become 20 ms rows (:mod:`.regression`), and
p is regressed on the *measured* velocity with the stroke ripple (first and second harmonic,
multiplicative) regressed out, so the candidate can move all the time.

1. **Lead-in.** From rest the trajectory filter brings wd to γ2, exactly as for a candidate.
   Rows are kept from the end of the start delay on.
2. **Legs.** The candidate γ moves along a direction at ``sweep_rate``·w per second (faster, up
   to 4×, where the power is clearly below the best seen: far from the top), never more than
   the filter's ramp lag ahead of wd, never outside [lo, hi]. Every 0.2 s a line through the
   last second or revolution of rows gives the local slope: a slope uphill along the leg by
   2.5 standard errors marks the leg as *climbing*; downhill by 2.5 standard errors after a
   climb means the top is behind: it is bracketed. Downhill without a climb (the lead-in
   overshot, or the guess was past the top): the leg reverses. At a bound while climbing the
   bound is expanded (``expand``) or the search ends there; a flat reach of the bound reverses.
3. **The top.** A quadratic through the rows within ±30 % of the best point (the skew of a
   Hill curve moves its vertex by < 0.03 % of the power at that width) gives the vertex v and
   its standard error σv. Converged once ½|p''|(2σv)² ≤ ``power_tol``·p: the optimum is
   known to within that fraction of the power; otherwise one more, slower pass across
   v ± max(10 %, 2σv) (at most three).
4. **Track.** The candidate goes to v and a :class:`~sessions.seekers.tracker.Tracker`
   follows it (``track``, the default) with the curvature the sweep measured.

An edge is an optimum only if the power does not still rise through it: the slope at the
bound, from every row near it, must point outward by three standard errors for ``at_bound``.
"""

from __future__ import annotations

import math

import numpy as np

from sessions.config import SeekerConfig
from sessions.filters import TrajectoryFilter
from sessions.seekers.base import (
    DELAY,
    DONE,
    MEASURING,
    SETTLING,
    Evaluation,
    Seeker,
)
from sessions.seekers.regression import Fit, Rows, T, W, fit
from sessions.seekers.tracker import Tracker

REFIT = 0.2  # s between decisions
REPORT = 1.0  # s between the evaluations the sweep records
TRAIL = 1.0  # s: the shortest trailing window for the local slope
TRAIL_MAX = 4.0  # s: the longest (one revolution, when slow)
K_SLOPE = 2.5  # standard errors for "climbing" / "descending"
K_EDGE = 3.0  # standard errors for "the power still rises through the bound"
TOP = 0.3  # the top fit's half-width, fraction of the velocity
MAX_REFINE = 3
MARGIN = 0.1  # rows this far (fraction of v) past the vertex on a side make it seen
FAST = 4.0
# rows start once the lead-in's acceleration is below this fraction of w per second: while the
# reference accelerates hard, τ̂ = τ - J ė is off by the transient of the tracking error
ACC_GATE = 0.3  # the most a leg speeds up where the power is clearly low
MIN_ROWS = 12


class SweepSeeker(Seeker):
    kind = "sweep"
    __slots__ = (
        "filter", "rows", "tracker", "direction", "climbed", "legs", "refines", "next_fit",
        "next_report", "best_w", "leg_lo", "leg_hi", "lead", "rate", "settle_to",
        "fit_top", "_report_from",
    )  # fmt: skip

    def __init__(self, cfg: SeekerConfig, dt: float, max_velocity: float) -> None:
        super().__init__(cfg, dt, max_velocity)
        self.filter = TrajectoryFilter(cfg.filter.order, cfg.filter.pole, dt)
        self.rows = Rows(dt)
        self.tracker: Tracker | None = None
        self.direction = 1.0
        self.climbed = False
        self.legs = 0
        self.refines = 0
        self.next_fit = cfg.start_delay + REFIT
        self.next_report = cfg.start_delay + REPORT
        self.best_w = math.nan
        self.leg_lo = self.leg_hi = math.nan  # the span a refine pass covers
        # a ramp through n lags of pole p lags by n/p seconds: γ leads wd by that much
        self.lead = cfg.filter.order / cfg.filter.pole
        self.rate = 0.0
        self.settle_to = math.nan
        self.fit_top: Fit | None = None
        self._report_from = cfg.start_delay

    def begin(self, w0: float) -> None:
        self.filter.reset(w0)
        self._copy_reference()
        self.direction = 1.0 if self.target >= w0 else -1.0
        self.phase = DELAY

    def _copy_reference(self) -> None:
        f = self.filter
        self.wd, self.ad, self.jd = f.wd, f.ad, f.jd

    def hold(self, t: float) -> None:
        self.filter.step(self.target)
        self._copy_reference()

    # -- one period ------------------------------------------------------------------------
    def update(self, t: float, q: float, p: float, e: float) -> Evaluation | None:
        x = self.wd + e if self.velocity_abscissa else self.wd
        ev = None
        if t >= self.cfg.start_delay and (
            self.phase != DELAY or abs(self.ad) <= ACC_GATE * max(self.wd, self.lo)
        ):
            self.rows.add(t, q, p, x, self.wd)
            phase = self.phase
            if phase == DONE:
                tracker = self.tracker
                if tracker is not None:
                    ev = tracker.update(t)
                    self.target = tracker.target(t + self.dt)
            else:
                if phase == DELAY:
                    self.phase = MEASURING
                if self.phase == MEASURING:
                    self._advance_candidate()
                if t >= self.next_fit:
                    self.next_fit = t + REFIT
                    ev = self._decide(t)
        self.filter.step(self.target)
        self._copy_reference()
        return ev

    def _advance_candidate(self) -> None:
        """γ moves along the leg, at most the filter's ramp lag ahead of wd."""
        step = self.direction * self.rate * max(self.wd, self.lo) * self.dt
        if step == 0.0:
            return
        ahead = abs(self.target + step - self.wd)
        if ahead <= self.lead * self.rate * max(self.wd, self.lo) * 1.2:
            self.target = self.clamp(self.target + step)

    # -- decisions, every REFIT seconds ----------------------------------------------------
    def _decide(self, t: float) -> Evaluation | None:
        ev = self._report(t)
        if self.phase == SETTLING:  # on the way to the vertex, then done
            if abs(self.wd - self.settle_to) <= max(0.02 * self.settle_to, self.cfg.e2):
                self._converge(t)
            return ev
        recent = self.rows.view(t - TRAIL)
        if len(recent) < MIN_ROWS:
            self.rate = self.cfg.sweep_rate
            return ev
        w_now = float(recent[:, W].mean())
        top = self._top_fit(self.best_w if math.isfinite(self.best_w) else w_now)
        self.fit_top = top
        if self.refines:
            if self._refine_done():
                self._finish(t)
            else:  # slowly across the span, quickly to it
                inside = self.leg_lo <= self.wd <= self.leg_hi
                self.rate = self.cfg.sweep_rate * (0.5 if inside else 2.0)
            return ev
        trail = self._trailing(t)
        slope, se = trail.slope(w_now) if trail is not None else (0.0, math.inf)
        along = slope * self.direction
        if along > K_SLOPE * se:
            self.climbed = True
        # far below the top and climbing: hurry through what cannot be the top
        p_now = trail.value(w_now) if trail is not None else math.nan
        peak = top.value(self.best_w) if top is not None else math.nan
        low = max(0.0, 1.0 - p_now / peak) if peak > 0.0 and math.isfinite(p_now) else 0.0
        fast = min(1.0, low / 0.1) if along > 0.0 else 0.0
        self.rate = self.cfg.sweep_rate * (1.0 + (FAST - 1.0) * fast)
        verdict = self._bracketed(top, w_now)
        if verdict == "bracketed":
            self._finish(t)
        elif (
            verdict == "behind"
            or (along < -K_SLOPE * se and not self.climbed)
            or (along < -K_SLOPE * se and verdict != "ahead")
        ):
            self._reverse()
        else:
            at_edge = self._at_edge()
            if at_edge is not None:
                if along > K_SLOPE * se and self.expand(at_edge):
                    return ev
                if along > K_SLOPE * se or self.legs >= 1:
                    self._finish(t)
                else:
                    self._reverse()
        return ev

    def _bracketed(self, top: Fit | None, w_now: float) -> str:
        """Where the top is, from the quadratic through the rows near it: "bracketed" (rows
        on both sides, at least MARGIN beyond it or at a bound), "behind" (passed and
        receding, the other side unseen), "ahead", or "unknown"."""
        if top is None or not top.concave(K_SLOPE):
            return "unknown"
        v, se = top.vertex()
        if not math.isfinite(v) or se > 0.25 * v:
            return "unknown"
        tol = max(0.01 * self.hi, 0.5 * self.cfg.e2)
        below = top.w_lo <= v * (1.0 - MARGIN) or top.w_lo <= self.lo + tol
        above = top.w_hi >= v * (1.0 + MARGIN) or top.w_hi >= self.hi - tol
        if below and above:
            return "bracketed"
        past = (w_now - v) * self.direction
        if past > MARGIN * v:
            return "behind"
        return "ahead" if past < 0.0 else "unknown"

    def _trailing(self, t: float) -> Fit | None:
        """A line through the last second of rows (or revolution, up to 4 s, with ripple)."""
        w = max(self.wd, self.lo)
        rev = 2.0 * math.pi / w
        span = min(max(TRAIL, rev), TRAIL_MAX)
        d = self.rows.view(t - span)
        if len(d) < MIN_ROWS:
            return None
        covered = (float(d[-1, T] - d[0, T])) * w
        ripple = covered >= 0.75 * 2.0 * math.pi  # the ripple can be told apart
        spread = float(np.ptp(d[:, W]))
        if spread <= 1e-6:
            return None
        return fit(d, float(d[-1, W]), max(spread, 1e-3), curvature=0.0, ripple=ripple)

    def _at_edge(self) -> str | None:
        """γ held at a bound and wd arrived there."""
        tol = max(0.01 * self.hi, 0.5 * self.cfg.e2)
        if self.direction > 0 and self.target >= self.hi and self.wd >= self.hi - tol:
            return "upper"
        if self.direction < 0 and self.target <= self.lo and self.wd <= self.lo + tol:
            return "lower"
        return None

    def _reverse(self) -> None:
        self.direction = -self.direction
        self.climbed = False
        self.legs += 1
        self.target = self.clamp(self.wd + self.direction * 1e-3)

    def _refine_done(self) -> bool:
        """A refine pass has crossed its span."""
        if self.direction > 0:
            return self.wd >= self.leg_hi or self.target >= self.hi
        return self.wd <= self.leg_lo or self.target <= self.lo

    # -- the top -----------------------------------------------------------------------------
    def _top_fit(self, centre: float) -> Fit | None:
        """The quadratic through the rows within ±30 % of the top, the centre moved to the
        vertex (twice at most); keeps ``best_w``, the best estimate of where the top is."""
        d = self.rows.view()
        f = None
        for _ in range(3):
            near = d[np.abs(d[:, W] - centre) <= TOP * centre]
            if len(near) < MIN_ROWS:
                return f
            g = fit(near, centre, max(TOP * centre, 1e-3))
            if g is None:
                return f
            f = g
            v, _ = f.vertex()
            if math.isfinite(v) and f.concave(K_SLOPE):
                new = min(max(v, f.w_lo), f.w_hi)
            else:  # no top in sight: the better end of what was seen
                new = f.w_hi if f.value(f.w_hi) >= f.value(f.w_lo) else f.w_lo
            new = min(max(new, self.lo), self.hi)
            if abs(new - centre) <= 0.02 * centre:
                centre = new
                break
            centre = new
        self.best_w = centre
        return f

    def _finish(self, t: float) -> None:
        """The top is bracketed (or a bound reached): locate it, refine if it is not known
        well enough, else go there."""
        cfg = self.cfg
        f = self._top_fit(self.best_w)
        self.fit_top = f
        side = self._edge_verdict()
        if side is not None:
            if self.expand(side):
                self.direction = 1.0 if side == "upper" else -1.0
                self.climbed = True
                self.refines = 0
                return
            self.at_bound = side
            self._go(self.hi if side == "upper" else self.lo, f)
            self.reason = f"the optimum lies beyond the {side} bound: widen the bracket"
            return
        v, se = (math.nan, math.inf) if f is None else f.vertex()
        if f is None or not f.concave() or not math.isfinite(v):
            if self.refines < MAX_REFINE:  # look again, slowly, around the best point
                self._refine(self.best_w, 0.2 * self.best_w)
                return
            # no maximum in the data: a flat top; the best point seen is as good as any
            self._go(self.best_w, f)
            self.reason = "no curvature above the noise: the best point seen"
            self.converged_at(t, self.target, self.optimum_power)
            return
        v = min(max(v, f.w_lo, self.lo), f.w_hi, self.hi)
        c2, _ = f.curvature
        level = max(f.value(v), 1e-12)
        loss = 0.5 * abs(c2) * (2.0 * se) ** 2 / level
        if loss > cfg.power_tol and self.refines < MAX_REFINE:
            self._refine(v, max(0.1 * v, 2.0 * se))
            return
        self.reason = (
            "optimum located" if loss <= cfg.power_tol else "refine passes spent: best estimate"
        )
        self._go(v, f)
        self.converged_at(t, v, self.optimum_power)

    def _refine(self, v: float, half: float) -> None:
        """One more pass across v ± half, towards its far end, more slowly than the search."""
        v = self.clamp(v)
        self.leg_lo, self.leg_hi = max(v - half, self.lo), min(v + half, self.hi)
        self.refines += 1
        self.direction = 1.0 if self.wd < v else -1.0
        self.target = self.clamp(self.wd + self.direction * 1e-3)
        self.rate = 0.5 * self.cfg.sweep_rate

    def _edge_verdict(self) -> str | None:
        """A bound the power still rises through, by K_EDGE standard errors of the slope of
        a line through the rows near it."""
        for side, edge in (("upper", self.hi), ("lower", self.lo)):
            d = self.rows.view()
            near = d[np.abs(d[:, W] - edge) <= 0.1 * edge]
            if len(near) < MIN_ROWS or float(np.ptp(near[:, W])) < 0.02 * edge:
                continue
            f = fit(near, edge, 0.1 * edge, curvature=0.0)
            if f is None:
                continue
            slope, se = f.slope(edge)
            outward = slope if side == "upper" else -slope
            if outward > K_EDGE * se and min(abs(self.best_w - edge), abs(self.wd - edge)) < (
                0.1 * edge
            ):
                return side
        return None

    def _go(self, v: float, f: Fit | None) -> None:
        v = self.clamp(v)
        self.target = v
        self.settle_to = v
        self.optimum = v
        self.optimum_power = f.value(v) if f is not None else None
        self.phase = SETTLING
        self.rate = 0.0

    def _converge(self, t: float) -> None:
        self.phase = DONE
        self.done = True
        self.reason = self.reason or "optimum located"
        if self.cfg.track:
            curv = None
            if self.fit_top is not None and self.fit_top.concave():
                curv = self.fit_top.curvature[0]
            assert self.optimum is not None
            f = self.fit_top
            noise = (f.sigma, f.inflate) if f is not None else None
            self.tracker = Tracker(self, self.optimum, curv, t, self.rows, noise)
            self.tracking = True

    def _report(self, t: float) -> Evaluation | None:
        """One evaluation a second while searching: the mean velocity of that second and the
        ripple-free power the rows give there."""
        if t < self.next_report:
            return None
        self.next_report = t + REPORT
        d = self.rows.view(self._report_from)
        self._report_from = t
        if len(d) < MIN_ROWS:
            return None
        w = float(d[:, W].mean())
        f = fit(d, w, max(float(np.ptp(d[:, W])), 1e-3), curvature=0.0, ripple=False)
        power = f.value(w) if f is not None else float(d[:, 2].mean())
        se = math.sqrt(max(float(f.cov[0, 0]), 0.0)) if f is not None else math.inf
        ev = Evaluation(float(d[-1, T]), w, power, se)
        self.evaluations.append(ev)
        return ev

    def fraction(self) -> float:
        if self.done:
            return 1.0
        return min(0.2 * self.legs + 0.25 * self.refines + (0.5 if self.climbed else 0.0), 0.95)
