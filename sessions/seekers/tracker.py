"""The track phase: following an optimum that moves, after the search has converged.

A person's optimum drifts during a session (fatigue lowers the maximal shortening velocity;
the optimal cadence of cycling rises with effort). Once a numerical seeker has converged on
θ, the tracker keeps θ there at a bounded cost and moves it when the power says so:

- a slow dither on the candidate, γ = θ ± SQUARE·A, a square wave of period
  ``dither_period`` (ramped in over one period and clipped to the bracket; the trajectory
  filter rounds its corners): it spreads w around θ so that the local slope of p(w) can be
  seen. A square, not a sine: wd then holds near each extreme for part of every half-period
  instead of passing through it, so the rows spread more around θ for the same excursion of
  wd (the person's cost is paid at the excursion, the slope is seen from the spread). Through
  the default filter, (32) with p = 3 at the 6 s period, a sine of amplitude A moves wd by
  0.795 A with a variance of half that squared; the square of SQUARE·A (0.8 A) by 0.774 A,
  with 0.552 of it squared: over ten benchmark populations 27 people reached 99 % of p* for
  good more than 2 s sooner and 6 later, no median slower (docs/benchmarks.md). A is as
  small as the noise allows: the amplitude at which the slope
  over ``track_memory`` pins θ down to PRECISION (2 %), from the fit's own residual noise,
  between 0.8 % of θ (less would drown in what the model misses) and ``dither``·θ (5 %),
  and more, in proportion, while the Kalman filter below knows θ worse than PRECISION,
  and never more than loses DITHER_COST (0.3 %) of the power at its extremes on the
  measured curvature (½|p''|A² ≤ 0.003 p; wd's excursion, 0.774 A, costs 0.6 of that). On
  average it costs about a third of that cap, well within the 1 % the issue allows;
- every ``REFIT`` seconds, the local model of :mod:`.regression` over the samples since the
  track phase began near θ (three dither amplitudes, 8-30 % of θ), weighted by
  exp(−age/``track_memory``), with the ripple and a drift in time regressed out and the
  curvature held near the search's (a ridge), else the generic −2p/θ² of a top where ±10 %
  in w costs 1 % in p. The drift may curve (τ², kept where its t reaches K_BEND): fatigue
  lowers the level exponentially, by far more than a small dither moves the power, and a
  curved trend fitted as a line leaks into the slope (a clean person tiring 33 % in two
  minutes walked θ 9 % off a w* that never moved);
- the rows' abscissa (wd + ē, :mod:`.regression`) averages the tracking error over
  ``track_memory`` instead of the search's second: wd now moves by a dither of 1-5 % of θ,
  and the person's fluctuation left in a one-second ē (pushing harder speeds the handle up
  as it raises the power) is then a good part of the abscissa's spread, in step with the
  power's noise: an errors-in-variables slope that walked θ up (+12 % in 100 s on a sharp
  person with 4 % noise and the 0.8 % dither floor). A lasting tracking error stays in ē;
- the first refit comes 2·REFIT after the track phase begins, not a whole dither period
  later: until its own dither has run a period, the fits also take the search's last
  LOOKBACK seconds of rows (the end of its last refine pass and the settling onto the
  vertex, a spread of w around θ the dither takes a period to give), their abscissa
  re-based on the longer average of the tracking error (:meth:`~.regression.Rows.smooth`).
  θ held a dither period where the search left it while a drifting w* moved on (a clean
  Hill person: 10.6 % above w* over the next 6-12 s, now 3.3 %). Only until then: kept
  as long as any row (3·track_memory), the refine pass's spread read a sharp top's
  asymmetry as a slope under a 1 % dither (θ +1.6 %);
- a pause (no samples for PAUSE: a protocol's rest between work intervals) is no part of
  the person's curve: the rows of the first RESUME seconds after it are left out of the fits.
  The person's effort comes back from rest within a second, a step in the power far larger
  than the dither moves it, and lined up with one side of the dither it read as a slope (θ
  19 % above w* over the first work interval of an interval training);
- the model's slope may change in time (an x·τ term): its vertex at the latest row is the
  optimum *now*, so a drifting optimum is followed without the window's lag;
- that vertex v (standard error σv) moves θ through a Kalman filter: it starts at the
  search's vertex with that vertex's standard error (at least PRECISION·θ: a vertex the search
  knew to 6 % is no 2 % fact), the optimum a random walk of WANDER·θ per √s, each refit a
  measurement of variance σv²·track_memory/REFIT (the windows overlap: a refit brings
  REFIT/track_memory of new data). On a clean signal θ follows within seconds; on a noisy
  one it moves only as the evidence accumulates, so noise does not make it wander. At most
  ``RATE``·θ per second;
- the slope decides when the vertex cannot (:meth:`Tracker._slope_step`): with the search's
  curvature held, the vertex now is u ± σu, and |u − θ| > K_SLOPE·σu means the slope at θ
  rejects θ as the optimum. On a flat top σu is 20-30 % of θ at every refit (the filter
  takes no vertex) while that slope is significant: θ is then sent to the nearest point
  the slope does not reject, u ± K_SLOPE·σu (a vertex known to PRECISE_STEP of θ, with no
  other maximum near θ, is a whole Newton step);
- the session ends on θ: the dither explores for what follows it, and at the seek's end
  (the owner's ``ends_at``, told by the protocol runner: the session's duration, a seek
  phase's end unless the training after it tracks on) nothing does. The dither fades out
  over the half-period before the last one, and wd settles on θ, the optimum stored: four
  benchmark people ended at 0.987-0.989 of p* on the dither's extreme, on the side θ erred
  to, while θ was above 0.99;
- at a bound (within the search's tolerance of it), with the slope there pointing outward
  beyond two standard errors: ``at_bound`` (or
  one expansion step with ``expand``). When θ leaves the bound again the optimum has come
  inside: the search's result is then recorded as converged there.

The curvature held is the sweep's, shrunk towards a generic top where the sweep saw it at
less than KNOWN standard errors (:func:`shrunk_curvature`): a square dither shows a slope,
never a curvature, so a curvature held too sharp is never corrected, and it sizes
everything: the dither's cost cap, the vertex's step (−slope/curvature), the ridge. A
skewed person with 6 % noise (#67 of the benchmark's seed 21) handed over at +16 % on a
curvature 18× the top's there (2.4 standard errors from zero) kept a 1.4 % dither whose
every refit put the vertex within 1 % of θ: θ stayed 14-16 % above w* to the end (p/p*
0.978); shrunk, the dither is 4 % and θ comes down (0.99).

Each refit records an :class:`Evaluation` at θ (the fitted power there).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from sessions.seekers.base import Evaluation
from sessions.seekers.regression import MAX_SHARPNESS, Fit, P, Rows, T, W, fit

if TYPE_CHECKING:
    from sessions.seekers.base import Seeker

REFIT = 1.0  # s between steps
WANDER = 0.015  # the optimum's random walk, fraction of θ per √s (the filter's prior; 2 % let a
# noisy steady top wander out of its band: docs/benchmarks.md, "A prior of 1.5 %")
RATE = 0.02  # the most θ moves, as a fraction of θ per second
WINDOW = 0.3  # rows within three dither amplitudes of θ are used, at most this fraction …
NARROW = 0.08  # … and at least this one (away from θ a Hill curve is no parabola)
MIN_ROWS = 50
DITHER_COST = 0.003
PRECISION = 0.02
MIN_DITHER = 0.008
K_SLOPE = 2.5  # standard errors of the slope at θ that reject θ as the optimum
K_BEND = 3.0  # standard errors of the level's curvature in time that keep it in the model
PAUSE = 0.1  # s without samples: the session paused the tracker (a protocol's rest) …
RESUME = 2.0  # … and the rows of this long after it came back are left out of the fits
SQUARE = 0.8  # the square dither's height, fraction of A: wd's excursion a sine's (above)
PRECISE_STEP = 0.05  # a Newton step is taken whole when its vertex is known to this of θ
LOOKBACK = 6.0  # s of the search's last rows the fits use until a dither period has run
SHARPNESS_SPREAD = 2.0  # how far a person's top may be from the generic one, in its sharpness
KNOWN = 3.0  # standard errors from zero beyond which the search's curvature is kept as it is


def generic_curvature(level: float, theta: float) -> float:
    """d²p/dw² of a generic top at θ: ½|p''|θ²/p = 1, ±10 % in w costing 1 % in p."""
    return -2.0 * max(level, 1e-12) / theta**2


def shrunk_curvature(c: float, se: float, level: float, theta: float) -> float:
    """The search's curvature c ± se, kept beyond KNOWN standard errors from zero; one the
    search barely saw (a stopping rule that stops once the curvature looks sharp stops on
    sharp-looking noise: 2.4 standard errors and 18× the top's own) combined with what any
    person's top is, the generic curvature g ± SHARPNESS_SPREAD·|g| (sharpness 1 ± 2: from
    a flat top's 0.1 to a sharp one's 5 within about two of its standard errors), weighted
    by inverse variances: brought within a few times of the generic."""
    if c < -KNOWN * se:
        return c
    g = generic_curvature(level, theta)
    w_fit, w_gen = 1.0 / max(se * se, 1e-300), 1.0 / (SHARPNESS_SPREAD * g) ** 2
    return (c * w_fit + g * w_gen) / (w_fit + w_gen)


def smoothstep(x: float) -> float:
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


class Tracker:
    __slots__ = (
        "owner", "rows", "theta", "curv", "t0", "amp", "omega", "period", "memory",
        "next_fit", "last_fit", "level", "noise", "amp_now", "x", "var", "seen", "resumed",
    )  # fmt: skip

    def __init__(
        self,
        owner: Seeker,
        theta: float,
        curvature: float | None,
        t0: float,
        rows: Rows,
        noise: tuple[float, float] | None = None,
        vertex_se: float | None = None,
    ) -> None:
        cfg = owner.cfg
        self.owner = owner
        self.rows = rows
        # the abscissa's noise well below the dither's spread, from the search's last rows on
        rows.smooth(cfg.track_memory, since=t0 - LOOKBACK)
        self.theta = owner.clamp(theta)
        self.curv = curvature if curvature is not None and curvature < 0.0 else None
        self.t0 = t0
        self.amp = cfg.dither
        self.period = cfg.dither_period
        self.omega = 2.0 * math.pi / cfg.dither_period
        self.memory = cfg.track_memory
        self.next_fit = t0 + REFIT
        self.last_fit = t0 + REFIT
        self.level = owner.optimum_power
        self.noise = noise  # (residual std of a row, its correlation inflation)
        self.x = self.theta  # the Kalman filter's estimate of the optimum and its variance:
        # known as well as the search knew its vertex, and no better than PRECISION
        known = vertex_se if vertex_se is not None and math.isfinite(vertex_se) else 0.0
        self.var = max(PRECISION * self.theta, known) ** 2
        self.amp_now = self._wanted()
        self.seen = t0
        self.resumed: list[float] = []  # when the samples came back after a pause
        owner.optimum = self.theta

    def target(self, t: float) -> float:
        """The candidate at time t: θ with the dither, inside the bounds; the dither ramped in
        over its first period, and out over the half-period before the last one to the
        seek's end (the session ends on θ: the module's docstring)."""
        x = t - self.t0
        a = self.amplitude() * smoothstep(x / self.period)
        left = self.owner.ends_at - t
        if left < self.period:  # the fade; 1 before it, so skipped on most loop periods
            a *= smoothstep(2.0 * left / self.period - 1.0)
        side = math.copysign(1.0, math.sin(self.omega * x))
        return self.owner.clamp(self.theta + SQUARE * a * side)

    def amplitude(self) -> float:
        return self.amp_now

    def _wanted(self) -> float:
        """The first dither amplitude: what the search's noise asks for, within bounds."""
        theta = self.theta
        top = self._cap()
        curv = self._held(self.level)
        if self.noise is None or curv is None:  # unknown: start small, grow as the fit asks
            return min(MIN_DITHER * theta, top)
        sigma, inflate = self.noise
        n = self.memory / self.rows.n_block / self.owner.dt  # rows in the memory
        want = math.sqrt(2.0 * inflate / n) * sigma / (-curv * PRECISION * theta)
        # the filter's own uncertainty: while θ is known worse than PRECISION, more dither
        want *= max(1.0, math.sqrt(self.var) / (PRECISION * theta))
        return min(max(want, MIN_DITHER * theta), max(top, MIN_DITHER * theta))

    def _cap(self) -> float:
        """``dither``·θ, and at most DITHER_COST of the power lost at the dither's extremes."""
        theta = self.theta
        top = self.amp * theta
        level = self.level if self.level is not None and self.level > 0.0 else None
        curv = self._held(level)
        if curv is not None and level is not None:
            top = min(top, math.sqrt(2.0 * DITHER_COST * level / -curv))
        return top

    def _held(self, level: float | None) -> float | None:
        """The curvature the tracker holds: the search's, else a generic top's at ``level``
        (None while the level is unknown)."""
        if self.curv is not None:
            return self.curv
        if level is None or level <= 0.0:
            return None
        return generic_curvature(level, self.theta)

    def update(self, t: float) -> Evaluation | None:
        """A step towards the fitted vertex when one is due; the evaluation it records."""
        if t - self.seen > PAUSE:  # a protocol's rest: the person starts again from it
            oldest = t - 3.0 * self.memory  # what the fits still see (:meth:`_fit`)
            self.resumed = [s for s in self.resumed if s + RESUME > oldest] + [t]
        self.seen = t
        if t < self.next_fit:
            return None
        self.next_fit = t + REFIT
        if t < self.t0 + 2.0 * REFIT:  # a row or two of the track phase's own first
            return None
        dt_fit, self.last_fit = t - self.last_fit, t
        f = self._fit(t)
        if f is None:
            return None
        theta = self.theta
        v, se = f.now if f.now is not None else f.vertex()
        near = math.isfinite(v) and math.isfinite(se) and abs(v - theta) <= WINDOW * theta
        self._filter(v if near else math.nan, se if near else math.inf, dt_fit)
        self._slope_step(t, newton=not near)
        self.x = min(max(self.x, (1.0 - WINDOW) * theta), (1.0 + WINDOW) * theta)
        limit = RATE * theta * dt_fit
        new = self.owner.clamp(theta + min(max(self.x - theta, -limit), limit))
        self._bounds(new, f, t)
        self.theta = new
        power = f.value(new)
        self.level = power
        self.noise = (f.sigma, f.inflate)
        # the dither the fit's noise asks for, by at most 1.5× a refit (it stays smooth)
        self.amp_now = min(max(self._wanted(), self.amp_now / 1.5), self.amp_now * 1.5)
        owner = self.owner
        owner.optimum = new
        owner.optimum_power = power
        ev = Evaluation(t, new, power, math.sqrt(max(float(f.cov[0, 0]), 0.0)))
        owner.evaluations.append(ev)
        return ev

    def _slope_step(self, t: float, *, newton: bool) -> None:
        """When the slope at θ rejects θ as the optimum, θ moves that way even if the vertex
        is poorly known. The fit with the search's curvature held gives the vertex now, u ± σu;
        |u − θ| > K_SLOPE·σu is the slope at θ beyond K_SLOPE standard errors. A vertex known
        to PRECISE_STEP of θ with no other maximum near θ (the rows on a flank): a Newton
        step to u. Otherwise (a flat top: every refit's vertex uncertain by 20-30 % of θ, so
        the Kalman filter takes none of them while w* leaves) θ is sent to the nearest point
        the slope does not reject, u ± K_SLOPE·σu, unless the filter already goes as far."""
        g = self._fit(t, fixed=True)
        if g is None or g.now is None:
            return
        u, su = g.now
        theta = self.theta
        if not (math.isfinite(u) and math.isfinite(su) and abs(u - theta) > K_SLOPE * su):
            return
        if newton and su < PRECISE_STEP * theta:
            self.x = u
            self.var = max(self.var, su * su)
            return
        edge = u + math.copysign(K_SLOPE * su, theta - u)  # between u and θ
        if (self.x - theta) / (edge - theta) < 1.0:  # the filter stops short of it (or turns)
            self.x = edge
            self.var = max(self.var, (edge - theta) ** 2)

    def _fit(self, t: float, *, fixed: bool = False) -> Fit | None:
        """The local model around θ (within three dither amplitudes), from the rows of the
        track phase (the search's moves are transients: the tracking error and τ̂ are off
        while wd accelerates), weighted by age, the curvature held near the search's (a
        ridge: a dither alone cannot pin it down)."""
        theta = self.theta
        half = min(WINDOW, max(3.0 * self.amp_now / theta, NARROW))
        # until its own dither has run a whole period, the search's last rows too
        first = self.t0 - LOOKBACK if t < self.t0 + self.period else self.t0
        d = self.rows.view(since=max(t - 3.0 * self.memory, first))
        d = d[np.abs(d[:, W] - theta) <= half * theta]
        for start in self.resumed:  # the person's effort coming back is no slope
            d = d[(d[:, T] < start) | (d[:, T] >= start + RESUME)]
        if len(d) < MIN_ROWS:
            return None
        level = self.level if self.level is not None and self.level > 0.0 else None
        level = level or max(float(np.mean(d[:, P])), 1e-9)
        prior = self._held(level)
        assert prior is not None  # level > 0
        # within what a person's top can be: ½|p''|θ²/p between 0.1 and MAX_SHARPNESS
        sharp = 0.5 * -prior * theta**2 / level
        prior *= min(max(sharp, 0.1), MAX_SHARPNESS) / max(sharp, 1e-12)
        wts = np.exp(-(t - d[:, T]) / self.memory)
        shape = {"curvature": prior} if fixed else {"prior": (prior, 0.5 * -prior)}
        # the level's trend curving in time (fatigue), kept only where the rows show it: a
        # curved trend the model misses leaks into the slope (a dither changes the power by
        # far less than fatigue does), a term the rows cannot see only adds variance
        f = fit(d, theta, half * theta, moving=True, weights=wts, bend=True, **shape)
        if f is not None and f.bend >= K_BEND:
            return f
        return fit(d, theta, half * theta, moving=True, weights=wts, **shape)

    def _filter(self, v: float, se: float, dt: float) -> None:
        """Kalman filter on the optimum: a random walk of WANDER·θ per √s, measured by the
        fitted vertex *now* (the model's slope moves in time) with variance σ²·memory/dt
        (overlapping windows: a refit brings dt/track_memory of new data)."""
        self.var += (WANDER * self.theta) ** 2 * dt
        if math.isfinite(v):
            r = se * se * self.memory / max(dt, 1e-9)
            gain = self.var / (self.var + r)
            self.x += gain * (v - self.x)
            self.var *= 1.0 - gain

    def _bounds(self, new: float, f: Fit, t: float) -> None:
        """At a bound (within :meth:`~.base.Seeker.edge`'s tolerance of it, as the search's
        verdict is) with the slope there pointing outward: at_bound (or expand). Not only on
        it: θ can rest 1 % inside while the slope at the bound points outward at 4 standard
        errors (#23 of the benchmark's seed 20, its w* 37 % above γ3)."""
        owner = self.owner
        side = owner.edge(new)
        if side is not None:
            bound, sign = (owner.hi, 1.0) if side == "upper" else (owner.lo, -1.0)
            slope, slope_se = f.slope(bound)
            if not sign * slope > 2.0 * slope_se:
                side = None
        if side is not None and owner.expand(side):
            side = None
        was = owner.at_bound
        owner.at_bound = side
        # asked again: an expansion has just moved the bound away from θ
        if was is not None and side is None and owner.edge(new) is None:
            owner.converged_at(t, new, f.value(new))  # the optimum came inside
