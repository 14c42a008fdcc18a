"""Gains the discrete loop can hold: the stability bound of each controller as implemented.

The proofs of the paper are continuous-time; the loop is not. What it does (loop.py, plant.py):
at t_k = k·dt it samples w_k, computes u_k, and u_k is held for one period (zero-order hold)
while (1) J ẇ = τ(w) + u runs. Near a velocity w*, τ(w) ≈ τ(w*) + s·(w − w*), with
s = dτ/dw the user's torque slope (s < 0 for every Hill or linear user: a muscle pushes less
the faster it shortens; s ≈ −1.5 N·m·s/rad for the default Hill user at rest). With
x = w − w*, λ = s/J, the exact discretisation of (1) over one period is

    x_{k+1} = a x_k + (φ/J) (u_k − u*),   a = e^{λ dt},  φ = (a − 1)/λ  (φ → dt as s → 0)   (S1)

Controller A (7) measures τ at the sample and cancels it, so only the change of τ inside the
period remains, and the error obeys

    e_{k+1} = (1 − k φ/J) e_k,  stable iff 0 < k φ/J < 2;  at s = 0:  k·dt/J < 2.           (S2)

RISE (23) with the integrals as the loop sums them, I_{k+1} = I_k + ((ks+1) αr e_k +
β sgn(e_k)) dt, and u_k = −(ks+1) e_k − I_k (+ constants). With β = 0 the state (e, I) has

    P(z) = z² − (1 + a − G) z + a − G (1 − h),   G = (ks+1) φ/J,  h = αr·dt              (S3)

Jury's conditions for z² + a₁z + a₀ (|a₀| < 1, P(1) > 0, P(−1) > 0):
    P(1)  = G h > 0                                  always;
    P(−1) = 2(1 + a) − G (2 − h) > 0                 G < 2(1 + a)/(2 − h);
    a₀ > −1                                          implied by P(−1) > 0 for h ≥ 0;
    a₀ < 1   ⟺  G (1 − h) > a − 1                    h < 1 for s ≤ 0; (ks+1)(1 − h) > s for s > 0.
With g = (ks + 1)·dt/J and y = λ dt/2 the upper bound reads

    g < 4 y coth(y) / (2 − h),   αr·dt < 1                                                  (S4)

and y·coth(y) ≥ 1 for either sign of s: the user's slope only relaxes RISE's bound, so s = 0,
g < 4/(2 − αr·dt), is the worst case for any person. For controller A a rising torque (s > 0,
not a Hill user) tightens (S2) by φ/dt = (e^{2y} − 1)/(2y), which the margin below covers up
to s·dt/J ≈ 1.26 (s ≈ 126 N·m·s/rad at 1 kHz with J = 0.1: no person).

The margin (S5): every gain may double before the loop goes unstable.
    controller A:  k·dt/J ≤ 1;     RISE:  (ks + 1)·dt/J ≤ 2/(2 − αr·dt),  αr·dt ≤ 1/2.
k·dt/J ≤ 1 is the deadbeat gain: the pole 1 − k·dt/J stays in [0, 1), the error never changes
sign from one period to the next, and the loop stays stable with any actuation delay δ·dt up to
one whole period (a drive behind a serial line): z² − (1 − g(1 − δ)) z + g δ is Schur for
g ≤ 1, 0 ≤ δ < 1. The same gain bounds the velocity governor of limits.py.

The sign integral (S6). β sgn(e) integrated is a relay behind an integrator: in discrete time
it cannot settle, it chatters. Its describing function (a relay of height β seen by a sine of
amplitude A is a gain 4β/(πA)) adds that much integral gain; the limit cycle sits where (S3)
with the extra gain reaches the unit circle, (ks+1)αr + 4β/(πA) = (ks+1)/dt, at cos θ = 1 − g/2:

    |e| ≈ 4 β dt / (π (ks+1) (1 − h)),    |u| ≈ |e| √g J/dt = 4 β dt / (π √g (1 − h))      (S6)

(the simulated limit cycle is 0.78 … 1.48 times (S6), the larger for small g, where it is no
longer a sine; tests/engine/test_stability.py checks 0.7 … 1.5). The torque ripple is
what a person feels and what can reach the clamp; β is bounded so that (S6) stays within
RIPPLE_FRACTION of the torque limit.

Numbers with J = 0.1 kg·m², αr = 4 1/s (the default):
    rate      exact k < / margined k ≤      exact ks < / margined ks ≤
    50 Hz     10 / 5 N·m·s/rad               9.417 / 4.208
    1 kHz     200 / 100                      199.4 / 99.20
    5 kHz     1000 / 500                     999.4 / 499.2
The defaults (k = 1, ks = 20, αr = 4, β = 0.5) hold at every rate from 50 Hz: below about
210 Hz ks is lowered to the largest accepted (config.default_ks; 4.208 at 50 Hz, where RISE's
g = 2/(2 − 0.08) = 1.042, αr·dt = 0.08 ≤ 0.5, and β's ripple is ±0.014 N·m).

Beyond the controllers (the reference must be one the loop can follow):
- trajectory filter (32)/(33): its discretisation is exact (filters.py), stable at any p·dt;
  the physical bound is the torque of its feedforward J·ad: a step of γ3 from rest gives
  ad_max = c_n p γ3, c_n = (n−1)^(n−1) e^{−(n−1)}/(n−1)! (0.2240 for n = 4, 0.2707 for n = 3),
  and J·ad_max ≤ REFERENCE_TORQUE_FRACTION of the torque limit, the rest being left to the user's
  torque and the feedback.
- perturbation seeker (14), forward Euler at the loop rate: each first-order rate r in it
  (α0, kf2, αf) has the pole 1 − r·dt: stable iff r·dt < 2, margined r·dt ≤ 1. The dither must
  lie inside the tracking bandwidth: the power the seeker reads lags the dither by the
  observer's phase (RISE: τ̂/τ = T(s) = (ks+1)(s + αr)/(J s² + (ks+1) s + (ks+1) αr); measured
  τ: none) plus half a period of zero-order hold; the demodulated gradient shrinks by cos(lag)
  and changes sign at 90°: lag ≤ MAX_DITHER_LAG. Its own feedforward J·ae·ω is bounded as the
  filter's.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sessions.config import SessionConfig

GAIN_MARGIN = 2.0  # (S5): each gain may double before the loop goes unstable
RIPPLE_FRACTION = 1.0 / 20.0  # (S6): sign-integral torque ripple, of the torque limit
REFERENCE_TORQUE_FRACTION = 0.5  # feedforward torque of the reference, of the torque limit
MAX_DITHER_LAG = math.radians(30.0)  # cos 30° = 0.87 of the gradient kept


# -- the closed forms ----------------------------------------------------------------------------
def _phi(inertia: float, dt: float, slope: float) -> tuple[float, float]:
    """(S1): a = e^{λ dt} and φ = (a − 1)/λ, λ = slope/J."""
    lam = slope / inertia
    if abs(lam * dt) < 1e-12:
        return 1.0, dt
    a = math.exp(lam * dt)
    return a, math.expm1(lam * dt) / lam


def measured_pole(k: float, inertia: float, dt: float, slope: float = 0.0) -> float:
    """(S2): the one pole of controller A's error, 1 − k φ/J."""
    return 1.0 - k * _phi(inertia, dt, slope)[1] / inertia


