"""The velocity-spectrum test (isokinetic steps, as on a Biodex or HUMAC dynamometer): its
plan, and the torque–velocity and power–velocity profile fitted to what it measured.

Plan (:func:`plan_profile`, a pure function the protocol runner follows): K velocities evenly
across the trainer's bracket [lo, hi], each held for M s, in ascending, descending, interleaved
(lo, hi, lo+1, hi-1, …: neighbours in time are far apart in velocity, so a slow drift such as
fatigue does not masquerade as curvature) or seeded random order. The runner feeds each
velocity to the trajectory filter (32)/(33) as a candidate γ; the first part of each step, while
wd and w settle on the new velocity, is not analysed. Its length follows from the filter: the
step response of pⁿ/(s+p)ⁿ is the regularised incomplete gamma function P(n, p t), so wd is
within ``tolerance`` of a jump Δ after t = P⁻¹(n, 1 - tolerance/|Δ|)/p. A step is lengthened
so that its analysed window covers whole turns of the handle, at least ``min_revolutions``
(a stroke-angle ripple then averages out of the mean).

Analysis (:func:`fit_profile`):
1. Per step, the mean torque over the settled window (cut to whole turns of the handle, the
   first harmonic of the stroke angle regressed out) and its standard error from batch means
   (:func:`_step_mean`): the person's torque fluctuates as band-limited (autocorrelated) noise,
   so neighbouring samples are far from independent and a naive σ/√n would be several times
   too small; means of batches much longer than the noise's correlation time are not. The
   step's velocity is the mean of the measured w. One point per step is what the fit sees:
   the K step means are independent.
2. Weighted least squares of the torque–velocity law through the K points, weights 1/SE²:
       Hill:    τ = τ0 (wmax - w) / (wmax + w/a)                    (H)
       linear:  τ = τ0 (1 - w/wmax)                                 (L)
   (L) in closed form (a straight line τ = b0 + b1 w, τ0 = b0, wmax = -b0/b1); (H) with
   ``scipy.optimize.least_squares`` in log-parameters (ln τ0, ln wmax, ln a), so every
   parameter stays positive. (L) is (H) with a → ∞, so the two are nested and compared by the
   extra-sum-of-squares F-test; (H) is chosen when it fits significantly better (p < 0.05)
   with its curvature inside the bounds, (L) otherwise, and always with fewer than 4 steps.
3. Power P = τ w. (H): w_opt = wmax (√(a² + a) - a), (L): w_opt = wmax/2; Pmax = τ(w_opt) w_opt.
4. Confidence intervals by the delta method: the parameters' covariance (JᵀWJ)⁻¹ scaled by the
   reduced χ² of the fit (so the SEs set only the relative weights; the scatter of the step
   means about the curve sets the scale, which also absorbs a drift or a misjudged SE), and
   Student's t with K - p degrees of freedom. Intervals are formed on the log scale and
   exponentiated: asymmetric, positive, and better behaved for wmax and τ0, which the fit
   extrapolates beyond the bracket. Why not a parametric bootstrap: with K ≈ 8 points it adds
   two orders of magnitude of time, and a bootstrap from the fitted SEs ignores the
   uncertainty of their scale; the tests check the delta-method intervals' coverage over
   repeated simulated sessions instead.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from sessions.config import FilterConfig

Order = Literal["ascending", "descending", "interleaved", "random"]
ORDERS: tuple[Order, ...] = ("ascending", "descending", "interleaved", "random")
Model = Literal["hill", "linear"]
TWO_PI = 2.0 * math.pi
MIN_STEPS = 3
BATCHES = 10  # batch means per step: 7-9 degrees of freedom for its standard error
MIN_BATCH = 25  # samples
MIN_SAMPLES = 3 * MIN_BATCH  # three batch means: the least that gives a standard error
A_BOUNDS = (0.01, 100.0)  # Hill curvature a; at 100 (H) is a straight line to within 1 %
F_TEST_ALPHA = 0.05
DEFAULT_FILTER = FilterConfig()  # (32): n = 4, p = 3 rad/s


class ProfileError(ValueError):
    """A plan or a velocity-spectrum test that cannot be used, with a one-line reason that
    names the argument (``steps[3].tau: …``)."""


# -- the plan --------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ProfileStep:
    """One isokinetic step. Times are seconds from the start of the profile phase; the samples
    from ``settled`` to ``end`` are analysed."""

    index: int  # position in the order run, 0-based
    velocity: float  # rad/s, the candidate γ the runner holds
    start: float
    settled: float
    end: float


@dataclass(frozen=True, slots=True)
class ProfilePlan:
    steps: tuple[ProfileStep, ...]

    @property
    def duration(self) -> float:
        return self.steps[-1].end if self.steps else 0.0

    def velocity_at(self, t: float) -> float | None:
        """The velocity to hold at phase time ``t``; None outside the steps."""
        for step in self.steps:
            if step.start <= t < step.end:
                return step.velocity
        return None

    def to_dict(self) -> dict[str, Any]:
        return {
            "duration": self.duration,
            "steps": [
                {"index": s.index, "velocity": s.velocity, "start": s.start,
                 "settled": s.settled, "end": s.end}
                for s in self.steps
            ],
        }  # fmt: skip


def _finite(name: str, x: float, *, positive: bool = False) -> float:
    x = float(x)
    if not math.isfinite(x) or (positive and x <= 0):
        raise ProfileError(
            f"{name}: must be a finite {'positive ' if positive else ''}number, got {x}"
        )
    return x


def filter_settle_time(jump: float, tolerance: float, filt: FilterConfig = DEFAULT_FILTER) -> float:
    """Seconds until the trajectory filter pⁿ/(s+p)ⁿ, (32)/(33), is within ``tolerance`` of a
    jump of size ``jump``: P(n, p t) = 1 - tolerance/|jump| solved for t."""
    jump = abs(jump)
    if jump <= tolerance:
        return 0.0
    from scipy import special  # here, not at the top: see _fit_hill

    return float(special.gammaincinv(filt.order, 1.0 - tolerance / jump)) / filt.pole


def order_velocities(
    velocities: Sequence[float], order: Order, seed: int | None = None
) -> list[float]:
    """``velocities`` (ascending) in the order a test runs them."""
    v = sorted(velocities)
    if order == "ascending":
        return v
    if order == "descending":
        return v[::-1]
    if order == "interleaved":
        lo, hi, out = 0, len(v) - 1, []
        while lo <= hi:
            out.append(v[lo])
            if hi != lo:
                out.append(v[hi])
            lo, hi = lo + 1, hi - 1
        return out
    if order == "random":
        rng = np.random.default_rng(seed)
        return [v[i] for i in rng.permutation(len(v))]
    raise ProfileError(f"order: must be one of {list(ORDERS)}, got {order!r}")


def plan_profile(
    bracket: tuple[float, float],
    count: int = 8,
    hold: float = 8.0,
    *,
    order: Order = "ascending",
    seed: int | None = None,
    start_velocity: float = 0.0,
    tolerance: float = 0.02,
    min_revolutions: float = 1.0,
    filt: FilterConfig = DEFAULT_FILTER,
) -> ProfilePlan:
    """The steps of a velocity-spectrum test: ``count`` velocities evenly from ``bracket[0]``
    to ``bracket[1]`` (rad/s), each held about ``hold`` s, starting from ``start_velocity``.
    Each step's first part, until the filter is within ``tolerance`` rad/s of the new
    velocity, is not analysed; the rest is rounded up to whole turns of the handle, at least
    ``min_revolutions`` of them (0: exactly ``hold`` s, or the settling if longer). Pure: the
    same arguments give the same plan."""
    lo = _finite("bracket[0]", bracket[0], positive=True)
    hi = _finite("bracket[1]", bracket[1], positive=True)
    if not lo < hi:
        raise ProfileError(f"bracket: must be increasing (lo < hi), got [{lo}, {hi}]")
    if not isinstance(count, int) or isinstance(count, bool) or not MIN_STEPS <= count <= 50:
        raise ProfileError(f"count: must be an integer from {MIN_STEPS} to 50, got {count!r}")
    hold = _finite("hold", hold, positive=True)
    tolerance = _finite("tolerance", tolerance, positive=True)
    min_revolutions = _finite("min_revolutions", min_revolutions)
    if min_revolutions < 0:
        raise ProfileError(f"min_revolutions: must be ≥ 0, got {min_revolutions}")
    prev = _finite("start_velocity", start_velocity)
    velocities = order_velocities(np.linspace(lo, hi, count).tolist(), order, seed)
    steps, t = [], 0.0
    for i, v in enumerate(velocities):
        settle = filter_settle_time(v - prev, tolerance, filt)
        turn = TWO_PI / v
        if min_revolutions > 0:  # the analysed window: whole turns, at least min_revolutions
            turns = max(math.ceil(min_revolutions - 1e-9), math.ceil((hold - settle) / turn - 1e-9))
            length = settle + turns * turn
        else:
            length = max(hold, settle)
        steps.append(ProfileStep(i, v, t, t + settle, t + length))
        t += length
        prev = v
    return ProfilePlan(tuple(steps))


# -- the measurements ------------------------------------------------------------------------
@dataclass(frozen=True)
class StepSamples:
    """What one step measured over its settled window, uniformly sampled: τ or τ̂ (N·m), the
    handle velocity w (rad/s) and, if known, the handle angle q (rad), which lets the
    stroke-angle ripple be removed."""

    velocity: float
    tau: np.ndarray
    w: np.ndarray
    q: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class StepMean:
    velocity: float  # held (commanded), rad/s
    w: float  # mean measured velocity, rad/s: the abscissa of the fit
    tau: float  # mean torque, N·m
    tau_se: float  # its standard error (batch means), N·m
    samples: int

    @property
    def power(self) -> float:
        return self.tau * self.w


def step_samples(
    plan: ProfilePlan,
    t: np.ndarray,
    tau: np.ndarray,
    w: np.ndarray,
    q: np.ndarray | None = None,
    *,
    t0: float = 0.0,
) -> list[StepSamples]:
    """Cut full-rate telemetry (``t`` in the same time base as ``t0``, the profile phase's
    start) into the settled window of each planned step."""
    t = np.asarray(t, dtype=float)
    out = []
    for step in plan.steps:
        i, j = np.searchsorted(t, [t0 + step.settled, t0 + step.end])
        out.append(
            StepSamples(
                step.velocity,
                np.asarray(tau[i:j], dtype=float),
                np.asarray(w[i:j], dtype=float),
                None if q is None else np.asarray(q[i:j], dtype=float),
            )
        )
    return out


def _check(i: int, step: StepSamples) -> int:
    _finite(f"steps[{i}].velocity", step.velocity, positive=True)
    n = len(step.tau)
    arrays = {"tau": step.tau, "w": step.w} | ({} if step.q is None else {"q": step.q})
    for name, x in arrays.items():
        x = np.asarray(x, dtype=float)
        if x.ndim != 1 or len(x) != n:
            raise ProfileError(f"steps[{i}].{name}: must be 1-D with as many samples as tau ({n})")
        bad = np.flatnonzero(~np.isfinite(x))
        if len(bad):
            raise ProfileError(f"steps[{i}].{name}: not finite (NaN or ∞) at sample {bad[0]}")
    if n < MIN_SAMPLES:
        raise ProfileError(f"steps[{i}].tau: {n} samples, need at least {MIN_SAMPLES}")
    return n


def _step_mean(i: int, step: StepSamples) -> StepMean:
    """Mean torque of one step and its standard error from batch means.

    With the angle known and at least one turn in the window, the window is cut to its last
    whole turns (every harmonic of a stroke-angle ripple then averages out of the mean). The
    batch means of τ are regressed on the batch means of sin q and cos q when the window spans
    most of a turn: the batch mean of τ̄ (1 + r sin q) is exactly linear in that of sin q, so
    the first harmonic leaves the batch-to-batch scatter, and the regression's own degrees of
    freedom are counted (regressing at full rate and then batching the residuals would not
    count them, and understates the error by up to a third over one or two turns)."""
    n = _check(i, step)
    tau = np.asarray(step.tau, dtype=float)
    w = np.asarray(step.w, dtype=float)
    q = None if step.q is None else np.asarray(step.q, dtype=float)
    if q is not None:
        turns = math.floor(abs(q[-1] - q[0]) / TWO_PI)
        if turns >= 1:
            keep = np.flatnonzero(np.abs(q[-1] - q) <= turns * TWO_PI)[0]
            tau, w, q = tau[keep:], w[keep:], q[keep:]
    batches = min(BATCHES, len(tau) // MIN_BATCH)
    cols = [np.ones(batches)]
    if q is not None and batches >= 5 and abs(q[-1] - q[0]) >= 0.75 * TWO_PI:
        cols += [_batch_means(np.sin(q), batches), _batch_means(np.cos(q), batches)]
    x = np.column_stack(cols)
    yb = _batch_means(tau, batches)
    coef, *_ = np.linalg.lstsq(x, yb, rcond=None)
    dof = batches - x.shape[1]
    resid = yb - x @ coef
    var = float(resid @ resid) / dof * float(np.linalg.pinv(x.T @ x)[0, 0]) if dof > 0 else 0.0
    return StepMean(float(step.velocity), float(w.mean()), float(coef[0]), math.sqrt(var), n)


def _batch_means(x: np.ndarray, batches: int) -> np.ndarray:
    return np.array([b.mean() for b in np.array_split(x, batches)])


# -- the fit ---------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Estimate:
    """A fitted quantity with its two-sided confidence interval [low, high] and its standard
    error (on the natural scale, linearised)."""

    value: float
    low: float
    high: float
    stderr: float

    def covers(self, x: float) -> bool:
        return self.low <= x <= self.high

    def to_dict(self) -> dict[str, float]:
        return {"value": self.value, "low": self.low, "high": self.high, "stderr": self.stderr}


@dataclass(frozen=True)
class ProfileCurve:
    """The fitted laws on a velocity grid from 0 to wmax, with pointwise confidence bands, for
    the τ–v and P–v charts. SI units (rad/s, N·m, W)."""

    w: np.ndarray
    tau: np.ndarray
    tau_low: np.ndarray
    tau_high: np.ndarray
    power: np.ndarray
    power_low: np.ndarray
    power_high: np.ndarray

    def to_dict(self) -> dict[str, list[float]]:
        names = ("w", "tau", "tau_low", "tau_high", "power", "power_low", "power_high")
        return {k: getattr(self, k).tolist() for k in names}


@dataclass(frozen=True)
class ProfileFit:
    """The fitted torque–velocity and power–velocity profile (SI units)."""

    model: Model
    tau0: Estimate  # isometric torque, N·m
    wmax: Estimate  # velocity of zero torque, rad/s
    a: Estimate | None  # Hill's curvature (None for the linear law)
    pmax: Estimate  # peak power, W
    w_opt: Estimate  # velocity of peak power, rad/s
    confidence: float
    dof: int
    reduced_chi2: float
    hill_p_value: float | None  # F-test of (H) against (L); None when (H) was not tried
    steps: tuple[StepMean, ...]
    curve: ProfileCurve
    warnings: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready plain data (for the REST API and the store)."""
        return {
            "model": self.model,
            **{k: getattr(self, k).to_dict() for k in ("tau0", "wmax", "pmax", "w_opt")},
            "a": None if self.a is None else self.a.to_dict(),
            "confidence": self.confidence,
            "dof": self.dof,
            "reduced_chi2": self.reduced_chi2,
            "hill_p_value": self.hill_p_value,
            "steps": [
                {"velocity": s.velocity, "w": s.w, "tau": s.tau, "tau_se": s.tau_se,
                 "power": s.power, "samples": s.samples}
                for s in self.steps
            ],
            "curve": self.curve.to_dict(),
            "warnings": list(self.warnings),
        }  # fmt: skip


