"""The seekers' search logic against functions whose maximum is known."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from sessions.config import SeekerConfig
from sessions.seekers import make_seeker
from sessions.seekers.parabolic import parabola_vertex, step7

pos = st.floats(0.2, 10.0)


@given(
    v=st.floats(0.5, 8.0),
    c=st.floats(0.05, 5.0),
    top=st.floats(0.5, 50.0),
    g=st.lists(st.floats(0.1, 10.0), min_size=3, max_size=3, unique=True),
)
@settings(max_examples=200, deadline=None)
def test_one_parabolic_step_lands_on_the_vertex(
    v: float, c: float, top: float, g: list[float]
) -> None:
    g1, g2, g3 = sorted(g)
    assume(g2 - g1 > 1e-2 and g3 - g2 > 1e-2)
    p = [top - c * (x - v) ** 2 for x in (g1, g2, g3)]  # a parabola, maximal at v
    assert parabola_vertex(g1, p[0], g2, p[1], g3, p[2]) == pytest.approx(v, rel=1e-6, abs=1e-6)


def unimodal(m: float, skew: float, power: float):
    """A unimodal function with its maximum at m, skewed and not a parabola."""
    return lambda x: -(abs(x - m) ** power) * (skew if x > m else 1.0)


@given(
    m=st.floats(1.0, 9.0),
    skew=st.floats(0.2, 5.0),
    power=st.floats(1.2, 3.0),
    frac=st.lists(st.floats(0.01, 0.99), min_size=3, max_size=3, unique=True),
)
@settings(max_examples=300, deadline=None)
def test_corrected_step7_keeps_the_maximum_bracketed(
    m: float, skew: float, power: float, frac: list[float]
) -> None:
    f = unimodal(m, skew, power)
    lo, hi = m - 0.9 * m * frac[0], m + (10 - m) * frac[1]
    mid = lo + (hi - lo) * frac[2]
    pts = sorted([(lo, f(lo)), (mid, f(mid)), (hi, f(hi))])
    assume(pts[1][1] >= max(pts[0][1], pts[2][1]))  # a proper bracket: middle point best
    for _ in range(12):
        (g1, p1), (g2, p2), (g3, p3) = pts
        g4 = parabola_vertex(g1, p1, g2, p2, g3, p3)
        if g4 is None or not g1 < g4 < g3 or min(abs(g4 - g) for g, _ in pts) < 1e-9:
            break
        pts = step7(pts, g4, f(g4))
        assert pts[0][0] <= m <= pts[2][0], "the corrected Step 7 lost the maximum"


def test_step7_as_printed_drops_the_maximum() -> None:
    # γ4 right of γ2 but lower: the maximum is in [γ1, γ4]; the misprint keeps [γ2, γ3].
    f = unimodal(2.0, 1.0, 2.0)
    pts = [(1.0, f(1.0)), (2.2, f(2.2)), (4.0, f(4.0))]
    fixed = step7(pts, 3.0, f(3.0))
    printed = step7(pts, 3.0, f(3.0), as_printed=True)
    assert fixed[0][0] <= 2.0 <= fixed[2][0]
    assert not printed[0][0] <= 2.0 <= printed[2][0]


@given(
    m=st.floats(1.3, 5.7),
    skew=st.floats(0.3, 3.0),
    power=st.floats(1.5, 3.0),
    guess=st.floats(0.05, 0.95),
)
@settings(max_examples=150, deadline=None)
def test_brent_finds_the_maximum_of_unimodal_functions(
    m: float, skew: float, power: float, guess: float
) -> None:
    lo, hi = 1.0, 6.0
    cfg = SeekerConfig(kind="brent", bracket=(lo, lo + (hi - lo) * guess, hi), max_evaluations=60)
    seeker = make_seeker(cfg, 1e-3, 15.0)
    found = seeker.drive(unimodal(m, skew, power))
    assert seeker.done
    assert abs(found - m) <= 3 * cfg.min_step
    candidates = [ev.candidate for ev in seeker.evaluations]
    gaps = [abs(a - b) for i, a in enumerate(candidates) for b in candidates[:i]]
    assert min(gaps) >= 0.5 * cfg.min_step  # no repeated point
    assert all(lo <= c <= hi for c in candidates)  # never outside the bracket


def test_brent_stops_on_noise_instead_of_chasing_it() -> None:
    # A flat top under noise: once points can't be told apart, stop (and not after 60 points).
    import random

    rng = random.Random(4)
    cfg = SeekerConfig(kind="brent", bracket=(1.0, 2.0, 6.0), max_evaluations=60)
    seeker = make_seeker(cfg, 1e-3, 15.0)
    sigma = 0.02
    found = seeker.drive(lambda x: 3.0 - 0.05 * (x - 3.5) ** 2 + rng.gauss(0, sigma), stderr=sigma)
    assert seeker.reason == "bracket within the tolerance"
    assert len(seeker.evaluations) < 20
    assert 3.0 - 0.05 * (found - 3.5) ** 2 >= 3.0 - 3 * sigma  # within noise of the top


def test_parabolic_drive_finds_the_surrogate_optimum_in_four_evaluations() -> None:
    cfg = SeekerConfig(kind="parabolic", bracket=(1.0, 2.5, 4.0))
    seeker = make_seeker(cfg, 1e-3, 15.0)
    found = seeker.drive(lambda w: 3.0 - (w - 3.0) ** 2 / 3.0)
    assert found == pytest.approx(3.0, abs=1e-9)
    assert [round(ev.candidate, 9) for ev in seeker.evaluations] == [1.0, 2.5, 4.0, 3.0]
    assert math.isclose(seeker.progress().best.power, 3.0)


def test_brent_bracketing_does_not_stride_past_a_visible_peak() -> None:
    # The surrogate (31), p = 2w(1 - w/6), peak at 3, searched from 1.5 (h = 5 % of [1, 5] =
    # 0.2). Once three points show the curvature, the stride stops at their vertex, then goes
    # h beyond to see the descent: no probe past w* + h. Golden growth alone (1.7, 1.9, 2.22,
    # 2.75, 3.59, …) strides on past the peak.
    cfg = SeekerConfig(kind="brent", bracket=(1.0, 1.5, 5.0))
    seeker = make_seeker(cfg, 1e-3, 15.0)
    found = seeker.drive(lambda w: 2.0 * w * (1.0 - w / 6.0))
    candidates = [ev.candidate for ev in seeker.evaluations]
    assert max(candidates) <= 3.0 + 0.2 + 1e-9
    assert abs(found - 3.0) <= cfg.min_step