def rise_characteristic(
    ks: float, alpha_r: float, inertia: float, dt: float, slope: float = 0.0
) -> tuple[float, float]:
    """(S3): (a₁, a₀) of P(z) = z² + a₁ z + a₀, RISE's linear error dynamics (β = 0)."""
    a, phi = _phi(inertia, dt, slope)
    G = (ks + 1.0) * phi / inertia
    return -(1.0 + a - G), a - G * (1.0 - alpha_r * dt)


def schur_stable(a1: float, a0: float) -> bool:
    """Jury's test for z² + a₁ z + a₀: both roots strictly inside the unit circle."""
    return abs(a0) < 1.0 and 1.0 + a1 + a0 > 0.0 and 1.0 - a1 + a0 > 0.0


def k_limit(inertia: float, dt: float) -> float:
    """(S2) at s = 0: the exact limit of controller A's k."""
    return 2.0 * inertia / dt


def max_k(inertia: float, dt: float) -> float:
    """(S5): the largest k accepted."""
    return k_limit(inertia, dt) / GAIN_MARGIN


def deadbeat_gain(inertia: float, dt: float) -> float:
    """J/dt: a proportional velocity gain at the margin (S5), e.g. the velocity governor's."""
    return inertia / dt


def alpha_r_limit(dt: float) -> float:
    """(S4): the exact limit of αr, αr·dt < 1."""
    return 1.0 / dt


def max_alpha_r(dt: float) -> float:
    """(S5): the largest αr accepted."""
    return alpha_r_limit(dt) / GAIN_MARGIN