@dataclass(frozen=True)
class _Law:
    """A torque–velocity law in log-parameters θ: τ(w; θ), its gradient and w_opt(θ)."""

    name: Model
    torque: Callable[[np.ndarray, np.ndarray], np.ndarray]
    grad: Callable[[np.ndarray, np.ndarray], np.ndarray]  # (len(w), len(θ))
    w_opt: Callable[[np.ndarray], float]


def _hill_torque(w: np.ndarray, th: np.ndarray) -> np.ndarray:
    tau0, wmax, a = np.exp(th)
    return tau0 * (wmax - w) / (wmax + w / a)  # (H)


def _hill_grad(w: np.ndarray, th: np.ndarray) -> np.ndarray:
    tau0, wmax, a = np.exp(th)
    d = wmax + w / a
    return np.column_stack(
        (
            tau0 * (wmax - w) / d,  # ∂τ/∂ln τ0 = τ
            tau0 * wmax * w * (1.0 + 1.0 / a) / d**2,  # ∂τ/∂ln wmax
            tau0 * (wmax - w) * w / (a * d**2),  # ∂τ/∂ln a
        )
    )


def _hill_w_opt(th: np.ndarray) -> float:
    _, wmax, a = np.exp(th)
    return float(wmax * (math.sqrt(a * a + a) - a))  # dP/dw = 0 of (H)·w


