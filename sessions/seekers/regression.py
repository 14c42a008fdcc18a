"""Learning p(w) from the whole stream: every sample, not only settled windows.

:class:`Rows` turns the loop's full-rate samples (t, q, p, w) into short blocks (20 ms by
default: a few noise correlation times, far shorter than anything the seekers do) and keeps
the recent ones in a bounded buffer. :func:`fit` regresses the power on the velocity around a
centre c, with the stroke ripple and an optional drift regressed out:

    p ≈ f(w) · (1 + Σₖ₌₁,₂ αₖ sin kq + βₖ cos kq) + d (t - t̄),   f(w) = a + b x + c₂ x²,
    x = (w - c) / h

The ripple is multiplicative (a person's torque varies with the stroke angle in proportion to
their effort); it is fitted linearly with f replaced by the previous pass's estimate (two
passes), first and second harmonic (one and two pushes per revolution).

The abscissa w of a row is where the power was produced, without what the person's own
fluctuation did to it: wd + ē, the commanded velocity plus the tracking error averaged over
``E_SMOOTH`` (1 s; the tracker, whose dither moves wd far less than a search does, sets a
longer one with :meth:`Rows.smooth`, and re-bases the search's last rows it fits on it: each
row keeps its wd and its own tracking error e). Not the raw w: a person pushing harder for a
moment speeds the handle up before the controller brings it back, so the raw w and the power's
noise move together, and a regression on the raw w reads that as a slope (an
errors-in-variables bias: with 5 % noise and a ±4 % dither it moves the fitted top by ~8 %).
wd is exogenous (the seeker sets it); ē keeps the abscissa unbiased by a lasting tracking
error (the bias of the paper's (13)). One second is far beyond the noise's correlation time,
but shorter than a stroke below 6.3 rad/s. So part of the handle's speed change within a
stroke (the ripple moves it too) stays in ē, in step with the power's ripple, and biases the
slope off the top (docs/benchmarks.md, "The ripple moves the handle").

Uncertainty: the residuals of neighbouring blocks are correlated (band-limited noise); the
covariance is inflated by the AR(1) factor (1 + r₁)/(1 - r₁) of the residuals' lag-one
correlation, the usual effective-sample-size correction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

COLUMNS = ("t", "w", "p", "s1", "c1", "s2", "c2", "wd", "e")
T, W, P, S1, C1, S2, C2, WD, E = range(9)  # w: the abscissa, wd + ē; e: the block's own


E_SMOOTH = 1.0  # s: the tracking error's average in the abscissa
MAX_SHARPNESS = 30.0  # the most ½|p''|w²/p a person's top can have


class Rows:
    """Block means of the sample stream, the newest ``capacity`` blocks kept."""

    __slots__ = (
        "n_block", "block_s", "capacity", "data", "size", "alpha", "e_mean", "_st", "_sq",
        "_sp", "_sw", "_sd", "_k",
    )  # fmt: skip

    def __init__(self, dt: float, block: float = 0.02, capacity: int = 8192) -> None:
        self.n_block = max(1, round(block / dt))
        self.block_s = self.n_block * dt
        self.capacity = capacity
        self.data = np.zeros((2 * capacity, len(COLUMNS)))
        self.size = 0
        self.smooth(E_SMOOTH)
        self.e_mean = math.nan
        self.clear_block()

    def smooth(self, seconds: float, since: float | None = None) -> None:
        """Average the tracking error in the abscissa over ``seconds`` from the next row on
        (an exponential moving average of that time constant); with ``since``, the rows from
        then on get as abscissa wd plus their tracking error's mean, and the average goes on
        from that mean (rows a longer average will be fitted with)."""
        self.alpha = min(1.0, self.block_s / seconds)
        if since is None or not self.size:
            return
        d = self.view(since)  # a view: the rows are re-based in place
        if len(d):
            self.e_mean = float(d[:, E].mean())
            d[:, W] = d[:, WD] + self.e_mean

    def clear_block(self) -> None:
        self._st = self._sq = self._sp = self._sw = self._sd = 0.0
        self._k = 0

    def clear(self) -> None:
        self.size = 0
        self.e_mean = math.nan
        self.clear_block()

    def add(self, t: float, q: float, p: float, w: float, wd: float) -> bool:
        """One sample: p measured at velocity w with the reference at wd; True when it
        completed a block (a new row)."""
        self._st += t
        self._sq += q
        self._sp += p
        self._sw += w
        self._sd += wd
        self._k += 1
        if self._k < self.n_block:
            return False
        k = self._k
        q = self._sq / k
        wd = self._sd / k
        e = self._sw / k - wd
        em = self.e_mean
        self.e_mean = e if math.isnan(em) else em + self.alpha * (e - em)
        if self.size == len(self.data):  # keep the newest half: amortised O(1)
            self.data[: self.capacity] = self.data[self.capacity :]
            self.size = self.capacity
        self.data[self.size] = (
            self._st / k,
            wd + self.e_mean,
            self._sp / k,
            math.sin(q),
            math.cos(q),
            math.sin(2.0 * q),
            math.cos(2.0 * q),
            wd,
            e,
        )
        self.size += 1
        self.clear_block()
        return True

    def view(self, since: float = -math.inf) -> np.ndarray:
        """The rows (oldest first) whose time is at least ``since``."""
        d = self.data[: self.size]
        if since > -math.inf and self.size:
            d = d[np.searchsorted(d[:, T], since) :]
        return d

    @property
    def last_t(self) -> float:
        return float(self.data[self.size - 1, T]) if self.size else -math.inf


@dataclass(frozen=True, slots=True)
class Fit:
    """p ≈ a + b x + c x² (x = (w - center)/scale), with its covariance and noise."""

    center: float
    scale: float
    coef: np.ndarray  # a, b, c (c fixed when the fit was given a curvature)
    cov: np.ndarray  # 3 × 3 (row and column of a fixed c are zero)
    ripple: tuple[float, float, float, float]  # relative α₁, β₁, α₂, β₂ (zeros if not fitted)
    sigma: float  # residual std of one row
    inflate: float  # the variance inflation for correlated residuals, (1 + r₁)/(1 - r₁)
    misfit: float  # with ``misfit_test``: the largest |t| of x³, x⁴ (the curve is no parabola)
    now: tuple[float, float] | None  # with ``moving``: the vertex at the last row, its std err
    n: int
    w_lo: float
    w_hi: float
    bend: float = 0.0  # with ``bend``: the |t| of the level's curvature in time (τ²)

    def value(self, w: float) -> float:
        x = (w - self.center) / self.scale
        a, b, c = self.coef
        return float(a + b * x + c * x * x)

    def slope(self, w: float) -> tuple[float, float]:
        """dp/dw at w and its standard error."""
        x = (w - self.center) / self.scale
        g = np.array([0.0, 1.0, 2.0 * x]) / self.scale
        return float(g @ self.coef), math.sqrt(max(float(g @ self.cov @ g), 0.0))

    def drop(self, w1: float, w2: float) -> tuple[float, float]:
        """p(w1) - p(w2) and its standard error."""
        x1, x2 = (w1 - self.center) / self.scale, (w2 - self.center) / self.scale
        g = np.array([0.0, x1 - x2, x1 * x1 - x2 * x2])
        return float(g @ self.coef), math.sqrt(max(float(g @ self.cov @ g), 0.0))

    @property
    def curvature(self) -> tuple[float, float]:
        """d²p/dw² and its standard error."""
        h2 = self.scale * self.scale
        return 2.0 * float(self.coef[2]) / h2, 2.0 * math.sqrt(max(self.cov[2, 2], 0.0)) / h2

    def concave(self, k: float = 2.0) -> bool:
        """A maximum beyond k standard errors, and a plausible one: no sharper than a top
        whose 99 % band is ±1.8 % of w (½|p''|w²/p ≤ MAX_SHARPNESS), which no person's curve
        is; sharper is a fit to too few rows or a transient."""
        c, se = self.curvature
        level = float(self.coef[0])
        if level > 0.0 and 0.5 * -c * self.center**2 / level > MAX_SHARPNESS:
            return False
        return c < -k * se

    def vertex(self) -> tuple[float, float]:
        """The stationary point of the parabola and its standard error (delta method);
        (nan, inf) when it is not a maximum."""
        _, b, c = self.coef
        if not c < 0.0:
            return math.nan, math.inf
        v = self.center - self.scale * b / (2.0 * c)
        g = np.array([0.0, -self.scale / (2.0 * c), self.scale * b / (2.0 * c * c)])
        return float(v), math.sqrt(max(float(g @ self.cov @ g), 0.0))


def _vertex_now(
    coef: np.ndarray,
    cov: np.ndarray,
    center: float,
    scale: float,
    j: int,
    tau: float,
    c_fixed: float | None = None,
) -> tuple[float, float]:
    """The vertex of a + (b + d τ) x + c x² at τ (d the coefficient in column j; c fixed
    when given, else fitted in column 2)."""
    b, d = coef[1], coef[j]
    c = coef[2] if c_fixed is None else c_fixed
    if not c < 0.0:
        return math.nan, math.inf
    bn = b + d * tau
    v = center - scale * bn / (2.0 * c)
    if c_fixed is None:
        idx = [1, 2, j]
        g = np.array([-scale / (2.0 * c), scale * bn / (2.0 * c * c), -scale * tau / (2.0 * c)])
    else:
        idx = [1, j]
        g = np.array([-scale / (2.0 * c), -scale * tau / (2.0 * c)])
    sub = cov[np.ix_(idx, idx)]
    return float(v), math.sqrt(max(float(g @ sub @ g), 0.0))


def _t_max(coef: np.ndarray, cov: np.ndarray, i: int, j: int) -> float:
    se = np.sqrt(np.maximum(np.diag(cov)[i:j], 1e-300))
    return float(np.max(np.abs(coef[i:j]) / se))


def _misfit(
    rows: np.ndarray,
    center: float,
    scale: float,
    *,
    drift: bool,
    weights: np.ndarray | None,
    ripple: bool,
) -> float:
    f = fit(rows, center, scale, drift=drift, weights=weights, ripple=ripple, powers=2)
    return math.inf if f is None else f.misfit


def without_ripple(rows: np.ndarray, ripple: tuple[float, float, float, float]) -> np.ndarray:
    """The rows with a known (relative) ripple divided out of the power."""
    if not any(ripple):
        return rows
    out = rows.copy()
    a1, b1, a2, b2 = ripple
    factor = 1.0 + a1 * rows[:, S1] + b1 * rows[:, C1] + a2 * rows[:, S2] + b2 * rows[:, C2]
    out[:, P] = rows[:, P] / np.maximum(factor, 0.1)
    return out


def fit_ripple(
    rows: np.ndarray, cols: list[np.ndarray]
) -> tuple[float, float, float, float] | None:
    """The relative ripple α₁, β₁, α₂, β₂ of p ≈ f·(1 + Σ …) with f spanned by ``cols``
    (two passes, as in :func:`fit`)."""
    p = rows[:, P]
    level = np.full(len(rows), max(float(np.mean(p)), 1e-12))
    k = len(cols)
    coef = None
    for _ in range(2):
        a = np.column_stack([*cols, *(level * rows[:, j] for j in (S1, C1, S2, C2))])
        solved = _solve(a, p, None, None)
        if solved is None:
            return None
        coef = solved[0]
        level = np.maximum(a[:, :k] @ coef[:k], 1e-12)
    assert coef is not None
    return tuple(float(v) for v in coef[k:])  # type: ignore[return-value]


def _solve(
    a: np.ndarray, y: np.ndarray, weights: np.ndarray | None, penalty: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Weighted least squares by the normal equations (a handful of columns, scaled to order
    one: well conditioned, and far cheaper than an SVD on the 1 kHz path); ``penalty`` =
    (index, λ, target) adds λ (βᵢ - target)². Returns β, M⁻¹ and AᵀW²A + λ eᵢeᵢᵀ."""
    aw = a if weights is None else a * weights[:, None]
    m = aw.T @ a
    rhs = aw.T @ y
    meat = aw.T @ aw
    if penalty is not None:
        i, lam, target = int(penalty[0]), float(penalty[1]), float(penalty[2])
        m[i, i] += lam
        rhs[i] += lam * target
        meat[i, i] += lam
    scale = np.sqrt(np.maximum(np.diag(m), 1e-300))
    ms = m / np.outer(scale, scale)
    try:
        if np.linalg.cond(ms) > 1e10:
            return None
        inv = np.linalg.inv(ms) / np.outer(scale, scale)
    except np.linalg.LinAlgError:
        return None
    return inv @ rhs, inv, meat