def ks_limit(alpha_r: float, inertia: float, dt: float) -> float:
    """(S4) at s = 0: the exact limit of ks, (ks + 1)·dt/J < 4/(2 − αr·dt)."""
    return 4.0 / (2.0 - alpha_r * dt) * inertia / dt - 1.0


def max_ks(alpha_r: float, inertia: float, dt: float) -> float:
    """(S5): the largest ks accepted, (ks + 1)·dt/J ≤ 2/(2 − αr·dt)."""
    return (ks_limit(alpha_r, inertia, dt) + 1.0) / GAIN_MARGIN - 1.0


def sign_chatter(
    beta: float, ks: float, alpha_r: float, inertia: float, dt: float
) -> tuple[float, float]:
    """(S6): amplitudes (|e| rad/s, |u| N·m) of the sign integral's limit cycle."""
    h = alpha_r * dt
    g = (ks + 1.0) * dt / inertia
    e = 4.0 * beta * dt / (math.pi * (ks + 1.0) * (1.0 - h))
    return e, e * math.sqrt(g) * inertia / dt


def max_beta(ks: float, alpha_r: float, inertia: float, dt: float, max_torque: float) -> float:
    """(S6): the largest β whose torque ripple stays within RIPPLE_FRACTION of the limit."""
    per_beta = sign_chatter(1.0, ks, alpha_r, inertia, dt)[1]
    return RIPPLE_FRACTION * max_torque / per_beta


def filter_peak(order: int) -> float:
    """c_n: the peak of ad for a unit step through pⁿ/(s+p)ⁿ, divided by p."""
    m = order - 1
    return m**m * math.exp(-m) / math.factorial(m)


def dither_lag(
    omega: float, kind: str, ks: float, alpha_r: float, inertia: float, dt: float
) -> float:
    """Phase (rad) by which the power the seeker reads lags a dither at ω."""
    lag = 0.5 * omega * dt  # the zero-order hold: half a period
    if kind == "rise":
        ks1 = ks + 1.0
        lag += math.atan2(ks1 * omega, ks1 * alpha_r - inertia * omega * omega)
        lag -= math.atan2(omega, alpha_r)
    return lag


def max_omega(kind: str, ks: float, alpha_r: float, inertia: float, dt: float) -> float:
    """The dither frequency at which :func:`dither_lag` reaches MAX_DITHER_LAG (bisection;
    the lag grows with ω up to the Nyquist frequency π/dt, which is the upper end)."""
    lo, hi = 0.0, math.pi / dt
    if dither_lag(hi, kind, ks, alpha_r, inertia, dt) <= MAX_DITHER_LAG:
        return hi
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if dither_lag(mid, kind, ks, alpha_r, inertia, dt) <= MAX_DITHER_LAG:
            lo = mid
        else:
            hi = mid
    return lo


def euler_rate_limit(dt: float) -> float:
    """A first-order rate r integrated by forward Euler: pole 1 − r·dt, margined r·dt ≤ 1."""
    return 2.0 / dt / GAIN_MARGIN


# -- the check every entry point runs (through SessionConfig) ------------------------------------
def _down(x: float) -> str:
    """x rounded down to 4 significant digits: a printed bound that is itself accepted."""
    if x <= 0.0 or not math.isfinite(x):
        return f"{x:g}"
    step = 10.0 ** (math.floor(math.log10(x)) - 3)
    return f"{math.floor(x / step) * step:.4g}"


def _where(cfg: SessionConfig) -> str:
    return f"at {cfg.rate:g} Hz with J = {cfg.machine.inertia:g} kg·m²"