def _linear_torque(w: np.ndarray, th: np.ndarray) -> np.ndarray:
    tau0, wmax = np.exp(th)
    return tau0 * (1.0 - w / wmax)  # (L)


def _linear_grad(w: np.ndarray, th: np.ndarray) -> np.ndarray:
    tau0, wmax = np.exp(th)
    return np.column_stack((tau0 * (1.0 - w / wmax), tau0 * w / wmax))


HILL = _Law("hill", _hill_torque, _hill_grad, _hill_w_opt)
LINEAR = _Law("linear", _linear_torque, _linear_grad, lambda th: float(np.exp(th[1]) / 2.0))


@dataclass(frozen=True)
class _Solution:
    law: _Law
    theta: np.ndarray
    cov: np.ndarray  # unscaled (JᵀWJ)⁻¹
    ssr: float  # weighted sum of squared residuals
    dof: int
    at_bound: bool = False


def _fit_linear(w: np.ndarray, y: np.ndarray, se: np.ndarray) -> _Solution:
    """(L) in closed form: weighted least squares of τ = b0 + b1 w, then θ = (ln b0, ln(-b0/b1))."""
    x = np.column_stack((np.ones_like(w), w)) / se[:, None]
    b, *_ = np.linalg.lstsq(x, y / se, rcond=None)
    b0, b1 = float(b[0]), float(b[1])
    if not (b1 < 0.0 and b0 > 0.0):
        raise ProfileError(
            f"steps: torque does not fall with velocity (fitted τ = {b0:.4g} + {b1:.4g}·w): "
            "no torque–velocity profile to fit"
        )
    cov_b = np.linalg.pinv(x.T @ x)
    g = np.array([[1.0 / b0, 0.0], [1.0 / b0, -1.0 / b1]])  # ∂(ln τ0, ln wmax)/∂(b0, b1)
    resid = x @ b - y / se
    return _Solution(
        LINEAR, np.log([b0, -b0 / b1]), g @ cov_b @ g.T, float(resid @ resid), len(w) - 2
    )


