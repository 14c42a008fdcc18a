"""The workflow's dashboard parts, no browser: units as a browser reads them, the charts'
minimum span, the live phase line, a protocol's fit to the editor's form."""

from __future__ import annotations

import math

import numpy as np

from server.service.session import ActiveSession
from sessions.config import parse_session_config
from sessions.protocol.config import Protocol
from sessions.protocol.stage import Stage
from sessions.store import PhaseRecord
from sessions.worker.ring import INDEX as RING
from sessions.worker.ring import WIDTH as RING_WIDTH
from webui.charts import VELOCITY_SPAN, SpanClass, span_range
from webui.escape import WORD_JOINER
from webui.feed import LiveState
from webui.tabs.phases import phases_markdown, profile_fit, profile_series
from webui.tabs.protocol import fits_form, phase_markdown
from webui.units import Units, power_text

RPM = 60.0 / (2.0 * math.pi)  # independent of sessions.units


def text(markdown: object) -> str:
    """What a reader sees of the escaped markdown (character references decoded)."""
    import html

    return html.unescape(str(markdown)).replace(WORD_JOINER, "").replace("**", "")


def test_velocities_in_the_browsers_unit() -> None:
    w = 3.0902
    assert Units("rpm").v(w) == f"{w * RPM:.1f} rpm" == "29.5 rpm"
    assert Units("rad/s").v(w) == "3.090 rad/s"
    assert Units("rpm").v(None) == Units("rpm").v(math.nan) == "—"
    for unit in ("rpm", "rad/s"):
        u = Units(unit)  # type: ignore[arg-type]
        assert math.isclose(u.to_si(u.from_si(w)), w, rel_tol=1e-4)
    assert math.isclose(Units("rpm").to_si(60.0), 2.0 * math.pi)


def test_power_per_body_mass_only_where_it_is_known() -> None:
    assert power_text(70.0, 70.0) == "70.0 W (1.00 W/kg)"
    assert power_text(70.0, None) == "70.0 W"
    assert power_text(70.0, 0.0) == "70.0 W"  # no mass, no W/kg (never ∞)
    assert power_text(None, 70.0) == "—"


def test_a_steady_signal_gets_the_minimum_span() -> None:
    # the case: a steady 3.095 rad/s with a 1e-4 zigzag
    y = 3.095 + 1e-4 * (-1.0) ** np.arange(200)
    lo, hi = span_range(y, min_span=0.5)
    assert hi - lo >= 0.5 and lo <= y.min() and hi >= y.max()
    # so three ticks across it, at 3 decimals, are three different labels
    ticks = {f"{x:.3f}" for x in np.linspace(lo, hi, 3)}
    assert len(ticks) == 3
    # a range that moves with the data only when the data leaves it
    assert span_range(y + 1e-3, min_span=0.5) == (lo, hi)
    # a wide signal keeps its own range (5 % padded), NaNs ignored
    wide = np.array([0.0, np.nan, 10.0])
    lo, hi = span_range(wide, min_span=0.5)
    assert lo <= -0.5 and 10.5 <= hi < 11.0
    assert span_range(np.full(3, np.nan), min_span=2.0) == (0.0, 2.0)


def stage(**kw: object) -> Stage:
    base: dict[str, object] = {
        "phase": 2, "kind": "train", "name": "train 3", "segment": 1, "role": "work",
        "mode": "track", "start": 30.0, "end": 40.0, "phase_start": 28.0, "phase_end": 70.0,
        "velocity": 3.1, "effort": 1.0, "interval": 1, "intervals": 2, "next_kind": "cooldown",
        "next_name": "cooldown 4",
    }  # fmt: skip
    return Stage(**{**base, **kw})  # type: ignore[arg-type]


def live_state(t: float, st: Stage | None) -> LiveState:
    protocol = {"phases": [{"kind": "warmup", "duration": 3}, {"kind": "seek"},
                           {"kind": "train", "intervals": 2, "work": 10, "rest": 10},
                           {"kind": "cooldown", "duration": 5}]}  # fmt: skip
    cfg = parse_session_config({"protocol": protocol, "duration": 300.0})
    state = LiveState()
    state.active = ActiveSession(session_id=7, user_id=1, cfg=cfg, stage=st)
    rows = np.zeros((1, RING_WIDTH))
    rows[0, RING["t"]], rows[0, RING["session"]] = t, 1
    state.window.extend(rows)
    return state