def controller_violation(cfg: SessionConfig) -> str | None:
    """The first bound (S2)-(S6) the controller breaks, as ``key: reason``; None if none."""
    c, J, dt = cfg.controller, cfg.machine.inertia, cfg.dt
    too_much = "is more than the loop can hold"
    if c.kind == "measured":
        if c.k > max_k(J, dt):
            return (
                f"controller.k: {c.k:g} {too_much} {_where(cfg)}: needs k·dt/J ≤ 1 (a gain "
                f"margin of 2 on the discrete limit 2), i.e. k ≤ {_down(max_k(J, dt))} N·m·s/rad"
            )
        return None
    h = c.alpha_r * dt
    if c.alpha_r > max_alpha_r(dt):
        return (
            f"controller.alpha_r: {c.alpha_r:g} {too_much} at {cfg.rate:g} Hz: needs αr·dt ≤ 0.5 "
            f"(a margin of 2 on the discrete limit 1), i.e. alpha_r ≤ {_down(max_alpha_r(dt))} 1/s"
        )
    if c.ks > max_ks(c.alpha_r, J, dt):
        return (
            f"controller.ks: {c.ks:g} {too_much} {_where(cfg)}: needs (ks + 1)·dt/J ≤ "
            f"2/(2 − αr·dt) = {_down(2.0 / (2.0 - h))} (a gain margin of 2 on the discrete "
            f"limit 4/(2 − αr·dt)), i.e. ks ≤ {_down(max_ks(c.alpha_r, J, dt))}"
        )
    b_max = max_beta(c.ks, c.alpha_r, J, dt, cfg.machine.max_torque)
    if c.beta > b_max:
        ripple = sign_chatter(c.beta, c.ks, c.alpha_r, J, dt)[1]
        return (
            f"controller.beta: {c.beta:g} makes the sign integral chatter by ±{ripple:.3g} N·m "
            f"{_where(cfg)} (4β·dt/(π·√g·(1 − αr·dt)), g = (ks + 1)·dt/J): needs at most "
            f"1/20 of machine.max_torque, {RIPPLE_FRACTION * cfg.machine.max_torque:g} N·m, "
            f"i.e. beta ≤ {_down(b_max)} N·m/s"
        )
    return None


def reference_violation(cfg: SessionConfig) -> str | None:
    """The first bound the seeker's reference breaks (filter, perturbation (14)); None if none."""
    s, m, dt = cfg.seeker, cfg.machine, cfg.dt
    budget = REFERENCE_TORQUE_FRACTION * m.max_torque
    c_n, top = filter_peak(s.filter.order), s.bracket[2]
    ff = m.inertia * c_n * s.filter.pole * top
    if ff > budget:
        p_max = budget / (m.inertia * c_n * top)
        return (
            f"seeker.filter.pole: {s.filter.pole:g} asks the motor for J·{c_n:.4f}·p·γ3 = "
            f"{ff:.3g} N·m of feedforward torque on a step from rest to γ3 = {top:g} rad/s: needs "
            f"at most half of machine.max_torque, {budget:g} N·m, i.e. pole ≤ {_down(p_max)} rad/s"
        )
    if s.kind != "perturbation":
        return None
    r_max = euler_rate_limit(dt)
    for key, sym, r in (("alpha0", "α0", s.alpha0), ("kf2", "kf2", s.kf2)):
        if r > r_max:
            return (
                f"seeker.{key}: {r:g} is more than forward Euler holds at {cfg.rate:g} Hz: needs "
                f"{sym}·dt ≤ 1 (a margin of 2 on the limit 2), i.e. {key} ≤ {_down(r_max)} 1/s"
            )
    if s.alpha_f > r_max:
        return (
            f"seeker.alpha_f: {s.alpha_f:g} is more than forward Euler holds at {cfg.rate:g} Hz: "
            f"needs αf·dt ≤ 1 (a margin of 2 on the limit 2), i.e. alpha_f ≤ {_down(r_max)} 1/s"
        )
    c = cfg.controller
    lag = dither_lag(s.omega, c.kind, c.ks, c.alpha_r, m.inertia, dt)
    if lag > MAX_DITHER_LAG:
        w_max = max_omega(c.kind, c.ks, c.alpha_r, m.inertia, dt)
        return (
            f"seeker.omega: {s.omega:g} is beyond the tracking bandwidth {_where(cfg)}: the power "
            f"the seeker reads lags the dither by {math.degrees(lag):.0f}° (needs ≤ "
            f"{math.degrees(MAX_DITHER_LAG):.0f}°), i.e. omega ≤ {_down(w_max)} rad/s"
        )
    dither = m.inertia * s.amplitude * s.omega
    if dither > budget:
        return (
            f"seeker.amplitude: {s.amplitude:g} at ω = {s.omega:g} rad/s asks the motor for "
            f"J·ae·ω = {dither:.3g} N·m of feedforward torque: needs at most half of "
            f"machine.max_torque, {budget:g} N·m, i.e. amplitude ≤ "
            f"{_down(budget / (m.inertia * s.omega))} rad/s"
        )
    return None


def violation(cfg: SessionConfig) -> str | None:
    """The first bound of this module that ``cfg`` breaks, as ``key: reason``; None if none."""
    return controller_violation(cfg) or reference_violation(cfg)