def _fit_hill(w: np.ndarray, y: np.ndarray, se: np.ndarray, start: _Solution) -> _Solution:
    """(H) by least squares in log-parameters, from the best of a small grid of starts."""
    tau0_l, wmax_l = np.exp(start.theta)

    def resid(th: np.ndarray) -> np.ndarray:
        return (_hill_torque(w, th) - y) / se

    best, best_cost = None, math.inf
    for a0 in (0.05, 0.15, 0.4, 1.0, 3.0, 10.0):
        for k in (1.0, 1.5, 2.5, 4.0):
            th = np.log([tau0_l, wmax_l * k, a0])
            f = _hill_torque(w, th) / np.exp(th[0]) / se  # (H) is linear in τ0: solve for it
            th[0] = math.log(max(float(f @ (y / se)) / float(f @ f), 1e-12))
            cost = float(resid(th) @ resid(th))
            if cost < best_cost:
                best, best_cost = th, cost
    lo, hi = math.log(A_BOUNDS[0]), math.log(A_BOUNDS[1])
    assert best is not None
    best[2] = min(max(best[2], lo + 1e-9), hi - 1e-9)
    # scipy is imported where a fit needs it: the server, its CLI and every spawned worker
    # import this module (through the protocol runner), and scipy takes ~1.5 CPU-s to load
    from scipy import optimize

    sol = optimize.least_squares(
        resid,
        best,
        jac=lambda th: _hill_grad(w, th) / se[:, None],
        bounds=([-np.inf, -np.inf, lo], [np.inf, np.inf, hi]),
        x_scale="jac",
        ftol=1e-15,
        xtol=1e-15,
        gtol=1e-15,
        max_nfev=2000,
    )
    jac = sol.jac
    at_bound = bool(min(sol.x[2] - lo, hi - sol.x[2]) < 1e-3)
    return _Solution(
        HILL, sol.x, np.linalg.pinv(jac.T @ jac), float(2.0 * sol.cost), len(w) - 3, at_bound
    )


