"""The seekers' search logic against functions whose maximum is known."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from sessions.config import SeekerConfig, parse_session_config
from sessions.seekers import make_seeker
from sessions.seekers.parabolic import parabola_vertex, step7
from sessions.seekers.sweep import SweepSeeker
from sessions.seekers.tracker import Tracker

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
    # A flat top under noise: once points can't be told apart, stop (and not after 60 points),
    # near the top: over 25 noise draws the median miss is a tenth of the noise resolution
    # δn = sqrt(k σ / |c|) ≈ 0.9 rad/s and three in four within a third of it. (One draw in
    # five still closes the bracket on a noise-made descent next to γ2 = 2, 1.5 rad/s off:
    # brent's weakness on noisy flat tops; the sweep regresses every sample instead.)
    import random

    sigma, misses = 0.02, []
    for seed in range(25):
        rng = random.Random(seed)
        cfg = SeekerConfig(kind="brent", bracket=(1.0, 2.0, 6.0), max_evaluations=60)
        seeker = make_seeker(cfg, 1e-3, 15.0)
        found = seeker.drive(
            lambda x, rng=rng: 3.0 - 0.05 * (x - 3.5) ** 2 + rng.gauss(0, sigma), stderr=sigma
        )
        assert seeker.reason in ("bracket within the tolerance", "evaluation budget spent")
        assert len(seeker.evaluations) < 25
        misses.append(abs(found - 3.5))
    misses.sort()
    resolution = math.sqrt(2 * sigma / 0.05)
    assert misses[len(misses) // 2] <= 0.15 * resolution
    assert misses[3 * len(misses) // 4 - 1] <= 0.35 * resolution


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


# -- the seekers on whole sessions ----------------------------------------------------------


def test_exp2_with_ergoseeks_defaults_ends_within_2pct_of_the_optimum() -> None:
    from sessions.experiments import experiment
    from sessions.simulation import run_simulation, score

    s = score(run_simulation(experiment("exp2", paper=False, seeker=SeekerConfig().kind)))
    assert s["converged"] and s["at_bound"] is None
    assert abs(s["optimum_w"] - s["w_star"]) <= 0.02 * s["w_star"]
    assert abs(s["wd_converged"] - s["w_star"]) <= 0.02 * s["w_star"]


def test_each_power_is_placed_where_it_was_produced() -> None:
    # p = τ̂·w at the mean of w: every window of exp2 (brent: windows, then the tracker) reads
    # the true power at its abscissa; p = τ̂·wd at the mean of wd (the paper's (13)) reads the
    # power of where the handle was not, while the tracking error has not died out.
    from sessions.experiments import experiment
    from sessions.simulation import run_simulation

    def worst(measure: str) -> float:
        # the paper's gains: a slow integral, so the tracking error lasts into the first window
        cfg = experiment("exp2", paper=True, seeker="brent", duration=25.0)
        seeker = {"measure": measure, "track": False}
        cfg = cfg.model_copy(update={"seeker": cfg.seeker.model_copy(update=seeker)})
        r = run_simulation(cfg)
        p_star = r.user.optimum()[1]
        return max(abs(ev.power - r.user.true_power(ev.candidate)) / p_star for ev in r.evaluations)

    # what is left is τ̂ - τ = -J ė, the error still settling in the first window (the issue
    # measured the same: −0.013 W)
    assert worst("velocity") <= 0.006
    assert worst("desired") > 0.01  # the bias of (13): the power of where the handle was not


def test_perturbation_stops_only_once_theta_has_arrived() -> None:
    # At the default tuning θ approaches w* geometrically; moving less than min_step a period
    # is not arriving (the old rule, four such periods, fired at 3.32 and 3.26 for w* = 3.09).
    from sessions.simulation import run_simulation

    for guess in (3.5, 5.0):
        cfg = parse_session_config(
            {
                "duration": 200.0,
                "rate": 500.0,
                "user": {"kind": "hill"},
                "seeker": {
                    "kind": "perturbation",
                    "bracket": [1.0, guess, 6.0],
                    "track": False,
                    "max_evaluations": 100,
                },
            }
        )
        r = run_simulation(cfg)
        w_star = r.user.w_star()
        assert r.progress.reason == "θ settled"
        marks = [ev.candidate for ev in r.evaluations]
        stop = marks[-1]
        assert abs(stop - w_star) < cfg.seeker.min_step
        # the old rule would have stopped far earlier, well away from w*
        old = next(
            i
            for i in range(4, len(marks))
            if all(abs(marks[j] - marks[j - 1]) < cfg.seeker.min_step for j in range(i - 3, i + 1))
        )
        assert abs(marks[old] - w_star) > 3 * abs(stop - w_star)
        assert r.column("wd")[-1] == pytest.approx(stop, abs=1e-6)  # the dither has faded


def test_the_tracker_follows_an_optimum_that_drifts_20pct_in_120s() -> None:
    from sessions.simulation import run_simulation

    cfg = parse_session_config(
        {
            "duration": 120.0,
            "seed": 3,
            "user": {
                "kind": "hill",
                "noise": 0.02,
                "ripple": 0.05,
                "velocity_fatigue_tau": 40.0,
                "velocity_fatigue_floor": 0.79,
            },
        }
    )
    r = run_simulation(cfg)
    user, sm = r.user, r.summary
    assert sm is not None and sm.t_converged is not None
    drift = 1.0 - user.w_star(t=120.0) / user.w_star(t=0.0)
    assert drift == pytest.approx(0.20, abs=0.005)
    t, wd = r.column("t"), r.column("wd")
    after = t >= sm.t_converged + 5.0  # once wd has reached the setpoint found
    ratio = user.power_ratio(wd[after], t[after])
    assert ratio.min() >= 0.98
    # the optimum found first, and the one at the end, each worth 99 % of the person's then
    first = user.power_ratio(np.array([sm.wd_converged]), np.array([sm.t_converged]))[0]
    end = user.power_ratio(np.array([sm.optimum_w]), np.array([120.0]))[0]
    assert first >= 0.99 and end >= 0.99
    assert sm.optimum_t == pytest.approx(120.0)


def test_tracking_costs_a_steady_user_under_1pct_of_power() -> None:
    from sessions.simulation import run_simulation

    def late_power(track: bool) -> float:
        cfg = parse_session_config(
            {"duration": 90.0, "seed": 2, "user": {"kind": "hill"}, "seeker": {"track": track}}
        )
        r = run_simulation(cfg)
        t, w = r.column("t"), r.column("w")
        late = t >= 30.0
        return float(np.mean(r.user.power_ratio(w[late], t[late])))

    on, off = late_power(True), late_power(False)
    assert off >= 0.99
    assert on >= off - 0.01


def test_the_session_ends_on_the_optimum_it_stores() -> None:
    # The dither explores for what follows it; at the session's end nothing does, and the
    # person's power at the end is at wd. Ended on the dither's extreme, on the side θ erred
    # to, four benchmark people ended below 99 % of p* while the optimum stored for them was
    # above it (docs/benchmarks.md). The track phase fades its dither out over the
    # half-period before the last one: wd ends on the optimum stored, the dither ran till then.
    from sessions.simulation import run_simulation

    for seed in (1, 2, 3):
        cfg = parse_session_config(
            {
                "duration": 60.0,
                "seed": seed,
                "user": {"kind": "hill", "tau0": 3.0, "wmax": 12.0, "noise": 0.04, "ripple": 0.1},
                "seeker": {"kind": "sweep", "bracket": [1.0, 5.0, 8.0]},
            }
        )
        r = run_simulation(cfg)
        sm = r.summary
        assert sm is not None and sm.optimum_w is not None
        t, wd, gamma = r.column("t"), r.column("wd"), r.column("gamma")
        period = cfg.seeker.dither_period
        before = (t >= cfg.duration - 2.5 * period) & (t < cfg.duration - period)
        assert np.ptp(gamma[before]) > 0.01 * sm.optimum_w  # the dither ran until then
        assert wd[-1] == pytest.approx(sm.optimum_w, rel=0.005)


def test_the_tracker_holds_the_optimum_of_a_person_who_tires() -> None:
    # Torque fatigue scales the power and never moves w*: a clean Hill person whose
    # strength falls 33 % in 120 s. The level's exponential trend, fitted as a line in time,
    # leaked into the slope the 0.8 % dither shows: θ walked away from w*, +1.5 % at 30 s and
    # +9 % at the end, each refit's vertex "known" to 0.1 %. The trend's curvature in the
    # model holds θ within 0.2 % from 30 s on.
    from sessions.simulation import run_simulation

    cfg = parse_session_config(
        {
            "duration": 120.0,
            "seed": 3,
            "user": {"kind": "hill", "tau0": 8.0, "wmax": 12.0, "curvature": 0.3,
                     "noise": 0.0, "ripple": 0.0, "fatigue_tau": 300.0},
            "seeker": {"kind": "sweep", "bracket": [1.0, 2.5, 6.0]},
        }
    )  # fmt: skip
    r = run_simulation(cfg)
    sm, w_star = r.summary, r.user.w_star()
    assert sm is not None and sm.t_converged is not None
    assert r.user.w_star(t=120.0) == pytest.approx(w_star)  # w* does not move
    assert sm.t_converged < 20.0
    tracked = [ev.candidate for ev in r.evaluations if ev.t >= 30.0]
    assert len(tracked) > 80
    assert max(abs(v / w_star - 1.0) for v in tracked) <= 0.01


def log_top_table(w_star: float, p_star: float, s: float, beta: float) -> list[list[float]]:
    """A measured-looking curve [w, τ] whose power on a log axis x = ln(w/w*) is
    p*·exp(−|x/s|^β/β): its maximum p* at w* exactly (β = 4: flat-topped; β = 2 with a
    small s: sharp)."""
    w = np.linspace(0.15, 3.2, 60) * w_star
    p = p_star * np.exp(-(np.abs(np.log(w / w_star) / s) ** beta) / beta)
    return [[0.0, float(p[0] / w[0])]] + [
        [float(a), float(b / a)] for a, b in zip(w, p, strict=True)
    ]


@pytest.mark.parametrize("seed", [1, 4, 5])
def test_the_tracker_follows_a_flat_topped_optimum_that_drifts_away(seed: int) -> None:
    # A flat top (99 % band about ±30 %) whose w* falls from 3.0 to 2.45 over the session,
    # with 4 % noise and 12 % ripple. The search once converged on a locate leg's second of
    # rows (a flat top read as the sharpest a person has, σv ≈ 0.6 %) and the tracker, holding
    # that curvature, stayed near 3.7 while w* left: p/p* 0.96 at the end.
    from sessions.simulation import run_simulation, score

    user = {
        "kind": "table",
        "points": log_top_table(3.0, 10.0, 0.65, 4.0),
        "noise": 0.04,
        "ripple": 0.12,
        "velocity_fatigue_floor": 0.72,
        "velocity_fatigue_tau": 110.0,
    }
    cfg = parse_session_config(
        {"duration": 120.0, "seed": seed, "user": user, "seeker": {"bracket": [1.5, 4.6, 6.4]}}
    )
    r = run_simulation(cfg)
    s, sm = score(r), r.summary
    assert s["w_star"] == pytest.approx(
        0.72 * 3.0 + 0.28 * 3.0 * math.exp(-120.0 / 110.0), rel=0.01
    )
    assert sm is not None and sm.t_converged is not None and s["at_bound"] is None
    assert s["power_ratio"] >= 0.98  # where the handle is at the end
    end = r.user.power_ratio(np.array([sm.optimum_w]), np.array([120.0]))[0]
    assert end >= 0.98  # and the optimum stored for the person


def test_the_track_phase_steps_from_the_searchs_last_rows_at_once() -> None:
    # A clean Hill person whose optimum falls 20 % (T = 40 s). The search converges 7.7 %
    # above w* (a parabola's vertex leans to a Hill top's flatter, faster side). The track
    # phase used to wait a whole dither period (6 s) for rows of its own, θ held where the
    # search left it while w* fell: over the 6-12 s after convergence θ was 10.6 % above
    # w*. With the search's last LOOKBACK seconds of rows (their abscissa re-based on the
    # track phase's longer average of the tracking error) its first step comes 2 refits
    # after it starts: 3.3 %.
    from sessions.simulation import run_simulation

    user = {"kind": "hill", "velocity_fatigue_tau": 40.0, "velocity_fatigue_floor": 0.8}
    r = run_simulation(parse_session_config({"duration": 30.0, "seed": 1, "user": user}))
    sm = r.summary
    assert sm is not None and sm.t_converged is not None
    t, gamma = r.column("t"), r.column("gamma")
    window = (t >= sm.t_converged + 6.0) & (t < sm.t_converged + 12.0)  # one dither period
    w_star = np.array([r.user.w_star(t=float(x)) for x in t[window]])
    assert float(gamma[window].mean() / w_star.mean()) <= 1.07


def test_a_small_dither_does_not_read_the_persons_fluctuation_as_a_slope() -> None:
    # A sharp steady person (99 % band about ±5 %) with 5 % noise, the dither held to 1 % of
    # θ. A person pushing harder for a moment speeds the handle up: with the search's
    # one-second average of the tracking error in the rows' abscissa, that fluctuation was a
    # good part of the abscissa's spread under so small a dither, in step with the power's
    # noise, and the slope it read walked θ up: +14 %, +2.4 % and +2.2 % above w* over the
    # track phase on noise seeds 1, 3 and 6 (+6.2 % on average). Averaged over track_memory,
    # θ scatters by about 1 % around w* from one noise seed to the next (six seeds, the
    # RISE default: −0.4 %, +0.3 %, −0.4 %, −0.6 %, −1.7 %, +2.0 %; mean −0.1 %). With the
    # search's curvature shrunk where it saw it at less than 3 standard errors (seed 6: the
    # tracker then holds this sharp top a little flatter, and under a dither held at 1 % its
    # vertices scatter more) seed 6 sits at +5.4 %; the mean, what the walk moved, at +0.5 %.
    from sessions.simulation import run_simulation

    user = {"kind": "table", "points": log_top_table(3.0, 30.0, 0.35, 2.0), "noise": 0.05}
    off = []
    for seed in range(1, 7):
        cfg = parse_session_config(
            {
                "duration": 120.0,
                "seed": seed,
                "user": user,
                "seeker": {"kind": "sweep", "bracket": [1.2, 5.0, 6.0], "dither": 0.01},
            }
        )
        r = run_simulation(cfg)
        sm, w_star = r.summary, r.user.w_star()
        assert w_star == pytest.approx(3.0, rel=0.01)
        assert sm is not None and sm.t_converged is not None
        tracked = np.array([ev.candidate for ev in r.evaluations if ev.t >= sm.t_converged + 10.0])
        assert len(tracked) > 60
        off.append(float(tracked.mean()) / w_star - 1.0)
        assert abs(off[-1]) <= 0.06
        assert r.user.power_ratio(np.array([sm.optimum_w]), np.array([120.0]))[0] >= 0.99
    assert abs(float(np.mean(off))) <= 0.01


@pytest.mark.parametrize("seed", [1, 2])
def test_a_sharp_top_is_within_99pct_of_its_power_from_10_s_on(seed: int) -> None:
    # A sharp top (99 % band ±5 %) with torque fatigue; the start guess outside the band.
    # It took 10-12 s: the first refine pass ran ±15 % around the coarse best point (the
    # curvature unknown), the candidate ran past the pass's end by the filter's lag, and wd
    # came back into the band only after the far end. Now the pass is centred and sized by
    # the smoother of the locate legs' rows, never aims past its end, and its end is pulled
    # in to the band once the top fit shows it.
    from sessions.simulation import run_simulation, score

    user = {
        "kind": "table",
        "points": log_top_table(2.5, 12.0, 0.35, 2.0),
        "noise": 0.03,
        "ripple": 0.1,
        "fatigue_tau": 1200.0,
    }
    cfg = parse_session_config(
        {"duration": 120.0, "seed": seed, "user": user, "seeker": {"bracket": [1.8, 2.9, 5.9]}}
    )
    r = run_simulation(cfg)
    assert r.user.power_ratio(np.array([2.9]), np.array([0.0]))[0] < 0.99
    s = score(r)
    assert s["t_99"] is not None and s["t_99"] <= 10.0


def _lone_tracker(
    theta: float, power: float, curvature: float, noise: tuple[float, float]
) -> Tracker:
    """A tracker at θ (the default sweep's, bracket [1, θ, 6]) on a top of that power and
    curvature whose fit had that noise, with no rows yet."""
    from sessions.seekers.regression import Rows

    bracket = [1.0, theta, 6.0]
    cfg = parse_session_config({"seeker": {"kind": "sweep", "bracket": bracket}}).seeker
    seeker = make_seeker(cfg, 1e-3, 15.0)
    seeker.optimum_power = power
    return Tracker(seeker, theta, curvature, 0.0, Rows(1e-3), noise=noise)


def test_the_dither_grows_while_the_tracker_knows_its_optimum_poorly() -> None:
    # The dither is what shows the slope: while the Kalman filter's σ of θ is k times the
    # precision asked, the amplitude the noise asks for grows k-fold (within the cost cap),
    # rather than staying at what a well-known θ would need (a θ 4 % off a sharp top stayed
    # there for a minute behind a 0.8 % dither).
    from sessions.seekers.tracker import MIN_DITHER, PRECISION

    tracker = _lone_tracker(2.5, 12.0, -30.0, noise=(0.25, 8.0))
    cap = tracker._cap()
    known = tracker._wanted()
    assert MIN_DITHER * 2.5 < known < cap / 2.0  # the noise's, neither floor nor cap
    tracker.var = (2.0 * PRECISION * 2.5) ** 2
    assert tracker._wanted() == pytest.approx(2.0 * known)
    tracker.var = (10.0 * PRECISION * 2.5) ** 2
    assert tracker._wanted() == pytest.approx(cap)


def test_the_track_phase_knows_theta_as_well_as_the_search_knew_its_vertex() -> None:
    # The Kalman filter starts from the search's vertex with that vertex's standard error,
    # not from PRECISION whatever the search saw: a vertex known to 6 % of θ is no 2 % fact,
    # and the filter would take the track phase's first refits as noise. Never better known
    # than PRECISION, and an unknown error (no curvature) is PRECISION.
    from sessions.seekers.regression import Rows
    from sessions.seekers.tracker import PRECISION

    cfg = parse_session_config({"seeker": {"kind": "sweep", "bracket": [1.0, 2.5, 6.0]}}).seeker
    seeker = make_seeker(cfg, 1e-3, 15.0)
    for vertex_se, sd in ((0.15, 0.15), (0.01, PRECISION * 2.5), (None, PRECISION * 2.5),
                          (math.inf, PRECISION * 2.5)):  # fmt: skip
        tracker = Tracker(seeker, 2.5, -30.0, 0.0, Rows(1e-3), vertex_se=vertex_se)
        assert math.sqrt(tracker.var) == pytest.approx(sd)


def _slow_stroke_session(
    user: dict, bracket: list[float], seed: int, seconds: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """(t, wd, γ) of a default session, its start delay, and when the stroke first turned a
    whole revolution after it."""
    from sessions.simulation import run_simulation

    cfg = parse_session_config(
        {"duration": seconds, "seed": seed, "user": user, "seeker": {"bracket": bracket}}
    )
    r = run_simulation(cfg)
    t, q = r.column("t"), r.column("q")
    k0 = int(np.searchsorted(t, cfg.seeker.start_delay))
    turned = float(t[k0 + int(np.searchsorted(q[k0:] - q[k0], 2.0 * math.pi))])
    return t, r.column("wd"), r.column("gamma"), cfg.seeker.start_delay, turned


@pytest.mark.parametrize("seed", [2, 3])
def test_a_slow_strokes_first_leg_climbs_before_a_whole_revolution(seed: int) -> None:
    # A sharp top at w* = 2.9 rad/s and a start guess at 0.55 w*: at that cadence the stroke
    # turns once in 3.8 s after the start delay. The trailing lines waited for a whole
    # revolution's ripple, and the first leg crept up the steep flank at sweep_rate all that
    # time: wd reached 0.9 w* at 6.6 s. From half a revolution on, a climb the lines see
    # speeds the leg up: 5.5 s.
    user = {"kind": "table", "points": log_top_table(2.9, 6.0, 0.38, 2.0), "noise": 0.01,
            "ripple": 0.11}  # fmt: skip
    t, wd, _, _, turned = _slow_stroke_session(user, [1.2, 1.6, 5.2], seed, 8.0)
    assert turned > 5.0  # the premise: a slow stroke
    reached = float(t[np.argmax(wd >= 0.9 * 2.9)])
    assert reached <= 6.0


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_half_a_revolution_turns_no_leg_round(seed: int) -> None:
    # A flat top (99 % band about ±30 %) at w* = 2.1 rad/s, 3.4 % noise, 12 % ripple, the
    # guess at 0.58 w*. Half a revolution's ripple misread part of the stroke as a fall: the
    # first leg turned round at 1.45 rad/s (0.69 w*) 4.6 s in, and the search converged at
    # 35 s. A fall turns a leg only once the ripple is learnt over a whole revolution.
    user = {"kind": "table", "points": log_top_table(2.1, 5.0, 0.6, 4.0), "noise": 0.034,
            "ripple": 0.12}  # fmt: skip
    t, _, gamma, delay, turned = _slow_stroke_session(user, [0.73, 1.22, 3.2], seed, 12.0)
    start = t > delay
    down = np.flatnonzero(start[1:] & (np.diff(gamma) < -1e-9))  # γ moving down: turned
    assert len(down) == 0 or float(t[down[0] + 1]) >= turned


def _stepped(seeker: SweepSeeker, periods: int) -> Iterator[int]:
    """Each period's index, once the candidate has advanced and the filter has stepped
    towards it (the sweep's search outside its decisions)."""
    for k in range(periods):
        seeker._advance_candidate()
        seeker.hold(0.0)
        yield k


def test_a_refine_pass_entering_its_span_never_aims_past_its_far_end() -> None:
    # wd below a pass's span (the locate leg overshot the top): the candidate may run ahead
    # of wd by the filter's lag while it climbs, but not past the span's far end, else the
    # lag carries wd beyond the band the span was sized to (a sharp top's ±5 %) and back.
    from sessions.seekers.sweep import FAST

    cfg = parse_session_config({"seeker": {"kind": "sweep", "bracket": [1.0, 2.0, 6.0]}}).seeker
    seeker = make_seeker(cfg, 1e-3, 15.0)
    seeker.begin(1.8)
    seeker.stage, seeker.span, seeker.direction = "refine", (2.5, 2.8), 1.0
    seeker.rate = cfg.sweep_rate * FAST
    targets, wds = [], []
    for _ in _stepped(seeker, 6000):
        targets.append(seeker.target)
        wds.append(seeker.wd)
    assert max(targets) <= 2.8 + 1e-12
    assert max(wds) <= 2.8 + 1e-9 and wds[-1] > 2.75  # and wd gets there


def test_a_pass_whose_far_end_is_a_bound_ends_when_wd_gets_there() -> None:
    # A pass down to γ1 from well above its span: the candidate is at the bound within a
    # fraction of a second, wd seconds later (the filter's lag). The pass once counted as
    # done when the candidate got there, and so did the next one, every 0.2 s: the search
    # spent all its refine passes within a second and settled on γ1 as its "best estimate"
    # (#2 of the benchmark's seed 16 at sweep_rate 0.2: p/p* 0.33 at the end).
    cfg = parse_session_config({"seeker": {"kind": "sweep", "bracket": [1.0, 2.0, 6.0]}}).seeker
    seeker = make_seeker(cfg, 1e-3, 15.0)
    seeker.begin(3.0)
    seeker.stage, seeker.span, seeker.direction = "refine", (1.0, 1.3), -1.0
    seeker.passes, seeker.best_w = 1, 1.15
    seeker.target = 2.999
    passes = []
    for k in _stepped(seeker, 8000):
        if k % 200 == 199:
            seeker._refine_step(k * 1e-3)
            passes.append((seeker.wd, seeker.passes))
    assert all(n == 1 for wd, n in passes if wd > 1.3)  # outside its span: the same pass
    assert passes[-1][1] >= 2  # and it ends once wd is there


def test_a_search_at_a_faster_sweep_rate_still_ends_at_the_top() -> None:
    # #2 of the benchmark's seed 16 (a sharp top at w* = 3.19, γ1 = 1.22) with sweep_rate
    # 0.2: the passes ending at once at γ1 (above) made the search converge there, and the
    # track phase stayed on the far flank, where the handle's oscillation hides the slope.
    from sessions.simulation import run_simulation, score
    from testing.benchmarks import load

    convergence = load("convergence")
    person = convergence.population(72, 16)[2]
    cfg = convergence.session_config(person, "sweep")
    cfg = cfg.model_copy(update={"seeker": cfg.seeker.model_copy(update={"sweep_rate": 0.2})})
    s = score(run_simulation(cfg))
    assert s["t_converged"] is not None and s["t_converged"] < 30.0
    assert s["power_ratio"] >= 0.99


def test_a_side_a_trailing_line_saw_fall_needs_no_second_proof() -> None:
    # The top fit p = 10 − 4 (w − 3)² over 2.4-3.6 with its vertex inside: the power at the
    # lower end is 14 % below the top at 7.2 standard errors, at the upper end 14 % at only
    # 1.8 (a fast leg crossed it: few rows there). The trailing line had already seen the
    # power fall above (the leg reversed there), so the top is bracketed; the search once
    # asked the quadratic to show that fall again and ran the leg on down the lower flank
    # (a Hill top: to 0.41 w*, converged 4 s later) before its first refine pass.
    from sessions.seekers.regression import Fit, Rows

    cfg = parse_session_config({"seeker": {"kind": "sweep", "bracket": [1.0, 4.0, 6.0]}}).seeker
    seeker = make_seeker(cfg, 1e-3, 15.0)
    rows = Rows(0.02, block=0.02)
    for k, w in enumerate(np.linspace(2.4, 3.6, 120)):
        rows.add(0.02 * k, 0.0, 10.0 - 4.0 * (w - 3.0) ** 2, float(w), float(w))
    seeker.rows, seeker.gate_t = rows, 0.0
    cov = np.array([[0.01, 0.0, 0.0], [0.0, 0.543, 0.507], [0.0, 0.507, 0.5]])
    top = Fit(center=3.0, scale=0.9, coef=np.array([10.0, 0.0, -3.24]), cov=cov,
              ripple=(0.0,) * 4, sigma=0.1, inflate=1.0, misfit=0.0, now=None, n=120,
              w_lo=2.4, w_hi=3.6)  # fmt: skip
    for end, z in ((2.4, 7.2), (3.6, 1.8)):
        drop, se = top.drop(3.0, end)
        assert drop / top.value(3.0) == pytest.approx(0.144, abs=1e-3)
        assert drop / se == pytest.approx(z, abs=0.05)
    seeker.dropped = set()
    assert not seeker._bracketed(top)  # the quadratic alone does not see the upper fall
    seeker.dropped = {"upper"}
    assert seeker._bracketed(top)
    seeker.dropped = {"lower"}  # a side seen is no evidence for the other
    assert not seeker._bracketed(top)


def _tracked_rows(slope: float, sigma: float, seed: int) -> tuple[object, float]:
    """A tracker at θ = 5 after 60 s of a 5 % dither on p = 7 + slope·(w − 5) − 0.15 (w − 5)²
    (a flat top: the optimum at 5 + slope/0.3), with white noise of ``sigma`` W a sample."""
    from sessions.seekers.regression import Rows

    cfg = parse_session_config({"seeker": {"kind": "sweep", "bracket": [1.0, 5.0, 9.0]}}).seeker
    seeker = make_seeker(cfg, 1e-3, 15.0)
    seeker.optimum_power = 7.0
    rows = Rows(1e-3)
    rng = np.random.default_rng(seed)
    t = np.arange(60000) * 1e-3
    w = 5.0 + 0.25 * np.sin(2.0 * math.pi * t / 6.0)
    p = 7.0 + slope * (w - 5.0) - 0.15 * (w - 5.0) ** 2 + sigma * rng.standard_normal(len(t))
    q = np.cumsum(w) * 1e-3  # the handle's angle
    for k in range(len(t)):
        rows.add(float(t[k]), float(q[k]), float(p[k]), float(w[k]), float(w[k]))
    tracker = Tracker(seeker, 5.0, -0.3, 0.0, rows, noise=(sigma / math.sqrt(20.0), 1.0))
    tracker.last_fit = tracker.next_fit = 59.0  # one refit's worth of time: θ moves ≤ 2 %
    return tracker, float(t[-1])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_significant_slope_moves_theta_though_the_vertex_is_unknown(seed: int) -> None:
    # The slope at θ says "slower" at ~4 standard errors, but the vertex (3.5) is known only
    # to ±0.35 (the top is that flat): the Kalman filter took none of the refits' vertices,
    # the Newton fallback asked for one known to 5 % of θ, and θ held while w* left.
    from sessions.seekers.tracker import RATE

    tracker, t = _tracked_rows(-0.45, 2.0, seed)
    tracker.update(t)
    assert tracker.theta < 5.0 - 0.5 * RATE * 5.0  # at least half the most it may move
    assert 3.5 < tracker.x < 5.0  # towards the optimum, not past it


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_no_slope_leaves_theta_where_it_is(seed: int) -> None:
    # The same noise with the optimum at θ: no step is taken on noise.
    tracker, t = _tracked_rows(0.0, 2.0, seed)
    tracker.update(t)
    assert tracker.theta == pytest.approx(5.0, abs=0.02)


def test_the_tracker_follows_a_flat_hill_top_whose_vertex_is_never_known() -> None:
    # A flat Hill top (99 % band about ±14 %) with 4 % noise and 15 % ripple whose w* falls
    # 26 % in 120 s (#8 of the benchmark's seed 15). Every refit's vertex had a standard error
    # of 20-30 % of θ (the top is that flat), so the Kalman filter took none of them and the
    # Newton fallback asked for a vertex known to 5 %: θ held near 4.9 while w* went
    # 4.8 → 3.5 (p/p* 0.973 at the end), though the slope at θ said "slower" at 3-4 standard
    # errors. Now the slope decides when the vertex cannot.
    from sessions.simulation import run_simulation, score

    user = {
        "kind": "hill",
        "tau0": 4.128,
        "wmax": 14.139,
        "curvature": 0.3566,
        "noise": 0.0435,
        "ripple": 0.1488,
        "velocity_fatigue_floor": 0.7039,
        "velocity_fatigue_tau": 55.26,
    }
    cfg = parse_session_config(
        {
            "duration": 120.0,
            "seed": 222376711,
            "user": user,
            "seeker": {"bracket": [2.19, 8.13, 10.44]},
        }
    )
    r = run_simulation(cfg)
    s, sm = score(r), r.summary
    assert s["w_star"] < 0.75 * r.user.w_star(t=0.0)  # the optimum did move
    assert sm is not None and sm.t_converged is not None and s["at_bound"] is None
    assert s["power_ratio"] >= 0.98  # where the handle is at the end
    end = r.user.power_ratio(np.array([sm.optimum_w]), np.array([120.0]))[0]
    assert end >= 0.99  # and the optimum stored for the person


def test_the_dither_spreads_w_more_than_a_sine_for_the_same_excursion() -> None:
    # The person pays the dither's cost at wd's excursion from θ; the slope at θ is seen
    # from how far the rows spread around it. Through the default trajectory filter a sine
    # of amplitude A moves wd by 0.795 A with a variance of exactly half that squared; the
    # tracker's square wave (corners rounded by the filter) moves it by no more, and spreads
    # it more. A full-height square would move wd by 0.967 A: past what the cap was set for.
    from sessions.filters import TrajectoryFilter

    tracker = _lone_tracker(3.0, 10.0, -10.0, noise=(0.5, 2.0))
    a = tracker.amplitude()
    assert 0.01 < a < 0.2  # between the floor and the cap: a dither the fit asked for
    cfg = tracker.owner.cfg
    f = TrajectoryFilter(cfg.filter.order, cfg.filter.pole, 1e-3)
    f.reset(3.0)
    wd = np.empty(60000)
    for k in range(len(wd)):
        f.step(tracker.target(k * 1e-3))
        wd[k] = f.wd
    x = wd[30000:] - 3.0  # five whole periods, long after the ramp-in
    peak = float(np.max(np.abs(x)))
    assert peak <= 0.8 * a  # no farther than a sine of amplitude a through the filter
    assert float(np.mean(x * x)) / peak**2 > 0.54  # a sine's: 0.5


def test_the_searchs_curvature_is_kept_as_well_as_it_was_known() -> None:
    # At θ = 5 with p = 10: the generic top's curvature is −0.8 (sharpness 1). A sharp top's
    # curvature (sharpness 4) known to 10 % or to 30 % is kept as it is; the same known to
    # 40 % (2.5 standard errors) moves towards the generic but stays sharper than half
    # itself; a sharp-looking 16× the generic known to 40 % (sharp-looking noise a stopping
    # rule stopped on) comes within 4× the generic. Always between the two.
    from sessions.seekers.tracker import generic_curvature, shrunk_curvature

    g = generic_curvature(10.0, 5.0)
    assert g == pytest.approx(-0.8)
    sharp = 4.0 * g
    assert shrunk_curvature(sharp, 0.1 * abs(sharp), 10.0, 5.0) == sharp
    assert shrunk_curvature(sharp, 0.3 * abs(sharp), 10.0, 5.0) == sharp
    loose = shrunk_curvature(sharp, 0.4 * abs(sharp), 10.0, 5.0)
    assert 0.5 * sharp > loose > sharp
    noise = shrunk_curvature(16.0 * g, 0.4 * 16.0 * abs(g), 10.0, 5.0)
    assert 4.0 * g < noise < g
    for c, se in ((0.2 * g, 0.1), (3.0 * g, 1.0), (30.0 * g, 10.0)):
        s = shrunk_curvature(c, se, 10.0, 5.0)
        assert min(c, g) <= s <= max(c, g)


def _skewed_points(
    w_star: float, *, peak_power: float | None = None, peak_torque: float | None = None
) -> list[list[float]]:
    """The benchmark's skewed table (`_table` in benchmarks/convergence.py, which tests do
    not import): power steep below w* (s = 0.3 on a log axis) and flat above (s = 0.7),
    60 points from 0.15 w* to 3.2 w* and one at rest; scaled to a peak power or torque."""
    w = np.linspace(0.15, 3.2, 60) * w_star
    x = np.log(w / w_star)
    p = np.exp(-((x / np.where(x < 0.0, 0.3, 0.7)) ** 2) / 2.0)
    if peak_power is not None:
        tau = (peak_power * p) / w
    else:
        assert peak_torque is not None
        tau = peak_torque * (p / w) / (p / w).max()
    return [[0.0, float(tau[0])]] + [[float(a), float(b)] for a, b in zip(w, tau, strict=True)]


def test_a_curvature_the_search_barely_saw_does_not_hold_theta_off_the_top() -> None:
    # A skewed top, steep below w* (s = 0.3 on a log axis) and flat above (s = 0.7): its 99 %
    # band −4 %/+10 % (#67 of the benchmark's seed 21, its curve, noise and seed, steady).
    # The sweep converged at +16 % on rows that never went below +7 %, with a curvature 2.4
    # standard errors from zero and 18× the top's there. Held by the tracker it kept the
    # dither at 1.4 % (the cost cap of so sharp a top) and read every refit's vertex within
    # 1 % of θ: θ stayed 12-16 % above w* to the end, the stored optimum at p/p* 0.984.
    # Shrunk towards a generic top by its standard error, the curvature sizes a 4 % dither
    # and θ comes down.
    from sessions.simulation import run_simulation

    points = _skewed_points(5.5, peak_power=14.5)
    cfg = parse_session_config(
        {
            "duration": 120.0,
            "seed": 1826872875,
            "user": {"kind": "table", "points": points, "noise": 0.06, "ripple": 0.05},
            "seeker": {"kind": "sweep", "bracket": [4.0, 6.84, 10.0]},
        }
    )
    r = run_simulation(cfg)
    sm, w_star = r.summary, r.user.w_star()
    assert w_star == pytest.approx(5.5, rel=0.01)
    assert sm is not None and sm.t_converged is not None
    late = np.array([ev.candidate for ev in r.evaluations if ev.t >= 90.0])
    assert len(late) > 20
    assert float(late.mean()) / w_star - 1.0 <= 0.10
    assert r.user.power_ratio(np.array([sm.optimum_w]), np.array([120.0]))[0] >= 0.99


def test_a_theta_resting_just_inside_a_bound_says_so() -> None:
    # #23 of the benchmark's seed 20: a skewed person (steep below w*) whose w* drifts from
    # 2.11 to 1.79 rad/s, far above the trainer's γ3 = 1.3. θ rested 1 % below γ3 for the
    # last 40 s with the slope at γ3 outward at 4 standard errors, and `at_bound` stayed
    # null: the tracker asked for θ exactly on the bound. The search's own verdict takes the
    # bound within `edge`'s tolerance; so does the tracker's now.
    from sessions.simulation import run_simulation

    points = _skewed_points(2.109, peak_torque=12.0)
    user = {"kind": "table", "points": points, "noise": 0.048, "ripple": 0.175}
    user |= {"velocity_fatigue_tau": 67.7, "velocity_fatigue_floor": 0.816, "fatigue_tau": 1397.0}
    cfg = parse_session_config(
        {
            "duration": 120.0,
            "seed": 1078039919,
            "machine": {"max_velocity": 15.0},
            "user": user,
            "seeker": {"kind": "sweep", "bracket": [0.52, 0.62, 1.3]},
        }
    )
    r = run_simulation(cfg)
    assert r.user.w_star(t=120.0) == pytest.approx(1.787, abs=0.001)  # outside all along
    assert r.summary is not None and r.summary.at_bound == "upper"
    assert r.summary.optimum_w is not None and r.summary.optimum_w >= 1.3 - 0.05
