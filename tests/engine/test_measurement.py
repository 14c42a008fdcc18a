"""Measuring p: the averaging window (averaging.py), the least-squares peak of the numerical
seekers (fit.py) and the regression on every sample (regression.py), against known truths."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from sessions.seekers.averaging import PowerAverager, summarise
from sessions.seekers.base import Evaluation
from sessions.seekers.fit import final_estimate, quadratic_peak, top_curvature
from sessions.seekers.regression import Rows, T, W, fit, smooth_top


def ar1(n: int, std: float, rho: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.empty(n)
    x[0] = rng.normal(0.0, std)
    b = std * math.sqrt(1 - rho * rho)
    for k in range(1, n):
        x[k] = rho * x[k - 1] + b * rng.normal()
    return x


# -- averaging.py ---------------------------------------------------------------------------


def test_the_window_ends_on_a_whole_revolution_and_removes_the_ripple() -> None:
    # p = 2 + 0.4 sin q at w = 3 rad/s: a window that ends on a whole revolution after the
    # shortest window, and a mean with the ripple regressed out: exactly 2.
    dt, w = 1e-3, 3.0
    avg = PowerAverager(window=0.5, max_window=6.0, quiet=1e-6)
    avg.start(0.0, 0.0)
    k = 0
    while True:
        t = k * dt
        q = w * t
        if avg.add(t, q, 2.0 + 0.4 * math.sin(q), w):
            break
        k += 1
    m = avg.result(t)
    assert 2 * math.pi / w <= m.duration <= 2 * math.pi / w + 2 * dt  # one revolution
    assert m.mean == pytest.approx(2.0, abs=1e-6)
    assert m.velocity == pytest.approx(w)


def test_a_quiet_signal_ends_at_the_shortest_window() -> None:
    avg = PowerAverager(window=0.5, max_window=6.0, quiet=0.01)
    avg.start(0.0, 0.0)
    k = 0
    while not avg.add(k * 1e-3, 0.001 * k, 3.0, 1.0):
        k += 1
    assert k * 1e-3 == pytest.approx(0.5, abs=2e-3)


def test_stderr_by_batch_means_covers_correlated_noise() -> None:
    # AR(1) noise correlated over ~30 samples: the naive σ/√n understates the error of the
    # mean several-fold; batch means must not. Over many windows the reported stderr matches
    # the scatter of the means.
    n, rho = 4000, 0.97
    means, errs = [], []
    for seed in range(60):
        p = 5.0 + ar1(n, 0.1, rho, seed)
        m = summarise(np.zeros(n), p, 4.0, 1.0)
        means.append(m.mean)
        errs.append(m.stderr)
    scatter = float(np.std(means, ddof=1))
    naive = 0.1 / math.sqrt(n)
    assert scatter > 4 * naive  # the correlation matters
    assert float(np.sqrt(np.mean(np.square(errs)))) == pytest.approx(scatter, rel=0.35)


# -- fit.py ----------------------------------------------------------------------------------


def test_quadratic_peak_is_the_vertex_of_a_parabola_with_a_drift() -> None:
    # p = 3 - 0.4 (g - 2.7)² - 0.01 t: the drift (fatigue) would bias a fit without its term
    evs = [
        Evaluation(t, g, 3.0 - 0.4 * (g - 2.7) ** 2 - 0.01 * t, 0.01)
        for t, g in enumerate([1.0, 3.5, 2.0, 3.0, 2.5, 2.8, 2.6, 3.2, 2.2], start=1)
    ]
    assert quadratic_peak(evs, 0.0, 10.0) == pytest.approx(2.7, abs=1e-6)
    assert top_curvature(evs) == pytest.approx(-0.8, rel=1e-6)
    assert final_estimate(evs, 0.0, 10.0, fallback=1.0) == pytest.approx(2.7, abs=1e-6)


def test_quadratic_peak_never_extrapolates_and_needs_a_maximum() -> None:
    rising = [Evaluation(i, g, g, 0.01) for i, g in enumerate([1.0, 2.0, 3.0, 4.0])]
    assert quadratic_peak(rising, 0.0, 10.0) is None  # no maximum: no peak
    conv = [Evaluation(i, g, (g - 2.0) ** 2, 0.01) for i, g in enumerate([1.0, 2.0, 3.0])]
    assert quadratic_peak(conv, 0.0, 10.0) is None  # a minimum is not a peak
    far = [Evaluation(i, g, -((g - 9.0) ** 2), 0.01) for i, g in enumerate([1.0, 2.0, 3.0])]
    assert quadratic_peak(far, 0.0, 10.0) == pytest.approx(3.0)  # kept within the points


# -- regression.py ----------------------------------------------------------------------------


def rows_of(w: np.ndarray, p: np.ndarray, q: np.ndarray, dt: float = 1e-3) -> np.ndarray:
    rows = Rows(dt)
    for k in range(len(w)):
        rows.add(k * dt, q[k], p[k], w[k], w[k])
    return rows.view()


def test_fit_recovers_a_parabola_under_multiplicative_ripple() -> None:
    # a sweep over w with p = (5 - 2 (w - 3)²)(1 + 0.2 sin q + 0.1 cos 2q): the ripple is
    # regressed out, the parabola and its vertex come out exact
    n = 20_000
    t = np.arange(n) * 1e-3
    w = 2.4 + 1.2 * (0.5 - 0.5 * np.cos(2 * math.pi * t / 20.0))
    q = np.cumsum(w) * 1e-3
    base = 5.0 - 2.0 * (w - 3.0) ** 2
    p = base * (1.0 + 0.2 * np.sin(q) + 0.1 * np.cos(2 * q))
    f = fit(rows_of(w, p, q), 3.0, 0.6)
    assert f is not None
    v, _ = f.vertex()
    assert v == pytest.approx(3.0, abs=2e-3)
    assert f.curvature[0] == pytest.approx(-4.0, rel=1e-2)
    assert f.ripple[0] == pytest.approx(0.2, abs=5e-3) and f.ripple[3] == pytest.approx(
        0.1, abs=5e-3
    )
    plain = fit(rows_of(w, p, q), 3.0, 0.6, ripple=False)  # without the ripple terms: off
    assert plain is not None and abs(plain.vertex()[0] - 3.0) > 5 * abs(v - 3.0)


N, DT = 15_000, 1e-3  # the Monte-Carlo fits' rows: 15 s at 1 kHz


def _vertices(noise_of: Callable[[int], np.ndarray]) -> tuple[list[float], list[float]]:
    """40 fits of p = 4 − (w − 3.1)² with relative noise ``noise_of(seed)`` while w sweeps
    3 ± 0.6 rad/s: each fit's vertex and its reported standard error."""
    t = np.arange(N) * DT
    w = 3.0 + 0.6 * np.sin(2 * math.pi * t / 5.0)
    q = np.cumsum(w) * DT
    vs, ses = [], []
    for seed in range(40):
        p = (4.0 - 1.0 * (w - 3.1) ** 2) * (1.0 + noise_of(seed))
        f = fit(rows_of(w, p, q), 3.0, 0.6)
        assert f is not None
        v, se = f.vertex()
        vs.append(v)
        ses.append(se)
    return vs, ses