def _choose(lin: _Solution, hill: _Solution | None, scale: float) -> tuple[_Solution, float | None]:
    """(H) when it fits significantly better than (L) (extra-sum-of-squares F-test)."""
    if hill is None:
        return lin, None
    tiny = 1e-18 * scale
    if lin.ssr <= tiny:  # a straight line through every point
        return lin, 1.0
    if hill.ssr <= tiny:
        return (lin, 1.0) if hill.at_bound else (hill, 0.0)
    f = max(lin.ssr - hill.ssr, 0.0) / (hill.ssr / hill.dof)
    from scipy import special

    p = float(special.fdtrc(1, hill.dof, f))  # the F(1, dof) distribution's survival
    return (hill if p < F_TEST_ALPHA and not hill.at_bound else lin), p


def _log_estimate(m: float, var: float, t: float) -> Estimate:
    se = math.sqrt(max(var, 0.0))
    v = math.exp(m)
    return Estimate(v, math.exp(m - t * se), math.exp(m + t * se), v * se)


def _gradient(f: Callable[[np.ndarray], float], th: np.ndarray, h: float = 1e-6) -> np.ndarray:
    g = np.empty(len(th))
    for k in range(len(th)):
        e = np.zeros(len(th))
        e[k] = h
        g[k] = (f(th + e) - f(th - e)) / (2.0 * h)
    return g