def test_the_phase_line_says_phase_time_left_and_next() -> None:
    line = text(phase_markdown(live_state(33.5, stage()), Units("rpm")))
    assert line.startswith("Phase train 3 (3/4) · WORK 1/2 · 7 s left in it")
    assert "phase 37 s left" in line and "next: cooldown 4" in line
    assert f"target {3.1 * RPM:.1f} rpm" in line
    assert "target 3.100 rad/s" in text(phase_markdown(live_state(33.5, stage()), Units("rad/s")))
    last = stage(kind="cooldown", name="cooldown 4", role="cooldown", next_kind=None,
                 next_name=None, phase=3, intervals=0)  # fmt: skip
    assert "next: end (at rest)" in text(phase_markdown(live_state(33.5, last), Units()))
    assert text(phase_markdown(LiveState(), Units())) == "Phase: —"


def test_which_protocols_the_form_can_show() -> None:
    def p(*kinds: str) -> Protocol:
        return Protocol.model_validate({"phases": [{"kind": k} for k in kinds]})

    assert fits_form(p("warmup", "seek", "train", "cooldown"))
    assert fits_form(p("seek", "profile", "train"))
    assert not fits_form(p("train", "warmup"))  # another order: runs as stored
    assert not fits_form(p("warmup", "train", "train"))  # a kind twice


def _phase(position: int, kind: str, name: str, **kw: object) -> PhaseRecord:
    base = {"id": position + 1, "session_id": 1, "position": position, "kind": kind,
            "name": name, "t_start": 10.0 * position, "t_end": 10.0 * position + 7.5,
            "planned_end": None, "mean_power": 2.345, "peak_power": 4.5, "work": 17.59,
            "mean_w": 3.0, "optimum_w": None, "detail": {}}  # fmt: skip
    return PhaseRecord.model_validate(base | kw)


def test_each_phases_summary_as_a_table_with_its_bound() -> None:
    evil = "<img src=x onerror=alert(1)>|**b**"
    phases = [
        _phase(0, "warmup", "warm-up"),
        _phase(1, "seek", evil, optimum_w=3.0, at_bound="upper"),
        _phase(2, "train", "", optimum_w=2.5, t_end=None, mean_power=None),
    ]
    out = str(phases_markdown(phases, Units("rad/s")))
    assert "<img" not in out and "|**b**" not in out  # the stored name is text, not markup
    rows = [r for r in text(out).splitlines() if r.startswith("| ") and "---" not in r]
    assert rows[1] == "| 1 | warm-up | warmup | 7.5 | 2.35 | 4.50 | 17.6 | — |"
    assert rows[2] == f"| 2 | {evil.replace('**', '')} | seek | 7.5 | 2.35 | 4.50 | 17.6 | " \
        "≥ 3.000 rad/s (at the upper bound) |"  # fmt: skip
    assert rows[3] == "| 3 | train | train | — | — | 4.50 | 17.6 | 2.500 rad/s |"
    assert "\n\n≥ / ≤: the search ended at the bracket" in out  # after the table, not in it
    inside = text(phases_markdown(phases[:1], Units("rpm")))
    assert "≥" not in inside and "bound" not in inside
    assert text(phases_markdown([], Units())) == "No protocol phases stored for this session."


def test_the_profile_charts_hold_the_fit_and_the_steps_it_was_fitted_to() -> None:
    fit = {
        "model": "linear", "confidence": 0.95,
        "curve": {"w": [0.0, 2.0, 4.0], "tau": [3.0, 2.0, 1.0], "tau_low": [2.8, 1.9, 0.9],
                  "tau_high": [3.2, 2.1, 1.1], "power": [0.0, 4.0, 4.0],
                  "power_low": [0.0, 3.8, 3.6], "power_high": [0.0, 4.2, 4.4]},
        "steps": [{"velocity": 1.0, "w": 1.01, "tau": 2.6, "tau_se": 0.01, "samples": 9},
                  {"velocity": 3.0, "w": 2.98, "tau": 1.4, "tau_se": 0.01, "samples": 9}],
    }  # fmt: skip
    data = profile_series(fit, Units("rpm"))
    x, tau, low, high, measured = data["tau"]
    np.testing.assert_allclose(x, np.array([0.0, 1.01, 2.0, 2.98, 4.0]) * RPM)
    np.testing.assert_array_equal(tau, [3.0, np.nan, 2.0, np.nan, 1.0])
    np.testing.assert_array_equal(low, [2.8, np.nan, 1.9, np.nan, 0.9])
    np.testing.assert_array_equal(high, [3.2, np.nan, 2.1, np.nan, 1.1])
    np.testing.assert_array_equal(measured, [np.nan, 2.6, np.nan, 1.4, np.nan])
    p = data["power"]
    np.testing.assert_allclose(p[4], [np.nan, 2.6 * 1.01, np.nan, 1.4 * 2.98, np.nan])
    np.testing.assert_array_equal(p[1], [0.0, np.nan, 4.0, np.nan, 4.0])
    fit_phase = _phase(0, "profile", "spectrum", detail={"profile": fit})
    assert profile_fit([fit_phase, _phase(1, "cooldown", "cool")]) == (fit_phase, fit)
    failed = _phase(0, "profile", "spectrum", detail={"profile": None, "profile_error": "x"})
    assert profile_fit([failed]) is None