def _noise(resid: np.ndarray, wts: np.ndarray, k: int) -> tuple[float, float]:
    """Residual variance of one row and the AR(1) inflation (1 + r₁)/(1 - r₁)."""
    n = len(resid)
    dof = max(float(wts.sum()) * (n - k) / n, 1.0)
    s2 = float((wts * resid * resid).sum()) / dof
    r1 = 0.0
    if n > 8:
        r0 = float(resid @ resid)
        if r0 > 0.0:
            r1 = min(max(float(resid[1:] @ resid[:-1]) / r0, 0.0), 0.95)
    return s2, (1.0 + r1) / (1.0 - r1)


@dataclass(slots=True)
class _Design:
    """The columns of the model over some rows: the polynomial in x (``base``), the time
    terms (``extra``), the response y (with a fixed curvature's part taken out)."""

    x: np.ndarray
    y: np.ndarray
    base: list[np.ndarray]
    extra: list[np.ndarray]
    c_fixed: float | None
    tau_end: float


def _design(
    rows: np.ndarray,
    center: float,
    scale: float,
    curvature: float | None,
    powers: int,
    drift: bool,
    moving: bool,
    bend: bool = False,
) -> _Design:
    n = len(rows)
    x = (rows[:, W] - center) / scale
    p = rows[:, P]
    c_fixed = None if curvature is None else 0.5 * curvature * scale * scale
    y = p if c_fixed is None else p - c_fixed * x * x
    base = [np.ones(n), x] if c_fixed is not None else [np.ones(n), x, x * x]
    base += [x**k for k in range(3, 3 + powers)]
    extra: list[np.ndarray] = []
    tau_end = 0.0
    if (drift or moving) and n:
        tt = rows[:, T]
        span = float(tt[-1] - tt[0])
        if span > 0.0:
            tau = (tt - tt.mean()) / span
            tau_end = float(tau[-1])
            extra.append(tau)
            if bend:
                extra.append(tau * tau)  # a level whose trend curves (fatigue is exponential)
            if moving:
                extra.append(x * tau)  # the slope changes in time: the top moves (last)
    return _Design(x, y, base, extra, c_fixed, tau_end)