def _curve(sol: _Solution, cov: np.ndarray, t: float, points: int) -> ProfileCurve:
    wmax = float(np.exp(sol.theta[1]))
    w = np.linspace(0.0, wmax, points)
    tau = sol.law.torque(w, sol.theta)
    g = sol.law.grad(w, sol.theta)
    half = t * np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", g, cov, g), 0.0))
    return ProfileCurve(w, tau, tau - half, tau + half, tau * w, (tau - half) * w, (tau + half) * w)


def _weights_se(means: Sequence[StepMean]) -> np.ndarray:
    """The standard errors the fit weighs the steps by: a variance function fitted to the
    steps' own SEs, SEᵢ = c |τ̄ᵢ|^θ / √nᵢ (the power-of-the-mean model of assay fitting), θ by
    a log-log regression clipped to [0, 2]. Each SE is itself an estimate from a few batch
    means (±25 %); used directly as weights, their scatter would add variance the covariance
    does not show (the intervals then cover less often than stated). All zero (noiseless
    data): equal weights."""
    se = np.array([m.tau_se for m in means])
    tau = np.abs([m.tau for m in means])
    n = np.array([m.samples for m in means], dtype=float)
    ok = np.isfinite(se) & (se > 0) & (tau > 0)
    if ok.sum() < 2:
        return np.ones(len(means))
    x, y = np.log(tau[ok]), np.log(se[ok] * np.sqrt(n[ok]))
    theta = float(np.clip(np.polyfit(x, y, 1)[0], 0.0, 2.0)) if np.ptp(x) > 0 else 0.0
    c = math.exp(float(np.mean(y - theta * x)))
    return c * np.maximum(tau, 1e-3 * tau.max()) ** theta / np.sqrt(n)


