"""The sweep seeker: learn p(w) from every sample while the candidate moves, not only from
settled windows.

A numerical seeker of Appendix A spends ~4 s of a person's effort per candidate (the filter
settles, then at least a revolution is averaged) and throws away what it saw in between. The
sweep keeps every sample: the loop's (t, q, p, w) become 20 ms rows (:mod:`.regression`), and
p is regressed on where it was produced with the stroke ripple (first and second harmonic,
multiplicative) regressed out, so the candidate can move all the time.

1. **Lead-in.** From rest the trajectory filter brings wd to γ2, as for any candidate. Rows
   are kept from the end of the start delay, once the lead-in's acceleration has eased (while
   the reference accelerates hard, τ̂ = τ − J ė is off by the tracking error's transient).
2. **Locate.** The candidate moves along a direction at ``sweep_rate``·w per second, up to 4×
   faster while it climbs a steep flank (a power elasticity d ln p/d ln w above 0.15: far from
   the top), never more than the filter's ramp lag ahead of wd, never outside [lo, hi]. Every
   0.2 s a line through the last ~10 % of w travelled (0.5-2 s of rows, the ripple divided
   out) gives the local slope; a slope counts when it is K_SLOPE standard errors and an
   elasticity of MIN_ELASTICITY away from zero. Downhill along the leg: the power falls on that
   side of the top; the leg reverses, unless it has fallen on both sides. The lines need the
   stroke ripple divided out, learnt once the stroke has turned CLIMB_TURN (half a
   revolution) and trusted to turn a leg round only from TURN (a whole one) on: at a slow
   cadence a revolution takes seconds (5 s at 1.2 rad/s) during which the first leg crept
   at ``sweep_rate`` up a steep flank it could already see; half a revolution's ripple may
   misread a flat stretch as a fall, and a leg turned the wrong way costs far more than one
   that climbs on slowly. Until TURN a climb speeds the leg up only once wd is past γ2:
   before that the rows are the lead-in's approach to γ2, and a leg sped up there ran on at
   4× far past a top just beyond γ2 (docs/benchmarks.md, "Half a revolution speeds a climb
   up").
   The quadratic through the rows within ±30 % of the top may see both sides fall first
   (by DROP, at K_BRACKET standard errors; a side the trailing line saw fall needs no
   second proof: a fast leg leaves few rows there). At a bound while climbing: one expansion
   step (``expand``), or the search ends there; reaching a bound counts as that side seen.
3. **Refine.** Passes across the band where the fitted power is within 1 % of its top,
   v ± sqrt(0.02 p/|p''|) (3-30 % of v), re-centred on the vertex after each pass: the
   candidate stays within the 99 % band while the estimate sharpens. Converged once
   ½|p''|(2σv)² ≤ ``power_tol``·p (the optimum known to within that fraction of the power at
   two standard errors), or after MAX_REFINE passes on the best estimate. A top fitted to
   fewer than TOP_ROWS rows (a locate leg crossing it fast) needs one refine pass first.
   Before the top fit shows a significant maximum, the first pass is centred where a local
   smoother of the locate legs' rows peaks and spans their 99 % band
   (:func:`~.regression.smooth_top`: no parabola through ±30 % of a sharp or skewed top,
   and no centre put where a fast leg's few rows happened to be), not ±UNKNOWN_BAND around
   the coarse best point. The candidate never goes past the pass's far end (the filter's
   lag would carry wd on beyond it), and the far end is pulled in to the band the top fit
   shows once it shows one, so the pass ends inside the person's 99 % band. A pass ends
   once wd is near its far end, a bound or not (the candidate is at a bound long before wd).
4. **Track.** The candidate goes to the vertex and a :class:`~sessions.seekers.tracker.Tracker`
   follows it (``track``, the default) with the curvature and noise the sweep measured.

An edge is an optimum only if the power does not still rise through it: for ``at_bound`` the
slope at the bound, from the rows within 10 % of it, must point outward by K_EDGE standard
errors; otherwise a top at the bound is a converged optimum like any other.
"""

from __future__ import annotations

import math

import numpy as np