def _iterate(
    rows: np.ndarray,
    d: _Design,
    weights: np.ndarray | None,
    ripple: bool,
    prior: tuple[float, float] | None,
    scale: float,
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], int, float, float] | None:
    """The least-squares passes: the ripple's columns scaled by the previous pass's f (and a
    prior's ridge weighed by the previous pass's noise). Returns (β, M⁻¹, meat), the number
    of columns, the residual variance and the AR(1) inflation."""
    n = len(rows)
    wts = weights if weights is not None else np.ones(n)
    level = np.full(n, max(float(np.mean(rows[:, P])), 1e-12))
    with_prior = prior is not None and d.c_fixed is None
    solved = None
    ncols = 0
    s2 = inflate = 0.0
    nb = len(d.base)
    for i in range(2 if ripple or with_prior else 1):
        cols = d.base + d.extra
        if ripple:
            cols += [level * rows[:, j] for j in (S1, C1, S2, C2)]
        a = np.column_stack(cols)
        penalty = None
        if with_prior and i > 0 and prior is not None:
            c2, se = prior
            h2 = 0.5 * scale * scale
            lam = s2 * inflate / max((se * h2) ** 2, 1e-300)
            penalty = np.array([2.0, lam, c2 * h2])
        solved = _solve(a, d.y, weights, penalty)
        if solved is None:
            return None
        coef = solved[0]
        s2, inflate = _noise(d.y - a @ coef, wts, len(cols))
        f = a[:, :nb] @ coef[:nb]
        if d.c_fixed is not None:
            f = f + d.c_fixed * d.x * d.x
        level = np.maximum(f, 1e-12)
        ncols = len(cols)
    assert solved is not None
    return solved, ncols, s2, inflate