def test_vertex_standard_error_matches_its_scatter() -> None:
    # noise correlated over ~30 ms: the AR(1) inflation keeps the standard error honest
    vs, ses = _vertices(lambda seed: ar1(N, 0.05, math.exp(-DT / 0.03), seed))
    scatter = float(np.std(vs, ddof=1))
    assert abs(float(np.mean(vs)) - 3.1) < 3 * scatter / math.sqrt(len(vs)) + 1e-3
    assert float(np.sqrt(np.mean(np.square(ses)))) == pytest.approx(scatter, rel=0.4)


@pytest.mark.xfail(
    strict=True,
    reason="regression._noise's AR(1) factor over-covers answered pushes 1.8x (docs/benchmarks.md)",
)
def test_vertex_standard_error_matches_its_scatter_when_pushes_are_answered() -> None:
    # In the loop a push is answered by the controller: the power's noise is correlated over
    # a few 20 ms rows and then negatively (the handle brought back), no AR(1) process. Here
    # n(t) = z(t) − 0.5 z(t − 60 ms), z correlated over 30 ms: rows' ρ₁ is high, yet the
    # long-run variance is small. The AR(1) factor of ρ₁ alone put the standard error at
    # 1.8× the vertex's scatter over seeds (so the tracker and the search trusted every fit
    # half as much as they should); the long-run variance puts it at the scatter (branch
    # seek6-lrv), but the seekers' tuning rests on the wider errors: docs/benchmarks.md.
    from scipy.signal import lfilter

    lag, a = 60, math.exp(-DT / 0.03)

    def answered(seed: int) -> np.ndarray:
        white = np.random.default_rng(seed).standard_normal(N + lag)
        z = lfilter([math.sqrt(1.0 - a * a)], [1.0, -a], white)
        return 0.05 * (z[lag:] - 0.5 * z[:-lag])

    vs, ses = _vertices(answered)
    scatter = float(np.std(vs, ddof=1))
    assert float(np.sqrt(np.mean(np.square(ses)))) == pytest.approx(scatter, rel=0.25)