def test_a_time_chart_gets_its_minimum_span_from_an_invisible_series() -> None:
    # the steady 3.095 rad/s with a 1e-4 zigzag: the span series holds a range at
    # least 0.5 wide around it (uPlot's auto range takes it in), whose three ticks are three
    # different labels; it stays put while the signal stays in it
    span = SpanClass(VELOCITY_SPAN)
    t = np.arange(200) * 0.02
    steady = 3.095 + 1e-4 * (-1.0) ** np.arange(200)
    x, a, _, pad = span.pad(t, steady, steady + 2e-4)
    assert x is t and a is steady and len(pad) == len(t)
    lo, hi = pad[0], pad[-1]
    assert np.isnan(pad[1:-1]).all()
    assert hi - lo >= VELOCITY_SPAN and lo <= steady.min() and hi >= steady.max() + 2e-4
    assert len({f"{v:.3f}" for v in np.linspace(lo, hi, 3)}) == 3
    for k in range(50):  # frames of the same steady signal: the same range
        assert span.pad(t, steady + 1e-5 * k)[-1][[0, -1]].tolist() == [lo, hi]
    # it drifts out of its range, still steady: a new range around it
    moved = span.pad(t, steady + 0.4)[-1]
    assert moved[0] <= steady.min() + 0.4 and moved[-1] >= steady.max() + 0.4 > hi
    # a wide signal: uPlot's own range; the span series holds the data's own extent (inside
    # that range, so it changes nothing) and starts finite (a NaN first point breaks uPlot)
    wide = np.concatenate(([np.nan], np.linspace(0.0, 3.0, 199)))
    pad = span.pad(t, wide)[-1]
    assert span.fixed is None and (pad[0], pad[-1]) == (0.0, 3.0)
    # steady again: the minimum span again
    pad = span.pad(t, np.full(200, 1.2))[-1]
    assert pad[-1] - pad[0] >= VELOCITY_SPAN and pad[0] < 1.2 < pad[-1]
    # nothing to range (an empty chart's NaN pair): NaN, and the class stays
    assert np.isnan(span.pad(np.array([0.0, 1.0]), np.full(2, np.nan))[-1]).all()
    assert span.fixed is not None


def test_the_live_charts_send_the_span_as_data_never_as_scales() -> None:
    # the frame's message is the data alone (its span series included): the charts' scales
    # are never assigned, so viser's client never rebuilds them
    import viser

    from sessions.telemetry import RECORD_INDEX, RECORD_WIDTH
    from webui.charts import LiveCharts, LiveWindow

    srv = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        charts, window = LiveCharts(srv.gui), LiveWindow(seconds=1.0)
        handles = (charts.velocity, charts.torque, charts.power, charts.passivity)
        scales = [h.scales for h in handles]
        spans: list[tuple[float, float] | None] = []
        for k in range(300):  # 6 s at 50 samples/s: steady, wide, steady
            t = 0.02 * k
            w = 2.0 + math.sin(2 * math.pi * t) if 2.0 <= t < 4.0 else 3.095 + 1e-4 * (-1) ** k
            rec = np.zeros((1, RECORD_WIDTH))
            rec[0, [RECORD_INDEX["t"], RECORD_INDEX["w"], RECORD_INDEX["wd"]]] = t, w, w
            rec[0, RECORD_INDEX["session"]] = 1.0
            window.extend(rec)
            charts.show(window)
            data = charts.velocity.data
            assert len(data) == 4 and len(data[3]) == len(data[0])  # t, wd, w, span
            fixed = charts.spans["velocity"].fixed
            if not spans or spans[-1] != fixed:
                spans.append(fixed)
        assert [h.scales for h in handles] == scales  # never assigned
        assert len(spans) == 3 and spans[1] is None  # fixed, uPlot's own, fixed again
    finally:
        srv.stop()


def test_a_countdown_never_starts_above_its_segments_length() -> None:
    # the stage's event (work 30-40 s) came before its first telemetry row: the last row is
    # still at 29.2 s, yet the work interval has 10 s left at most (it read 11)
    line = text(phase_markdown(live_state(29.2, stage()), Units()))
    assert "WORK 1/2 · 10 s left in it" in line, line
    assert "phase 40 s left" in line  # counted from the same moment: the stage has begun
