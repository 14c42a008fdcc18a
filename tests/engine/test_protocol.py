"""Session protocols in simulation: the runner drives the reference phase after phase through
the same loop as the live worker, and every session ends at rest.

Independent truth: the protocol as configured (phase kinds, durations, velocities), physical
invariants (at rest: w = 0 and, the person relaxed, u = 0; a reference that never jumps), the
seeker alone (a seek phase passes its reference through untouched), the first-order response
in closed form, and the Hill person's own parameters for the profile phase.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from sessions.config import MachineConfig, ScenarioError, SessionConfig, parse_session_config
from sessions.loop import Loop
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.protocol.analysis import phase_spans, summarize_phase
from sessions.protocol.config import REST_VELOCITY, STOP_DECELERATION, Protocol
from sessions.protocol.cues import CuedPerson
from sessions.requests import RequestError, Rig, SessionStart, session_config
from sessions.simulation import SimulationResult, run_simulation

HILL = {"kind": "hill", "tau0": 3.0, "wmax": 10.0, "curvature": 0.25}
FULL = {
    "name": "full",
    "phases": [
        {"kind": "warmup", "duration": 10.0, "ramp": 4.0},
        {"kind": "seek", "duration": 120.0, "hold": 3.0},
        {"kind": "train", "intervals": 2, "work": 10.0, "rest": 10.0, "countdown": 3.0},
        {"kind": "cooldown", "duration": 8.0, "hold": 2.0},
    ],
}


def session(protocol: dict, seed: int = 2, **over: object) -> SessionConfig:
    return parse_session_config(
        {"seed": seed, "user": {**HILL, "noise": 0.03}, "protocol": protocol, **over}
    )


def columns(r: SimulationResult) -> dict[str, np.ndarray]:
    return {n: r.column(n) for n in ("t", "q", "w", "wd", "ad", "u", "tau", "W", "gamma")}


@pytest.fixture(scope="module")
def full() -> SimulationResult:
    return run_simulation(session(FULL))


def test_a_full_protocol_ends_at_rest_with_zero_torque(full: SimulationResult) -> None:
    c = columns(full)
    last = c["t"] >= c["t"][-1] - 0.5  # the last half second: still, relaxed
    assert np.abs(c["w"][last]).max() < REST_VELOCITY
    assert np.abs(c["wd"][last]).max() < REST_VELOCITY
    assert np.abs(c["u"][last]).max() < 0.02  # N·m: nothing to hold once the person relaxes
    assert full.stages[-1].role == "relax" and full.cfg.protocol is not None
    assert c["t"][-1] < full.cfg.duration  # it ended by itself, before the session's cap


def test_the_phases_are_the_protocols(full: SimulationResult) -> None:
    end = float(full.column("t")[-1]) + full.cfg.dt
    spans = phase_spans(full.stages, end, full.progress.target)
    assert [s.kind for s in spans] == ["warmup", "seek", "train", "cooldown"]
    warm, seek, train, cool = spans
    assert warm.start == 0.0 and warm.end == pytest.approx(10.0)
    assert seek.end - seek.start < 120.0  # converged, then held 3 s
    assert full.progress.done
    assert train.end - train.start == pytest.approx(3.0 + 2 * (10.0 + 10.0))
    assert cool.end - cool.start >= 8.0 + 2.0
    roles = [st.role for st in train.stages]
    assert roles == ["countdown", "work", "rest", "countdown", "work", "rest"]
    # phases touch: each ends where the next begins
    assert all(a.end == b.start for a, b in itertools.pairwise(spans))


def test_training_tracks_the_optimum_and_rests_slowly(full: SimulationResult) -> None:
    # tracking on (the default; the seeker's track phase, issue 14): each work interval's
    # reference is the seeker's target, which follows the optimum; it must stay where the
    # person's true power is within 2 % of their best (the Hill person's own closed form)
    c = columns(full)
    end = float(c["t"][-1]) + full.cfg.dt
    train = next(s for s in phase_spans(full.stages, end) if s.kind == "train")
    assert full.progress.tracking
    rho = full.cfg.seeker.rho
    w_star, p_star = full.user.optimum(rho)
    for st in train.stages:
        window = (c["t"] >= st.end - 3.0) & (c["t"] < st.end)  # the settled end of each stretch
        mean_w = float(c["w"][window].mean())
        at_end = float(c["w"][np.searchsorted(c["t"], st.end) - 1])
        if st.role == "work":
            during = (c["t"] >= st.start) & (c["t"] < st.end - 0.01)
            gamma = c["gamma"][during]
            assert np.ptp(gamma) > 1e-3  # tracked: the target (the tracker's dither) moved
            assert mean_w == pytest.approx(float(c["wd"][window].mean()), rel=0.02)
            assert full.user.true_power(mean_w, rho) >= 0.98 * p_star
            assert st.velocity == pytest.approx(w_star, rel=0.1)
        elif st.role == "countdown":  # brings the handle up to speed before the work
            assert at_end == pytest.approx(w_star, rel=0.1)
        elif st.role == "rest":
            assert mean_w == pytest.approx(1.0, abs=0.05)  # the rest velocity
    summary = summarize_phase(c, train)
    works = summary.detail["intervals"]
    assert [w["interval"] for w in works] == [1, 2]
    assert all(w["mean_power"] > 2 * summary.mean_power / 3 for w in works)


def test_training_without_tracking_holds_the_optimum_found() -> None:
    protocol = {**FULL, "phases": [dict(p) for p in FULL["phases"]]}
    protocol["phases"][2]["track"] = False
    r = run_simulation(session(protocol))
    c = columns(r)
    end = float(c["t"][-1]) + r.cfg.dt
    train = next(s for s in phase_spans(r.stages, end) if s.kind == "train")
    found = train.optimum
    assert found is not None
    for st in (s for s in train.stages if s.role == "work"):
        during = (c["t"] >= st.start) & (c["t"] < st.end - 0.01)
        window = (c["t"] >= st.end - 3.0) & (c["t"] < st.end)
        assert st.velocity == pytest.approx(found)
        assert np.ptp(c["gamma"][during]) < 1e-9  # held, not tracked
        assert float(c["w"][window].mean()) == pytest.approx(found, rel=0.02)


@pytest.mark.parametrize(
    ("after", "ends_at"),
    [
        ({"kind": "cooldown", "duration": 8.0}, 40.0),
        ({"kind": "train", "intervals": 1, "work": 10.0, "rest": 10.0, "track": False}, 40.0),
        ({"kind": "train", "intervals": 1, "work": 10.0, "rest": 10.0}, math.inf),
    ],
    ids=["cooldown", "train-held", "train-tracked"],
)
def test_a_seek_phase_ends_on_its_optimum_unless_training_tracks_it_on(
    after: dict, ends_at: float
) -> None:
    # the track phase fades its dither out before the seeker's reference is taken from it
    # (test_seekers: the session ends on the optimum it stores): at a protocol's seek phase's
    # end, unless the training after it goes on following the optimum (its dither learning)
    phases = [{"kind": "seek", "duration": 40.0, "until_converged": False}, after]
    loop = Loop(session({"name": "seek", "phases": phases}))
    loop.begin(0.0, 0.0)
    assert loop.seeker.ends_at == ends_at
    r = run_simulation(session({"name": "seek", "phases": phases}))
    c = columns(r)
    seek = next(s for s in phase_spans(r.stages, float(c["t"][-1])) if s.kind == "seek")
    at_end = np.searchsorted(c["t"], seek.end) - 1
    found = next(st.optimum for st in r.stages if st.phase == 1)  # as the next phase began
    assert found is not None
    if math.isinf(ends_at):  # the dither still on where training takes over
        window = (c["t"] >= seek.end - 3.0) & (c["t"] < seek.end)
        assert np.ptp(c["gamma"][window]) > 0.01 * found
    else:
        assert c["wd"][at_end] == pytest.approx(found, rel=0.005)


def test_the_reference_never_jumps_between_phases(full: SimulationResult) -> None:
    # the hand-over from the seeker's reference to the runner's keeps wd, ad continuous
    wd, ad = full.column("wd"), full.column("ad")
    assert np.abs(np.diff(wd)).max() < 0.01  # rad/s per period
    assert np.abs(np.diff(ad)).max() < 0.02  # rad/s² per period


def test_a_seek_phase_is_the_seeker_alone() -> None:
    # without a protocol the session is one seek phase: the loop with the runner gives,
    # sample for sample, what the loop gives with the seeker as its reference
    cfg = parse_session_config({"duration": 20.0, "seed": 4, "user": {**HILL, "noise": 0.03}})
    rows = []
    for bare in (False, True):
        loop, plant = Loop(cfg), Plant(cfg.machine.inertia)
        user = SimulatedUser(cfg.user, cfg.dt, cfg.seed)
        if bare:
            loop.reference = loop.seeker  # type: ignore[assignment]
            calls = list(loop._calls)
            calls[-1] = loop.seeker.tell
            loop._calls = tuple(calls)
        loop.begin(0.0, 0.0)
        out = []
        for _ in range(round(cfg.duration * cfg.rate)):
            u = loop.step(plant.q, plant.w, plant.sample_torque(user))
            out.append(loop.row)
            plant.advance(u, cfg.dt, user)
            user.advance(cfg.dt)
        rows.append(np.array(out))
    np.testing.assert_array_equal(rows[0], rows[1])


def test_wind_down_brings_the_handle_to_rest_under_control() -> None:
    cfg = session({"phases": [{"kind": "seek", "duration": 60.0, "until_converged": False}]})
    loop, plant = Loop(cfg), Plant(cfg.machine.inertia)
    person = CuedPerson(SimulatedUser(cfg.user, cfg.dt, cfg.seed), loop.reference, cfg.dt)
    loop.begin(0.0, 0.0)
    rows = []
    for k in range(round(60.0 / cfg.dt)):
        if k == 30_000:  # mid-phase, at the optimum: a stop is asked for
            loop.wind_down()
        u = loop.step(plant.q, plant.w, plant.sample_torque(person))
        rows.append((*loop.row, loop.stage))
        plant.advance(u, cfg.dt, person)
        person.advance(cfg.dt)
        if loop.finished:
            break
    r = np.array(rows)
    after = r[30_001:]
    assert loop.finished and np.all(after[:, -1] == 1)  # the runner's stop phase
    assert np.all(np.diff(after[:, 3]) <= 1e-12)  # wd only falls
    assert after[:, 4].min() >= -STOP_DECELERATION * (1 + 1e-6)
    assert abs(r[-1, 2]) < REST_VELOCITY and abs(r[-1, 5]) < 0.02
    # from ~3 rad/s: the ramp at the stop's deceleration, the filter's lag, the rest hold
    assert len(after) * cfg.dt < r[30_000, 3] / STOP_DECELERATION + 4.0


@pytest.mark.parametrize("order", [3, 4])
def test_a_stop_asked_while_the_handle_speeds_up_never_speeds_it_up_further(order: int) -> None:
    """The trainer stops while the search drives the handle up its steepest: from that period
    on wd only falls (the filter's momentum does not carry the handle faster), and it comes
    to rest. Bumpless adoption of a rising reference let wd climb on for the filter's lag."""
    cfg = session(
        {"phases": [{"kind": "seek", "duration": 60.0, "until_converged": False}]},
        seeker={"kind": "sweep", "bracket": (1.0, 1.5, 8.0), "filter": {"order": order}},
    )
    loop, plant = Loop(cfg), Plant(cfg.machine.inertia)
    person = CuedPerson(SimulatedUser(cfg.user, cfg.dt, cfg.seed), loop.reference, cfg.dt)
    loop.begin(0.0, 0.0)
    wd, ad, asked = [], [], None
    for k in range(round(60.0 / cfg.dt)):
        if asked is None and k * cfg.dt > 3.0 and loop.value("ad") > 0.3:
            asked = k  # climbing fast towards an optimum far above the guess
            loop.wind_down()
        u = loop.step(plant.q, plant.w, plant.sample_torque(person))
        wd.append(loop.value("wd"))
        ad.append(loop.value("ad"))
        plant.advance(u, cfg.dt, person)
        person.advance(cfg.dt)
        if loop.finished:
            break
    assert asked is not None and loop.finished
    after = np.array(wd[asked:])
    assert np.all(np.diff(after) <= 1e-12), f"wd rose by {after.max() - after[0]:.3f} rad/s"
    assert np.array(ad[asked + 1 :]).max() <= 1e-9  # the row of the asked period: as it ran
    assert abs(wd[-1]) < REST_VELOCITY


def test_a_cued_person_follows_the_effort_as_a_first_order_response() -> None:
    class Cue:
        effort = 1.0

    cue, dt = Cue(), 1e-3
    person = CuedPerson(SimulatedUser(parse_session_config({}).user, dt, 1), cue, dt)
    base = person.person.torque(0.0, 2.0)
    cue.effort = 0.0  # relax
    for _ in range(300):
        person.advance(dt)
    scale = person.torque(0.0, 2.0) / person.person.torque(0.0, 2.0)
    assert scale == pytest.approx(math.exp(-0.3 / 0.3), rel=1e-9)  # 300 ms = one time constant
    assert base > 0 and person.w_star() == person.person.w_star()  # the truth is the person's


def test_the_profile_phase_recovers_a_hill_persons_parameters() -> None:
    # 3 % band-limited noise, RISE's τ̂ (28) through the closed loop: the stated tolerances
    # are τ0 and wmax within 5 %, w* within 2 % (docs/protocols.md), each for three seeds
    protocol = {"phases": [
        {"kind": "profile", "count": 8, "hold": 6.0, "velocities": [1.0, 6.0]},
        {"kind": "cooldown", "duration": 4.0},
    ]}  # fmt: skip
    for seed in (1, 2, 3):
        r = run_simulation(session(protocol, seed=seed, seeker={"bracket": [1.0, 3.5, 6.5]}))
        end = float(r.column("t")[-1]) + r.cfg.dt
        span = phase_spans(r.stages, end)[0]
        assert span.kind == "profile" and len(span.stages) == 8
        fit = summarize_phase(columns(r), span).profile
        assert fit is not None, seed
        w_star = r.user.w_star()
        assert fit.tau0.value == pytest.approx(3.0, rel=0.05), seed
        assert fit.wmax.value == pytest.approx(10.0, rel=0.05), seed
        assert fit.w_opt.value == pytest.approx(w_star, rel=0.02), seed
        # (the intervals' coverage is tests/engine/test_profile.py's, over 100 sessions)


@pytest.mark.parametrize(
    ("protocol", "key", "reason"),
    [
        ({"phases": [{"kind": "cooldown"}, {"kind": "seek"}]}, "protocol", "must be last"),
        ({"phases": [{"kind": "seek"}, {"kind": "seek"}]}, "protocol", "at most one seek"),
        ({"phases": [{"kind": "train", "rest": 2.0, "countdown": 3.0}]}, "countdown", "longer"),
        ({"phases": [{"kind": "warmup", "duration": 5, "ramp": 9}]}, "ramp", "longer"),
        ({"phases": [{"kind": "sprint"}]}, "protocol.phases.0", "sprint"),
        ({"phases": [{"kind": "seek", "speed": 3}]}, "speed", "unknown key"),
        ({"phases": []}, "protocol.phases", "at least 1"),
        ({"phases": [{"kind": "train", "velocity": 7.0}]}, "velocity", "upper bound γ3"),
        ({"phases": [{"kind": "profile", "velocities": [4, 2]}]}, "velocities", "increasing"),
    ],
)
def test_a_bad_protocol_is_refused_naming_the_field(protocol: dict, key: str, reason: str) -> None:
    with pytest.raises(Exception) as err:
        parse_session_config({"protocol": protocol})
    assert key in str(err.value) and reason in str(err.value)


def test_the_duration_is_the_protocols_unless_given_and_never_shorter() -> None:
    cfg = session(FULL)
    assert cfg.duration == math.ceil(Protocol.model_validate(FULL).longest((1.0, 6.0), 15.0))
    with pytest.raises(ScenarioError, match="duration: 60 s is shorter than the protocol"):
        session(FULL, duration=60.0)
    again = SessionConfig.model_validate(cfg.model_dump())  # as stored and read back
    assert again == cfg


def test_a_trainers_request_with_a_protocol() -> None:
    rig = Rig("sim", MachineConfig(), 1000.0, has_torque_sensor=True)
    req = SessionStart(user_id=1, protocol=Protocol.model_validate(FULL))
    cfg = session_config(req, rig, optimum=3.0)
    lo, mid, hi = cfg.seeker.bracket
    assert (lo, mid, hi) == pytest.approx((1.8, 3.0, 4.5))  # around the stored optimum
    assert cfg.duration == math.ceil(cfg.protocol.longest((lo, hi), 15.0))  # type: ignore[union-attr]
    with pytest.raises(RequestError) as err:  # a given duration must let it finish
        session_config(req.model_copy(update={"duration": 60.0}), rig)
    assert err.value.field == "duration"
    fast = {"phases": [{"kind": "warmup", "velocity": 5.0}]}  # above 1.5 × the optimum
    with pytest.raises(RequestError) as err:
        session_config(SessionStart(user_id=1, protocol=fast), rig, optimum=3.0)
    assert err.value.field == "protocol.phases.0.velocity" and "γ3" in err.value.reason
    with pytest.raises(RequestError) as err:  # a template is resolved by the caller, or refused
        session_config(SessionStart(user_id=1, template_id=3), rig)
    assert err.value.field == "template_id"


@pytest.mark.parametrize(("bracket", "side"), [([1.0, 2.0, 3.0], "upper"), ([5.0, 7.0, 9.0], None)])
def test_a_seek_phase_that_ends_at_the_brackets_edge_says_so(
    bracket: list[float], side: str | None
) -> None:
    # a Hill person with w* = 7.7 rad/s (their own closed form): above [1, 3] the seek phase
    # ends on the upper edge and its stored summary says so; inside [5, 9] it ends on the peak
    # and says nothing. Phases that do not seek never carry a bound.
    user = {"kind": "hill", "tau0": 3.0, "wmax": 7.7 / 0.30902}
    protocol = {"phases": [{"kind": "warmup", "duration": 2.0},
                           {"kind": "seek", "duration": 90.0, "hold": 0.5},
                           {"kind": "cooldown", "duration": 2.0}]}  # fmt: skip
    r = run_simulation(session(protocol, user=user, seeker={"bracket": bracket}, rate=500.0,
                               machine={"max_velocity": 12.0}))  # fmt: skip
    w_star, _ = r.user.optimum(r.cfg.seeker.rho)
    assert w_star == pytest.approx(7.7, rel=1e-3) and (w_star > bracket[2]) == (side is not None)
    end = float(r.column("t")[-1]) + r.cfg.dt
    spans = phase_spans(r.stages, end, r.progress.target, r.progress.at_bound)
    warm, seek, cool = (summarize_phase(columns(r), s) for s in spans)
    assert seek.end - seek.start < 90.0  # it ended by itself: at the edge, or on the peak
    assert (warm.at_bound, seek.at_bound, cool.at_bound) == (None, side, None)
    assert seek.export_phase().at_bound == side
    if side == "upper":
        assert seek.optimum_w == pytest.approx(bracket[2], rel=0.03)
    else:
        assert seek.optimum_w == pytest.approx(w_star, rel=0.06)


def test_each_work_intervals_onset_is_no_slope_to_the_tracker() -> None:
    # Between work intervals the tracker is paused; when the work begins the person's effort
    # comes back from rest within a second, far more than the dither moves the power, and
    # that step, lined up with one side of the dither, read as a slope: θ ran 19 % above w*
    # over the first interval. The rows of the first seconds after a pause are left out.
    protocol = {**FULL, "phases": [dict(p) for p in FULL["phases"]]}
    protocol["phases"][2] = {
        "kind": "train", "intervals": 5, "work": 10.0, "rest": 8.0, "countdown": 3.0,
    }  # fmt: skip
    r = run_simulation(session(protocol))
    c = columns(r)
    end = float(c["t"][-1]) + r.cfg.dt
    train = next(s for s in phase_spans(r.stages, end) if s.kind == "train")
    w_star, _ = r.user.optimum(r.cfg.seeker.rho)
    works = [s for s in train.stages if s.role == "work"]
    assert len(works) == 5
    for st in works:
        late = (c["t"] >= st.end - 3.0) & (c["t"] < st.end)
        assert float(c["wd"][late].mean()) == pytest.approx(w_star, rel=0.1)