from sessions.config import SeekerConfig
from sessions.filters import TrajectoryFilter
from sessions.seekers.base import DELAY, DONE, MEASURING, SETTLING, Evaluation, Seeker
from sessions.seekers.regression import (
    Fit,
    P,
    Rows,
    T,
    W,
    fit,
    fit_ripple,
    smooth_top,
    without_ripple,
)
from sessions.seekers.tracker import Tracker, shrunk_curvature

REFIT = 0.2  # s between decisions
REPORT = 1.0  # s between the evaluations the sweep records
TRAIL_SPAN = 0.1  # the trailing line covers this fraction of w travelled …
TRAIL_MIN, TRAIL_MAX = 0.5, 2.0  # … within these many seconds
K_SLOPE = 2.5  # standard errors for "climbing" / "falling"
MIN_ELASTICITY = 0.03  # |d ln p / d ln w| below this is no slope (a model's misfit, not data)
K_BRACKET = 2.0  # standard errors for "the quadratic sees both sides fall" (the fits'
# standard errors are 2-2.5x their scatter, docs/benchmarks.md: 2 of them are 4-5 real ones)
DROP = 0.01  # a side of the top is seen once the power there is this fraction below it
SIDE_ROWS = 25  # rows (half a second) needed on each side of the vertex
K_EDGE = 3.0  # standard errors for "the power still rises through the bound"
TOP = 0.3  # the top fit's half-width, fraction of the velocity …
NARROWEST = 0.08  # … narrowed down to this on a sharp top
MISFIT = 4.0  # |t| of an x³ or x⁴ term above which the parabola does not fit that wide
MAX_REFINE = 6
TOP_ROWS = 150  # a top from fewer rows (3 s: a couple of revolutions) needs a refine pass:
# a locate leg crossing it fast gives a standard error the ripple and the noise's correlation
# over so few rows make far too small (a flat top read as the sharpest a person has)
FAST = 4.0  # the most a leg speeds up on a steep flank
STEEP = (0.15, 0.45)  # elasticities from which a leg speeds up, and at which it is fastest
ACC_GATE = 0.3  # rows start once |ad| is below this fraction of w per second
MIN_ROWS = 12
CLIMB_TURN = math.pi  # rad the stroke turns before a learnt ripple may speed a climb up …
TURN = 2.0 * math.pi  # … and before a fall it shows may turn a leg round
UNKNOWN_BAND = 0.15  # a refine pass's half-width before the curvature is known
RIPPLE_MEMORY = 30.0  # s of rows the ripple is learnt from