def fit(
    rows: np.ndarray,
    center: float,
    scale: float,
    *,
    curvature: float | None = None,
    prior: tuple[float, float] | None = None,
    drift: bool = False,
    weights: np.ndarray | None = None,
    ripple: bool = True,
    misfit_test: bool = False,
    powers: int = 0,
    moving: bool = False,
    bend: bool = False,
) -> Fit | None:
    """The model above over ``rows``. ``curvature`` (d²p/dw²) fixes c₂ instead of fitting
    it; ``prior`` = (d²p/dw², its standard error) pulls c₂ towards a value the rows cannot
    pin down by themselves (a ridge, in the rows' own noise units); ``drift`` adds a level
    changing in time (fatigue), ``moving`` also a slope changing in time (x·τ: the top
    moving), and ``Fit.now`` is then the vertex at the last row's time; ``misfit_test`` also
    fits x³ and x⁴ and reports how significant they are (a lack-of-fit test: the parabola
    is no good this wide), the parabola's coefficients still from the quadratic alone;
    ``bend`` (with ``drift`` or ``moving``) adds a level curving in time (τ²) and reports
    the |t| of its coefficient in ``Fit.bend``. None when the rows cannot determine the
    model."""
    misfit = 0.0
    if misfit_test:
        misfit = _misfit(rows, center, scale, drift=drift, weights=weights, ripple=ripple)
    d = _design(rows, center, scale, curvature, powers, drift, moving, bend)
    k = len(d.base) + len(d.extra) + (4 if ripple else 0)
    if len(rows) < k + 3 or float(np.ptp(d.x)) <= 0.0:
        return None
    done = _iterate(rows, d, weights, ripple, prior, scale)
    if done is None:
        return None
    (coef, inv, meat), ncols, s2, inflate = done
    cov_full = inv @ meat @ inv * s2 * inflate  # the sandwich: robust to the weights
    nb = len(d.base) - powers
    cov = np.zeros((3, 3))
    cov[:nb, :nb] = cov_full[:nb, :nb]
    coef3 = np.zeros(3)
    coef3[:nb] = coef[:nb]
    if d.c_fixed is not None:
        coef3[2] = d.c_fixed
    if not np.all(np.isfinite(coef3)) or not np.all(np.isfinite(cov)):
        return None
    rip = tuple(float(v) for v in coef[ncols - 4 : ncols]) if ripple else (0.0, 0.0, 0.0, 0.0)
    now = None
    bend_t = 0.0
    if bend and len(d.extra) >= 2:
        bend_t = _t_max(coef, cov_full, len(d.base) + 1, len(d.base) + 2)
    if moving and len(d.extra) >= 2:
        j = len(d.base) + len(d.extra) - 1  # x·τ: the last of the time terms
        now = _vertex_now(coef, cov_full, center, scale, j, d.tau_end, d.c_fixed)
    w = rows[:, W]
    return Fit(
        center=center,
        scale=scale,
        coef=coef3,
        cov=cov,
        ripple=rip,  # type: ignore[arg-type]
        sigma=math.sqrt(max(s2, 0.0)),
        inflate=inflate,
        misfit=misfit if not powers else _t_max(coef, cov_full, 3, 3 + powers),
        bend=bend_t,
        now=now,
        n=len(rows),
        w_lo=float(w.min()),
        w_hi=float(w.max()),
    )


