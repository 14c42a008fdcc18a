"""Perturbation-based extremum seeking, eq. (14) (after Krstić & Wang, Krstić & Deng).

    wd      = ae sin(ωt) + θ
    dθ/dt   = -αf θ + κ
    dκ/dt   = -α0 κ + α0 kf1 (sat(p) - η) ae sin(ωt)                            (14)
    dη/dt   = -kf2 η + kf2 sat(p)
with sat(p) = P·tanh(p/P), ad = ae ω cos ωt + dθ/dt and jd = -ae ω² sin ωt + d²θ/dt²
(analytic derivatives, as the paper asks). Forward Euler at the loop rate: every rate here
is ≤ 15 1/s, so the error at 1 kHz is negligible next to the averaging approximation.

Around it, for a person on the handle (none of it changes (14) itself):
- lead-in: wd rises from the current velocity to θ(0) = γ2 through the trajectory filter, and
  (14) starts once the start delay has passed and |e| ≤ ē1, |wd - γ2| ≤ ē2, with η(0) = p;
- the dither amplitude ramps in (and out) over one period with a smoothstep, so wd, ad, jd
  stay continuous;
- projection: θ is kept inside [γ1 + ae, γ3 − ae], so that wd = θ + ae sin ωt never leaves
  the bracket (the trainer's bounds), κ zeroed when it pushes outward (the paper's footnote 2);
  θ held there with κ pushing outward at the end of a period is ``at_bound``;
- convergence: θ approaches w* geometrically, θ_k − w* ≈ q^k (θ_0 − w*), so a small move per
  period does not mean θ has arrived (at the default tuning it moves less than min_step a
  period within ~0.25 rad/s of w*). θ is settled once, over the last six dither periods, its
  net displacement is below min_step *and* the distance still to go, extrapolated from the
  ratio q of successive moves (|Δ| q/(1 − q)), is below min_step/2. Then, with ``track``
  (the default), (14) keeps running, which is how it follows an optimum that moves; without,
  the dither fades out and wd holds θ. One evaluation (θ, η) is recorded per period.

Default tuning (docs/engine.md; the tests check it converges): ae = 0.2 rad/s,
ω = 1.5 rad/s, α0 = 0.5 1/s, kf1 = 8, kf2 = 0.5 1/s, αf = 0. Three time scales: tracking
(RISE's slow pole ≈ αr = 4 1/s, the fast one ≈ 45 1/s) > ω = 1.5 rad/s ≫ the θ adaptation
rate kf1·ae²/2·|p''| ≈ 0.05-0.1 1/s for the users here. α0 well below ω keeps the stroke-angle
ripple (at the revolution frequency, near ω) and the noise out of the gradient estimate. The
dither costs ≈ |p''|ae²/4 ≈ 0.3 % of p while it runs; it stops once θ settles.
"""

from __future__ import annotations

import itertools
import math

from sessions.config import SeekerConfig
from sessions.filters import TrajectoryFilter
from sessions.seekers.base import DELAY, DONE, MEASURING, SETTLING, Evaluation, Seeker

SETTLE_PERIODS = 6


def _smoothstep(x: float) -> tuple[float, float, float]:
    """s(x) = 3x² - 2x³ on [0, 1] and its first two derivatives."""
    if x <= 0.0:
        return 0.0, 0.0, 0.0
    if x >= 1.0:
        return 1.0, 0.0, 0.0
    return x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x), 6.0 - 12.0 * x