def test_the_abscissa_ignores_the_persons_own_fluctuation() -> None:
    # w = wd + e with e driven by the power's own noise (the person pushes, the handle speeds
    # up): a regression on raw w reads that as a slope; rows place p at wd + ē (ē averaged
    # over 0.5 s), so a flat power stays flat.
    n, dt = 30_000, 1e-3
    t = np.arange(n) * dt
    wd = 3.0 + 0.1 * np.sin(2 * math.pi * t / 6.0)
    noise = ar1(n, 0.05, math.exp(-dt / 0.03), 1)
    p = 4.0 * (1.0 + noise)  # flat in w: the true slope is 0
    w = wd + 0.5 * noise  # the handle follows the push
    rows = Rows(dt)
    for k in range(n):
        rows.add(t[k], 0.0, p[k], w[k], wd[k])
    f = fit(rows.view(), 3.0, 0.3, ripple=False)
    slope, se = f.slope(3.0)
    assert abs(slope) < 3 * se
    raw = np.column_stack(
        [t, w, p, np.zeros(n), np.ones(n), np.zeros(n), np.ones(n)]
    )  # rows at full rate on the raw w
    g = fit(raw, 3.0, 0.3, ripple=False)
    raw_slope, raw_se = g.slope(3.0)
    assert raw_slope > 5 * raw_se and raw_slope > 0.5  # the bias the rows avoid


def test_rows_re_based_on_a_longer_average_take_wd_plus_their_mean_tracking_error() -> None:
    # The track phase fits the search's last rows with its own, longer average of the
    # tracking error: from ``since`` on each row's abscissa becomes its wd plus the mean of
    # those rows' errors, the rows before keep theirs, and the average goes on from there.
    dt = 1e-3
    rows = Rows(dt)
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 4.0, dt)
    wd = 3.0 + 0.2 * np.sin(t)
    e = 0.05 * np.sign(np.sin(7.0 * t)) + 0.01 * rng.standard_normal(len(t))
    for k in range(len(t)):
        rows.add(float(t[k]), 0.0, 1.0, float(wd[k] + e[k]), float(wd[k]))
    before = rows.view().copy()
    rows.smooth(20.0, since=2.0)
    after = rows.view()
    late = before[:, T] >= 2.0
    n = rows.n_block
    block_wd = wd.reshape(-1, n).mean(axis=1)  # the rows' own wd and e, from the samples
    block_e = e.reshape(-1, n).mean(axis=1)
    assert np.allclose(after[~late], before[~late])
    assert np.allclose(after[late, W], block_wd[late] + block_e[late].mean(), atol=1e-12)
    assert rows.e_mean == pytest.approx(float(block_e[late].mean()), abs=1e-12)
    assert not np.allclose(before[late, W], after[late, W])  # the 1 s average was another