def fit_profile(
    steps: Sequence[StepSamples],
    *,
    model: Literal["auto", "hill", "linear"] = "auto",
    confidence: float = 0.95,
    points: int = 200,
) -> ProfileFit:
    """Fit the torque–velocity law to a velocity-spectrum test (see the module's docstring).
    Raises :class:`ProfileError` naming the problem for unusable input."""
    if model not in ("auto", "hill", "linear"):
        raise ProfileError(f"model: must be 'auto', 'hill' or 'linear', got {model!r}")
    if not 0.0 < confidence < 1.0:
        raise ProfileError(f"confidence: must be between 0 and 1, got {confidence}")
    if len(steps) < MIN_STEPS:
        raise ProfileError(f"steps: need at least {MIN_STEPS} steps, got {len(steps)}")
    means = sorted((_step_mean(i, s) for i, s in enumerate(steps)), key=lambda m: m.w)
    if len({round(m.velocity, 9) for m in means}) < MIN_STEPS:
        raise ProfileError(f"steps: need at least {MIN_STEPS} distinct velocities")
    w = np.array([m.w for m in means])
    y = np.array([m.tau for m in means])
    se = _weights_se(means)
    lin = _fit_linear(w, y, se)
    if model == "hill" and len(means) < 4:
        raise ProfileError("model: Hill's law needs at least 4 steps")
    hill = _fit_hill(w, y, se, lin) if model != "linear" and len(means) >= 4 else None
    if model == "auto":
        sol, p_value = _choose(lin, hill, float((y / se) @ (y / se)))
    else:
        sol = hill if model == "hill" and hill is not None else lin
        p_value = _choose(lin, hill, float((y / se) @ (y / se)))[1]
    short = [i for i, s in enumerate(steps) if s.q is not None and abs(s.q[-1] - s.q[0]) < TWO_PI]
    notes = [
        f"steps {short}: less than one turn of the handle; a stroke-angle ripple biases "
        "their means (plan whole turns)"
    ]
    return _result(sol, means, confidence, points, p_value, notes if short else [])


def _result(
    sol: _Solution,
    means: list[StepMean],
    confidence: float,
    points: int,
    p_value: float | None,
    notes: list[str],
) -> ProfileFit:
    rchi2 = sol.ssr / sol.dof if sol.dof > 0 else math.nan
    cov = sol.cov * (rchi2 if sol.dof > 0 else math.nan)
    from scipy import special

    q = 0.5 + confidence / 2.0
    t = float(special.stdtrit(sol.dof, q)) if sol.dof > 0 else math.nan  # Student's t quantile
    th = sol.theta

    def derived(f: Callable[[np.ndarray], float]) -> Estimate:
        g = _gradient(lambda x: math.log(f(x)), th)
        return _log_estimate(math.log(f(th)), float(g @ cov @ g), t)

    w_opt = sol.law.w_opt
    warnings = list(notes)
    if sol.at_bound:
        warnings.append(f"Hill's curvature a reached its bound {A_BOUNDS}")
    wmax = math.exp(th[1])
    if wmax > 3.0 * means[-1].w:
        warnings.append("wmax lies far beyond the fastest step: an extrapolation")
    return ProfileFit(
        model=sol.law.name,
        tau0=_log_estimate(th[0], cov[0, 0], t),
        wmax=_log_estimate(th[1], cov[1, 1], t),
        a=_log_estimate(th[2], cov[2, 2], t) if sol.law is HILL else None,
        pmax=derived(lambda x: float(sol.law.torque(np.array([w_opt(x)]), x)[0]) * w_opt(x)),
        w_opt=derived(w_opt),
        confidence=confidence,
        dof=sol.dof,
        reduced_chi2=rchi2,
        hill_p_value=p_value,
        steps=tuple(means),
        curve=_curve(sol, cov, t, points),
        warnings=tuple(warnings),
    )