SMOOTH_WIDTH = 0.08  # the smoother's kernel: a Gaussian of this std in ln w
SMOOTH_GRID = 60  # points at which the smoothed curve is evaluated
SMOOTH_SIDE = 5.0  # kernel mass (rows) needed on each side of a grid point: no extrapolation
MIN_SMOOTH_ROWS = 12


def smooth_top(rows: np.ndarray) -> tuple[float, float, float, float] | None:
    """Where the power peaks along the rows without a model of the whole curve: a local
    quadratic in u = ln w, Gaussian kernel of SMOOTH_WIDTH, evaluated on a grid over the rows'
    range (only where rows lie on both sides). Returns (w at the maximum, the power there,
    and the lowest and highest w of the run of grid points within 1 % of it), or None when
    the smoothed power is highest where the rows end (no top inside them).

    A parabola through ±30 % of a sharp or skewed top misfits, and one through the few rows
    a fast leg leaves near the top is anchored wherever its centre was put; the local fit
    needs neither. A Gaussian kernel of width h on a top of log-width s widens it to
    √(s² + h²): on the sharpest tops a person has (s ≈ 0.3) that is 3 %. Rows: the ripple
    divided out."""
    if len(rows) < 4 * MIN_SMOOTH_ROWS:
        return None
    u = np.log(np.maximum(rows[:, W], 1e-9))
    lo, hi = float(u.min()), float(u.max())
    if hi - lo < 2.0 * SMOOTH_WIDTH:
        return None
    grid = np.linspace(lo, hi, SMOOTH_GRID)
    level = _smoothed(u, rows[:, P], grid)
    valid = np.flatnonzero(np.isfinite(level))
    if len(valid) < 3:
        return None
    j = int(valid[np.argmax(level[valid])])
    if j in (valid[0], valid[-1]) or not np.isfinite(level[[j - 1, j + 1]]).all():
        return None  # highest where the rows end: no top seen inside them
    top = float(level[j])
    within = level >= (0.99 * top if top > 0.0 else top)  # (-inf where not evaluated)
    lo_j, hi_j = j, j  # the band: the run of grid points within 1 % of the top
    while lo_j > 0 and within[lo_j - 1]:
        lo_j -= 1
    while hi_j < len(grid) - 1 and within[hi_j + 1]:
        hi_j += 1
    # between grid points: the vertex of the parabola through the three around the top
    y0, y2 = float(level[j - 1]), float(level[j + 1])
    den = y0 - 2.0 * top + y2
    shift = min(max(0.5 * (y0 - y2) / den, -0.5), 0.5) if den < 0.0 else 0.0
    step = float(grid[1] - grid[0])
    return (
        math.exp(float(grid[j]) + shift * step),
        top,
        math.exp(float(grid[lo_j])),
        math.exp(float(grid[hi_j])),
    )


def _smoothed(u: np.ndarray, p: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The local quadratic's level at each grid point (-inf where rows do not lie on both
    sides, or the fit is singular): weighted moments, one 3 × 3 solve per point."""
    x = (u[None, :] - grid[:, None]) / SMOOTH_WIDTH  # grid × rows
    k = np.exp(-0.5 * x * x)
    ok = ((k * (x < 0.0)).sum(axis=1) >= SMOOTH_SIDE) & ((k * (x > 0.0)).sum(axis=1) >= SMOOTH_SIDE)
    m = [(k * x**j).sum(axis=1) for j in range(5)]
    r = np.stack([(k * x**j * p[None, :]).sum(axis=1) for j in range(3)], -1)
    a = np.stack([np.stack(m[i : i + 3], -1) for i in range(3)], -2)  # Σk xⁱ⁺ʲ
    ok &= np.abs(np.linalg.det(a)) > 1e-9 * np.maximum(m[0], 1.0) ** 3
    level = np.full(len(grid), -np.inf)
    if ok.any():
        level[ok] = np.linalg.solve(a[ok], r[ok][..., None])[:, 0, 0]
    return level