class PerturbationSeeker(Seeker):
    kind = "perturbation"
    __slots__ = (
        "filter", "theta", "kappa", "eta", "t_es", "t_fade", "period", "period_start",
        "theta_marks", "theta_lo", "theta_hi", "ae", "_dtheta", "_ddtheta", "_dither", "_gains",
    )  # fmt: skip

    def __init__(self, cfg: SeekerConfig, dt: float, max_velocity: float) -> None:
        super().__init__(cfg, dt, max_velocity)
        self.filter = TrajectoryFilter(cfg.filter.order, cfg.filter.pole, dt)
        # wd = θ + ae sin ωt stays inside [lo, hi]: θ inside [lo + ae, hi - ae]
        self.ae = min(cfg.amplitude, 0.45 * (self.hi - self.lo))
        self.theta_lo, self.theta_hi = self.lo + self.ae, self.hi - self.ae
        self.theta = min(max(self.target, self.theta_lo), self.theta_hi)
        self.target = self.theta
        self.kappa = 0.0
        self.eta = 0.0
        self.t_es = math.inf
        self.t_fade = math.inf
        self.period = 2.0 * math.pi / cfg.omega
        # (14)'s constants, read once: tell() runs every period
        self._gains = (cfg.alpha0, cfg.alpha0 * cfg.kf1, cfg.kf2, cfg.alpha_f)
        self.period_start = 0.0
        self.theta_marks: list[float] = []
        self._dtheta = 0.0
        self._ddtheta = 0.0
        self._dither = 0.0  # A(t)·sin(ω(t - t_es)) at the coming sample

    def begin(self, w0: float) -> None:
        self.filter.reset(w0)
        self.wd, self.ad, self.jd = self.filter.wd, self.filter.ad, self.filter.jd
        self.target = self.theta
        self.phase = DELAY

    def sat(self, p: float) -> float:
        big = self.cfg.saturation
        return big * math.tanh(p / big)

    def amplitude(self, t: float) -> tuple[float, float, float]:
        """A(t), A'(t), A''(t): ramp in over one period, ramp out over one after convergence."""
        ae, T = self.ae, self.period
        if self.t_es + T <= t < self.t_fade:
            return ae, 0.0, 0.0
        s, ds, dds = _smoothstep((t - self.t_es) / T)
        if t >= self.t_fade:
            r, dr, ddr = _smoothstep((t - self.t_fade) / T)
            s, ds, dds = s * (1 - r), ds * (1 - r) - s * dr, dds * (1 - r) - 2 * ds * dr - s * ddr
        return ae * s, ae * ds / T, ae * dds / (T * T)

    def update(self, t: float, q: float, p: float, e: float) -> Evaluation | None:
        cfg = self.cfg
        if self.phase in (DELAY, SETTLING):
            self.phase = SETTLING if t >= cfg.start_delay else DELAY
            if (
                self.phase == SETTLING
                and abs(e) <= cfg.e1
                and abs(self.filter.wd - self.theta) <= cfg.e2
            ):
                self.phase = MEASURING
                self.t_es = self.period_start = t
                self.theta = min(max(self.filter.wd, self.theta_lo), self.theta_hi)
                self.eta = self.sat(p)
                self.theta_marks = [self.theta]
                self._dither = 0.0
            else:
                self._lead_in()
                return None
        ev = None
        if self.phase == MEASURING or (self.phase == DONE and self.tracking):
            ev = self._adapt(t, p)
        self._reference(t + self.dt)
        return ev

    def hold(self, t: float) -> None:
        if self.phase in (DELAY, SETTLING):
            self._lead_in()
        else:
            self._reference(t + self.dt)

    def _lead_in(self) -> None:
        self.filter.step(self.theta)
        f = self.filter
        self.wd, self.ad, self.jd = f.wd, f.ad, f.jd

    def _reference(self, tn: float) -> None:
        """wd, ad, jd at the coming sample tn."""
        w = self.cfg.omega
        self.target = self.theta
        if self.t_es + self.period <= tn < self.t_fade:  # full amplitude: A' = A'' = 0
            a = self.ae
            x = w * (tn - self.t_es)
            s = math.sin(x)
            self._dither = a * s
            self.wd = self.theta + a * s
            self.ad = self._dtheta + a * w * math.cos(x)
            self.jd = self._ddtheta - a * w * w * s
            return
        a, da, dda = self.amplitude(tn)
        s, c = math.sin(w * (tn - self.t_es)), math.cos(w * (tn - self.t_es))
        self._dither = a * s
        self.wd = self.theta + a * s
        self.ad = self._dtheta + da * s + a * w * c
        self.jd = self._ddtheta + dda * s + 2.0 * da * w * c - a * w * w * s
        if self.phase == DONE and not self.tracking:
            self.ad = da * s + a * w * c
            self.jd = dda * s + 2.0 * da * w * c - a * w * w * s

    def _adapt(self, t: float, p: float) -> Evaluation | None:
        dt = self.dt
        alpha0, alpha0_kf1, kf2, alpha_f = self._gains
        dither = self._dither
        sp = self.sat(p)
        kappa = self.kappa
        dkappa = -alpha0 * kappa + alpha0_kf1 * (sp - self.eta) * dither  # (14)
        dtheta = -alpha_f * self.theta + kappa  # (14)
        self.eta += dt * kf2 * (sp - self.eta)  # (14)
        kappa += dt * dkappa
        theta = self.theta + dt * dtheta
        lo, hi = self.theta_lo, self.theta_hi
        if theta <= lo or theta >= hi:  # projection: wd stays inside the bracket
            theta = min(max(theta, lo), hi)
            if (theta <= lo and kappa < 0) or (theta >= hi and kappa > 0):
                kappa = 0.0
                dkappa = 0.0
            dtheta = 0.0
        self.kappa = kappa
        self.theta = theta
        self._dtheta = dtheta
        self._ddtheta = -alpha_f * dtheta + dkappa
        if t - self.period_start < self.period:
            return None
        return self._period_done(t)

    def _period_done(self, t: float) -> Evaluation:
        """One dither period done: record it, report a bound, test convergence."""
        cfg = self.cfg
        self.period_start += self.period
        theta = self.theta
        ev = Evaluation(t, theta, self.eta, 0.0)
        self.evaluations.append(ev)
        self.theta_marks.append(theta)
        self.optimum, self.optimum_power = theta, self.eta
        self.bracket = (max(self.lo, theta - self.ae), min(self.hi, theta + self.ae))
        # held at a projection limit for a whole period: the gradient pushes outward (an
        # optimum inside would have pulled θ off within a period)
        tol = 0.1 * self.ae
        held = self.theta_marks[-2:]
        if len(held) == 2 and min(held) >= self.theta_hi - tol:
            self.at_bound = "upper"
        elif len(held) == 2 and max(held) <= self.theta_lo + tol:
            self.at_bound = "lower"
        else:
            if self.at_bound is not None and self.done:
                self.converged_at(t, theta, self.eta)  # the optimum came inside
            self.at_bound = None
        if self.done:
            return ev
        settled = self._settled()
        if settled or self.at_bound is not None or len(self.evaluations) >= cfg.max_evaluations:
            self.done = True
            if self.at_bound is not None:
                self.reason = f"θ held at the {self.at_bound} bound: widen the bracket"
            elif settled:
                self.reason = "θ settled"
                self.converged_at(t, theta, self.eta)
            else:
                self.reason = "evaluation budget spent"
            self.phase = DONE
            if cfg.track:
                self.tracking = True
            else:
                self.t_fade = t
                self.kappa = self._dtheta = self._ddtheta = 0.0
        return ev

    def _settled(self) -> bool:
        """θ has arrived: small net displacement over SETTLE_PERIODS periods, and the
        distance still to go, extrapolated geometrically, smaller still."""
        marks = self.theta_marks[-(SETTLE_PERIODS + 1) :]
        if len(marks) < SETTLE_PERIODS + 1:
            return False
        step = self.cfg.min_step
        if abs(marks[-1] - marks[0]) >= step:
            return False
        moves = [b - a for a, b in itertools.pairwise(marks)]
        num = sum(a * b for a, b in itertools.pairwise(moves))
        den = sum(a * a for a in moves[:-1])
        ratio = min(max(num / den, 0.0), 0.95) if den > 0.0 else 0.0
        return abs(moves[-1]) * ratio / (1.0 - ratio) < 0.5 * step

    def best(self) -> Evaluation | None:
        return self.evaluations[-1] if self.evaluations else None

    def fraction(self) -> float:
        if self.done:
            return 1.0
        return min(len(self.evaluations) / max(self.cfg.max_evaluations, 1), 0.99)