class SweepSeeker(Seeker):
    kind = "sweep"
    __slots__ = (
        "filter", "rows", "tracker", "stage", "direction", "dropped", "legs", "passes",
        "next_fit", "next_report", "best_w", "best_p", "span", "lead", "rate", "settle_to",
        "fit_top", "ripple", "ripple_known", "ripple_whole", "gate_t", "q_first", "q_last",
        "_report_from",
    )  # fmt: skip

    def __init__(self, cfg: SeekerConfig, dt: float, max_velocity: float) -> None:
        super().__init__(cfg, dt, max_velocity)
        self.filter = TrajectoryFilter(cfg.filter.order, cfg.filter.pole, dt)
        self.rows = Rows(dt)
        self.tracker: Tracker | None = None
        self.stage = "lead"
        self.direction = 1.0
        self.dropped: set[str] = set()  # the sides on which the power was seen to fall
        self.legs = 0
        self.passes = 0
        self.next_fit = cfg.start_delay + REFIT
        self.next_report = cfg.start_delay + REPORT
        self.best_w = math.nan  # coarse: where the trailing lines saw the most power
        self.best_p = -math.inf
        self.span = (math.nan, math.nan)  # a refine pass's interval
        # a ramp through n lags of pole p lags by n/p seconds: γ leads wd by that much
        self.lead = cfg.filter.order / cfg.filter.pole
        self.rate = cfg.sweep_rate
        self.settle_to = math.nan
        self.fit_top: Fit | None = None
        self.ripple = (0.0, 0.0, 0.0, 0.0)
        self.ripple_known = False
        # learnt over TURN: a fall it shows may turn a leg round; until then a climb it shows
        # speeds the leg up only past γ2, the lead-in's approach to γ2 left to the filter
        self.ripple_whole = False
        self.gate_t = math.inf  # rows from here on are used for p(w); all of them for the ripple
        self.q_first = self.q_last = math.nan
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
        if t >= self.cfg.start_delay:
            self.rows.add(t, q, p, x, self.wd)
            if self.q_first != self.q_first:  # nan: the first sample
                self.q_first = q
            self.q_last = q
        if t >= self.cfg.start_delay and (
            self.stage != "lead" or abs(self.ad) <= ACC_GATE * max(self.wd, self.lo)
        ):
            if self.stage == "track":
                tracker = self.tracker
                if tracker is not None:
                    ev = tracker.update(t)
                    self.target = tracker.target(t + self.dt)
            else:
                if self.stage == "lead":
                    self.stage, self.phase = "locate", MEASURING
                    self.gate_t = t
                if self.stage != "settle":
                    self._advance_candidate()
                if t >= self.next_fit:
                    self.next_fit = t + REFIT
                    ev = self._decide(t)
        self.filter.step(self.target)
        self._copy_reference()
        return ev

    def _advance_candidate(self) -> None:
        """γ moves along the leg, at most the filter's ramp lag ahead of wd; in a refine
        pass it stops at the span's end (the filter's cascade of lags then brings wd there
        without overshoot)."""
        speed = self.rate * max(self.wd, self.lo)
        step = self.direction * speed * self.dt
        if abs(self.target + step - self.wd) <= 1.2 * self.lead * speed:
            target = self.target + step
            if self.stage == "refine":
                lo, hi = self.span
                inside = lo <= self.wd <= hi
                if inside or (self.wd - hi) * self.direction < 0.0:
                    # never past the span's far end: the filter's lag would carry wd on
                    target = min(max(target, lo), hi)
            self.target = self.clamp(target)

    # -- decisions, every REFIT seconds ----------------------------------------------------
    def _decide(self, t: float) -> Evaluation | None:
        ev = self._report(t)
        if self.stage == "settle":  # on the way to the vertex, then done
            if abs(self.wd - self.settle_to) <= max(0.02 * self.settle_to, self.cfg.e2):
                self._converge(t)
            return ev
        centre = self.best_w if math.isfinite(self.best_w) else self.wd
        self.fit_top = self._top_fit(centre)
        self._learn_ripple(t)
        if self.stage == "refine":
            self._refine_step(t)
        else:
            self._locate_step(t)
        return ev

    def _learn_ripple(self, t: float) -> None:
        """The stroke ripple, once the rows cover CLIMB_TURN of the stroke (whole from TURN on):
        a cubic in w times the ripple through the last RIPPLE_MEMORY seconds of rows (lead-in
        included: a smooth bias in the power does not look like a function of the angle)."""
        turned = self.q_last - self.q_first
        if not turned >= CLIMB_TURN:
            return
        d = self.rows.view(t - RIPPLE_MEMORY)
        if len(d) < 4 * MIN_ROWS:
            return
        w = d[:, W]
        x = (w - w.mean()) / max(float(w.std()), 1e-6)
        cols = [np.ones(len(d)), x, x * x, x * x * x]
        f = fit_ripple(d, cols)
        if f is not None:
            self.ripple, self.ripple_known = f, True
            self.ripple_whole = turned >= TURN

    def _locate_step(self, t: float) -> None:
        if not self.ripple_known:  # until then a slope may be the stroke's, not the curve's
            return
        trail = self._trailing(t)
        if trail is None:
            return
        w_now = 0.5 * (trail.w_lo + trail.w_hi)
        p_now = trail.value(w_now)
        slope, se = trail.slope(w_now)
        se = max(se, MIN_ELASTICITY * abs(p_now) / (K_SLOPE * w_now))  # see MIN_ELASTICITY
        if p_now > self.best_p:
            self.best_w, self.best_p = w_now, p_now
        along = slope * self.direction
        elasticity = along * w_now / max(abs(p_now), 1e-12)
        steep = min(max((elasticity - STEEP[0]) / (STEEP[1] - STEEP[0]), 0.0), 1.0)
        climbing = along > K_SLOPE * se
        if not self.ripple_whole and (self.wd - self.cfg.bracket[1]) * self.direction < 0.0:
            climbing = False  # still the lead-in's approach to γ2 (see ripple_whole)
        self.rate = self.cfg.sweep_rate * (1.0 + (FAST - 1.0) * steep * climbing)
        ahead = "upper" if self.direction > 0 else "lower"
        if along < -K_SLOPE * se:  # the power falls this way: the top is behind
            if not self.ripple_whole:
                return  # part of a revolution's ripple may speed a climb up, not turn a leg
            self.dropped.add(ahead)
            if len(self.dropped) == 2:
                self._start_refine(t)
            else:
                self._reverse()
        elif self._bracketed(self.fit_top):
            self._start_refine(t)
        else:
            at_edge = self._at_edge()
            if at_edge is not None:
                if climbing and self.expand(at_edge):
                    return
                self.dropped.add(at_edge)  # nothing to see beyond a bound
                if len(self.dropped) == 2 or climbing:
                    self._start_refine(t)
                else:
                    self._reverse()

    def _trailing(self, t: float) -> Fit | None:
        """A line through the rows of the last ~10 % of w travelled, the ripple divided out."""
        span = min(max(TRAIL_SPAN / max(self.rate, 1e-9), TRAIL_MIN), TRAIL_MAX)
        d = self.rows.view(max(t - span, self.gate_t))
        if len(d) < MIN_ROWS:
            return None
        spread = float(np.ptp(d[:, W]))
        if spread <= 1e-6:
            return None
        d = without_ripple(d, self.ripple)
        return fit(d, float(d[-1, W]), max(spread, 1e-3), curvature=0.0, ripple=False)

    def _bracketed(self, top: Fit | None) -> bool:
        """The quadratic through the rows near the top sees it fall on both sides: at the
        rows' lowest and highest velocity the fitted power is below the vertex's by DROP of
        it and by K_BRACKET standard errors (or the rows reach a bound there, or a trailing
        line already saw the power fall on that side: the leg that crossed the top fast and
        reversed left few rows there, and asking the quadratic to see it again ran the next
        leg on down the other flank: #28 of the benchmark's seed 16, a Hill top, went down
        to 0.41 w* and converged at 19.2 s, now 0.49 w* and 15.2 s)."""
        if top is None or not top.concave(K_BRACKET):
            return False
        v, se = top.vertex()
        if not (top.w_lo < v < top.w_hi) or se > 0.25 * v:
            return False
        tol = max(0.01 * self.hi, 0.5 * self.cfg.e2)
        d = self.rows.view(self.gate_t)
        near = d[np.abs(d[:, W] - top.center) <= TOP * top.center][:, W]
        for end, bound, side, name in (
            (top.w_lo, self.lo, near < v, "lower"),
            (top.w_hi, self.hi, near > v, "upper"),
        ):
            if int(side.sum()) < SIDE_ROWS:
                return False
            if abs(end - bound) <= tol or name in self.dropped:
                continue  # a bound, or a side a trailing line already saw fall
            drop, drop_se = top.drop(v, end)
            if not (drop >= DROP * top.value(v) and drop >= K_BRACKET * drop_se):
                return False
        return True

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
        self.legs += 1
        self.target = self.clamp(self.wd + self.direction * 1e-3)

    # -- the top -----------------------------------------------------------------------------
    def _top_fit(self, centre: float) -> Fit | None:
        """The quadratic through the rows near the top: within ±30 % of it, narrowed to
        three 99 %-bands (at least ±8 %) on a sharp top, and while x³ or x⁴ terms are
        significant beyond MISFIT standard errors (a lack-of-fit test: the curve is no
        parabola that wide); its centre moved to the vertex."""
        d = self.rows.view(self.gate_t)
        f = None
        half = TOP
        for _ in range(6):
            near = d[np.abs(d[:, W] - centre) <= half * centre]
            if len(near) < MIN_ROWS:
                return f
            # a level drifting in time (fatigue) once the legs have gone both ways
            both_ways = self.legs + self.passes >= 2
            g = fit(
                near,
                centre,
                max(half * centre, 1e-3),
                misfit_test=half > NARROWEST,
                drift=both_ways,
            )
            if g is None:
                return f
            if g.misfit > MISFIT and half > NARROWEST:  # not a parabola at this width
                f, half = g, max(0.7 * half, NARROWEST)
                continue
            f = g
            v, _ = f.vertex()
            if not (math.isfinite(v) and f.concave(2.0) and f.w_lo <= v <= f.w_hi):
                # no top inside: move towards the better end of what the rows cover
                end = f.w_hi if f.value(f.w_hi) >= f.value(f.w_lo) else f.w_lo
                end = min(max(end, self.lo), self.hi)
                if abs(end - centre) <= 0.02 * centre:
                    return f
                centre = self.best_w = end
                continue
            new = min(max(v, f.w_lo, self.lo), f.w_hi, self.hi)
            band = math.sqrt(2.0 * 0.01 * max(f.value(new), 1e-12) / abs(f.curvature[0]))
            narrow = min(max(3.0 * band / new, NARROWEST), TOP)
            if abs(new - centre) <= 0.02 * centre and narrow >= 0.9 * half:
                return f
            centre, half = new, narrow
        return f

    def _estimate(self) -> tuple[float, float, float]:
        """(v, σv, half-width of the 99 % band) from the top fit; without a significant top,
        the vertex of a concave fit (else the coarse best point) and ±UNKNOWN_BAND."""
        f = self.fit_top
        if f is not None and f.concave(2.0):
            v, se = f.vertex()
            if math.isfinite(v) and f.w_lo <= v <= f.w_hi:
                c2 = abs(f.curvature[0])
                band = math.sqrt(2.0 * 0.01 * max(f.value(v), 1e-12) / c2)
                # 80 % of it: the curvature a parabola fits to a skewed top is a little low
                return self.clamp(v), se, min(max(0.8 * band, 0.03 * v), TOP * v)
        smooth = None
        if self.passes == 0:  # the locate legs' rows: where they peak, and their 99 % band
            smooth = smooth_top(without_ripple(self.rows.view(self.gate_t), self.ripple))
        if smooth is not None:
            w, _, lo, hi = smooth
            v = self.clamp(w)
            return v, math.inf, min(max(0.5 * (hi - lo), 0.03 * v), UNKNOWN_BAND * v)
        v = self.clamp(self.best_w if math.isfinite(self.best_w) else self.wd)
        if f is not None and f.coef[2] < 0.0:  # a maximum, not yet significant: still the best
            u, _ = f.vertex()
            if f.w_lo <= u <= f.w_hi:
                v = self.clamp(u)
        return v, math.inf, UNKNOWN_BAND * v

    def _start_refine(self, t: float) -> None:
        side = self._edge_verdict()
        if side is not None:
            if self.expand(side):
                self.direction = 1.0 if side == "upper" else -1.0
                self.dropped.discard(side)
                return
            self.at_bound = side
            self.reason = f"the optimum lies beyond the {side} bound: widen the bracket"
            self._go(self.hi if side == "upper" else self.lo)
            return
        self.stage = "refine"
        self._next_pass(t)

    def _next_pass(self, t: float) -> None:
        """Converged, or one more pass across the band around the current estimate."""
        cfg = self.cfg
        v, se, half = self._estimate()
        f = self.fit_top
        if f is not None and math.isfinite(se):
            c2 = abs(f.curvature[0])
            loss = 0.5 * c2 * (2.0 * se) ** 2 / max(f.value(v), 1e-12)
            located = loss <= cfg.power_tol and (self.passes > 0 or f.n >= TOP_ROWS)
            if located or self.passes >= MAX_REFINE:
                self.reason = "optimum located" if located else "best estimate"
                self.converged_at(t, v, f.value(v))
                self._go(v)
                return
        elif self.passes >= MAX_REFINE:
            self.reason = "no curvature above the noise: the best point seen"
            self.converged_at(t, v, None)
            self._go(v)
            return
        self.passes += 1
        self.span = (max(v - half, self.lo), min(v + half, self.hi))
        # towards the end of the span farther from where wd is
        self.direction = 1.0 if self.wd < v else -1.0
        self.target = self.clamp(self.wd + self.direction * 1e-3)

    def _refine_step(self, t: float) -> None:
        self._shorten_pass()
        lo, hi = self.span
        inside = lo <= self.wd <= hi
        # slow enough that the filter's lag (lead·rate·w) stays within half the span
        fits = 0.5 * (hi - lo) / 2.0 / (self.lead * max(self.wd, self.lo))
        self.rate = min(self.cfg.sweep_rate, fits) if inside else self.cfg.sweep_rate * FAST
        # the target stops at the span's end and wd approaches it from inside: a tolerance
        near = max(0.1 * (hi - lo), 0.005 * hi)
        done = self.wd >= hi - near if self.direction > 0 else self.wd <= lo + near
        # a bound too: a pass that ended with the candidate there ended at once, and so did
        # the next, every 0.2 s (docs/benchmarks.md, "A pass whose far end is a bound")
        if done:
            self._next_pass(t)

    def _shorten_pass(self) -> None:
        """The pass's far end pulled in to the band the rows now show: a pass begun at the
        unknown-curvature width (±UNKNOWN_BAND) would otherwise carry wd beyond a sharp
        top's 99 % band once the top is known, and back."""
        v, se, half = self._estimate()
        if not math.isfinite(se):
            return
        lo, hi = self.span
        if self.direction > 0:
            self.span = (lo, max(min(hi, v + half + se), lo))
            self.target = min(self.target, max(self.span[1], self.wd))
        else:
            self.span = (min(max(lo, v - half - se), hi), hi)
            self.target = max(self.target, min(self.span[0], self.wd))

    def _edge_verdict(self) -> str | None:
        """A bound the power still rises through, by K_EDGE standard errors of the slope of
        a line through the rows within 10 % of it, the best point seen near it."""
        d = self.rows.view()
        for side, edge in (("upper", self.hi), ("lower", self.lo)):
            if not abs(self.best_w - edge) <= 0.1 * edge:
                continue
            near = d[np.abs(d[:, W] - edge) <= 0.1 * edge]
            if len(near) < MIN_ROWS or float(np.ptp(near[:, W])) < 0.02 * edge:
                continue
            f = fit(near, edge, 0.1 * edge, curvature=0.0)
            if f is None:
                continue
            slope, se = f.slope(edge)
            if (slope if side == "upper" else -slope) > K_EDGE * se:
                return side
        return None

    def _go(self, v: float) -> None:
        v = self.clamp(v)
        f = self.fit_top
        self.target = self.settle_to = self.optimum = v
        self.optimum_power = f.value(v) if f is not None and f.w_lo <= v <= f.w_hi else None
        self.stage, self.phase = "settle", SETTLING
        self.rate = 0.0

    def _converge(self, t: float) -> None:
        self.stage, self.phase = "track", DONE
        self.done = True
        if self.cfg.track:
            f = self.fit_top
            curv = None
            if f is not None and f.concave(2.0):  # as sure as the search was of it
                curv = shrunk_curvature(*f.curvature, f.value(self.optimum), self.optimum)
            noise = (f.sigma, f.inflate) if f is not None else None
            vertex_se = f.vertex()[1] if curv is not None and f is not None else None
            assert self.optimum is not None
            self.tracker = Tracker(self, self.optimum, curv, t, self.rows, noise, vertex_se)
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
        d = without_ripple(d, self.ripple)
        w = float(d[:, W].mean())
        f = fit(d, w, max(float(np.ptp(d[:, W])), 1e-3), curvature=0.0, ripple=False)
        power = f.value(w) if f is not None else float(d[:, P].mean())
        se = math.sqrt(max(float(f.cov[0, 0]), 0.0)) if f is not None else math.inf
        ev = Evaluation(float(d[-1, T]), w, power, se)
        self.evaluations.append(ev)
        return ev

    def fraction(self) -> float:
        if self.done:
            return 1.0
        return min(0.15 * self.legs + 0.5 * (self.stage == "refine") + 0.07 * self.passes, 0.95)