def test_a_level_curving_in_time_stays_out_of_the_slope() -> None:
    # The tracker's model around θ = 3: a 3 % dither for 60 s on p = L(t)·(8 − 0.8 (w − 3.1)²)
    # with L(t) = exp(−t/200), a strength that fatigues. The level falls 26 % while the
    # dither moves the power by ~0.3 %: a linear trend in time leaves the trend's curvature
    # in the residual, and what of it lines up with the dither reads as slope (the vertex
    # now 0.04 off, 14× the τ² model's error). With τ² the vertex now is w* within 0.3 %,
    # and the term's t says the rows need it.
    dt = 1e-3
    t = np.arange(60_000) * dt
    w = 3.0 + 0.09 * np.sin(2 * math.pi * t / 6.0)
    q = np.cumsum(w) * dt
    p = np.exp(-t / 200.0) * (8.0 - 0.8 * (w - 3.1) ** 2)
    rows = Rows(dt)
    for k in range(len(t)):
        rows.add(float(t[k]), float(q[k]), float(p[k]), float(w[k]), float(w[k]))
    d = rows.view()
    wts = np.exp(-(t[-1] - d[:, 0]) / 20.0)
    kw = {"prior": (-0.6, 0.3), "moving": True, "weights": wts}
    bent, straight = fit(d, 3.0, 0.27, bend=True, **kw), fit(d, 3.0, 0.27, **kw)
    assert bent is not None and bent.now is not None and bent.bend > 10.0
    assert straight is not None and straight.now is not None and straight.bend == 0.0
    assert bent.now[0] == pytest.approx(3.1, abs=0.01)
    assert abs(straight.now[0] - 3.1) > 3.0 * abs(bent.now[0] - 3.1)


def skewed_top(w: np.ndarray, w_star: float, s_lo: float, s_hi: float) -> np.ndarray:
    """p = 10·exp(−x²/(2s²)) on x = ln(w/w*), s = s_lo below w*, s_hi above: the skewed tops
    of the benchmark's population; its 99 % band is w*·exp(±s·√0.02)."""
    x = np.log(w / w_star)
    s = np.where(x < 0.0, s_lo, s_hi)
    return 10.0 * np.exp(-((x / s) ** 2) / 2.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_smoother_finds_a_skewed_top_a_parabola_misses(seed: int) -> None:
    # One leg from 5 down to 1.5 rad/s in 6 s across a skewed top at 3 (99 % band
    # 2.88-3.31), 2 % correlated noise: the smoothed top lies in the band and so does its
    # band's centre, where a parabola through ±30 % of the top puts the vertex ~20 % off.
    n, dt = 6000, 1e-3
    t = np.arange(n) * dt
    w = 5.0 - 3.5 * t / t[-1]
    q = np.cumsum(w) * dt
    p = skewed_top(w, 3.0, 0.3, 0.7) * (1.0 + ar1(n, 0.02, math.exp(-dt / 0.03), seed))
    rows = rows_of(w, p, q)
    found = smooth_top(rows)
    assert found is not None
    v, top, lo, hi = found
    band = (3.0 * math.exp(-0.3 * math.sqrt(0.02)), 3.0 * math.exp(0.7 * math.sqrt(0.02)))
    assert band[0] <= v <= band[1]
    assert top == pytest.approx(10.0, rel=0.02)
    assert lo < v < hi and band[0] <= 0.5 * (lo + hi) <= band[1]
    assert 0.3 < (hi - lo) / (band[1] - band[0]) < 1.5  # the band's width, roughly
    parabola = fit(rows, 3.0, 0.9, ripple=False)
    assert parabola is not None and abs(parabola.vertex()[0] - 3.0) > 0.1 * 3.0


def test_the_smoother_sees_no_top_where_the_power_still_rises_at_the_rows_end() -> None:
    # rows that climb to their last velocity (the optimum beyond the bracket): no top
    n, dt = 6000, 1e-3
    w = np.linspace(1.0, 2.5, n)
    q = np.cumsum(w) * dt
    assert smooth_top(rows_of(w, skewed_top(w, 3.0, 0.3, 0.7), q)) is None
    assert smooth_top(rows_of(w[::-1], skewed_top(w[::-1], 0.8, 0.3, 0.7), q)) is None
