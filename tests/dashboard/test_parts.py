"""The dashboard's data plumbing, no browser: the bounded live window, arrays made safe for
viser's uPlot, the seeker's progress from event frames, the event log lines."""

from __future__ import annotations

import html
import math
from datetime import UTC, datetime

import numpy as np
import pytest

from sessions.config import parse_session_config
from sessions.store import SessionRecord, UserRecord
from sessions.worker.ring import INDEX as RING
from sessions.worker.ring import WIDTH as RING_WIDTH
from webui.charts import (
    LIVE,
    SAMPLE_RATE,
    WINDOW_S,
    LiveWindow,
    lead_finite,
    plottable,
    seeker_data,
    seeker_range,
    seeker_x_range,
)
from webui.escape import WORD_JOINER
from webui.feed import describe_event
from webui.progress import SeekerProgressView
from webui.tabs.history import session_markdown, sessions_table
from webui.units import Units


def ring_rows(t: np.ndarray, session: int = 1) -> np.ndarray:
    rows = np.zeros((len(t), RING_WIDTH))
    rows[:, RING["t"]] = t
    rows[:, RING["w"]] = np.sin(t)
    rows[:, RING["u_out"]] = -t
    rows[:, RING["session"]] = session
    return rows


def test_the_live_window_keeps_the_last_ten_seconds_and_at_most_500_points() -> None:
    assert WINDOW_S == 10.0  # the documented window
    win = LiveWindow()  # the dashboard's: WINDOW_S of a SAMPLE_RATE subscription
    dt = 1.0 / SAMPLE_RATE
    for start in range(0, 30, 2):  # 30 s at the live window's rate, in 2 s batches
        win.extend(ring_rows(np.arange(start, start + 2, dt)))
    t = win.rows[:, LIVE["t"]]
    assert t[-1] == win.last[LIVE["t"]]
    # the whole window, not a part of it: the last WINDOW_S seconds, every sample of them
    assert t[-1] - t[0] == pytest.approx(WINDOW_S, abs=dt + 1e-9)
    assert len(t) == pytest.approx(WINDOW_S * SAMPLE_RATE, abs=1)
    t_chart, w_chart = win.series("t", "w")
    assert len(t_chart) <= 500
    assert t_chart[-1] == t[-1]  # the newest sample is always drawn
    assert np.all(np.diff(t_chart) > 0)
    np.testing.assert_allclose(w_chart, np.sin(t_chart))


def test_a_new_session_starts_the_window_afresh() -> None:
    win = LiveWindow()
    win.extend(ring_rows(np.arange(0, 5, 0.02), session=1))
    win.extend(ring_rows(np.arange(0, 1, 0.02), session=2))
    assert set(win.rows[:, LIVE["session"]]) == {2}
    assert win.rows[0, LIVE["t"]] == 0.0
    mixed = np.concatenate(
        (ring_rows(np.arange(1, 2, 0.02), 2), ring_rows(np.arange(0, 1, 0.02), 3))
    )
    win.extend(mixed)
    assert set(win.rows[:, LIVE["session"]]) == {3}


def test_arrays_for_upLot_never_empty_never_led_by_nan() -> None:
    x, y = plottable((np.zeros(0), np.zeros(0)))
    assert len(x) == 2 and np.all(np.isnan(y))  # a chart given zero points never redraws
    col = np.array([np.nan, np.nan, 2.0, np.nan, 3.0])
    np.testing.assert_array_equal(lead_finite(col)[:3], [2.0, 2.0, 2.0])
    assert math.isnan(lead_finite(col)[3])  # inner gaps stay (uPlot joins around them)
    np.testing.assert_array_equal(lead_finite(np.full(3, np.nan)), np.zeros(3))


def test_the_seeker_chart_data() -> None:
    evs = [(3.47, 2.847), (3.28, 2.860), (3.07, 2.865)]
    x, measured, best, bracket = seeker_data(evs, (1.0, 6.0), (3.07, 2.865))
    np.testing.assert_array_equal(x, [1.0, 3.07, 3.28, 3.47, 6.0])
    np.testing.assert_array_equal(measured[1:4], [2.865, 2.860, 2.847])
    assert np.isnan(measured[[0, 4]]).all()
    assert best[1] == 2.865 and np.isnan(best[[0, 2, 3, 4]]).all()
    assert bracket[0] == bracket[4] == 2.847
    lo, hi = seeker_range(evs)
    assert lo < 2.847 and hi > 2.865


def test_seeker_progress_from_event_frames() -> None:
    cfg = parse_session_config({"seeker": {"kind": "brent", "bracket": [1.0, 3.5, 6.0]}})
    view = SeekerProgressView()
    view.reset(7, cfg)
    assert view.bracket == (1.0, 6.0) and view.fraction == 0.0 and view.target == 3.5
    frame = {"type": "seeker", "session_id": "7", "session_t": 3.6, "candidate": 3.47,
             "power": 2.847, "target": 3.28, "done": False}  # fmt: skip
    view.add(frame)
    view.add(frame)  # the same evaluation from the store and from the event: once
    view.add({**frame, "session_t": 6.0, "candidate": 3.28, "power": 2.86, "target": 3.07})
    view.add({**frame, "session_t": 8.3, "candidate": 3.07, "power": 2.865, "target": 2.69})
    assert len(view.evaluations) == 3
    # Without the worker's bracket: the nearest candidates around the best, within γ1..γ3.
    assert view.bracket == (1.0, 3.28)
    assert 0.0 < view.fraction < 1.0
    expected = math.log(5.0 / 2.28) / math.log(5.0 / 0.1)  # Seeker.fraction's rule
    assert math.isclose(view.fraction, expected)
    # With it: the worker's figures win.
    view.add({**frame, "session_t": 9.9, "candidate": 2.69, "power": 2.842, "target": 3.11,
              "bracket_lo": 2.69, "bracket_hi": 3.28, "fraction": 0.4})  # fmt: skip
    assert view.bracket == (2.69, 3.28) and view.fraction == 0.4
    view.add({**frame, "session_t": 14.2, "candidate": 3.11, "power": 2.8648, "target": 3.101,
              "done": True})  # fmt: skip
    assert view.fraction == 1.0
    assert "Optimum: 3.101 rad/s** (converged)" in text_of(view.describe())


def text_of(markdown: str | None) -> str:
    """What a reader sees of escaped inline markdown (its character references decoded)."""
    assert markdown is not None
    return html.unescape(markdown).replace(WORD_JOINER, "")


def test_event_log_lines() -> None:
    assert text_of(describe_event({"type": "event", "kind": "estop"})).startswith("E-STOP")
    line = describe_event({"type": "session_finished", "session_id": 4, "status": "completed"})
    assert text_of(line) == "session #4 ended: completed"
    assert describe_event({"type": "event", "kind": "timing"}) is None
    # A device's fault text is escaped like any stored string.
    fault = describe_event({"type": "event", "kind": "fault", "reason": "<img src=x onerror=1>"})
    assert "<" not in str(fault) and text_of(fault) == "fault: <img src=x onerror=1>"


def test_the_seeker_chart_shows_every_candidate_and_the_bracket() -> None:
    evs = [(3.47, 2.847), (3.28, 2.860), (2.85, 2.856)]
    lo, hi = seeker_x_range(evs, (3.03, 3.10))
    assert lo < 2.85 and hi > 3.47
    lo, hi = seeker_x_range([], (1.0, 6.0))
    assert lo < 1.0 and hi > 6.0


def _record(**search: object) -> SessionRecord:
    search = {"converged": False} | search
    return SessionRecord(
        id=7, user_id=1, account_id=None, backend="simulation",
        config={"seeker": {"kind": "sweep"}, "controller": {"kind": "rise"}},
        status="completed", started_at=datetime(2026, 12, 1, 12, tzinfo=UTC), ended_at=None,
        seeker="sweep", optimum_w=6.0, optimum_p=9.5, mean_power=8.0,
        peak_power=12.0, work=960.0, duration=120.0, passivity_min=0.0, evaluation_count=100,
        abort_reason=None, **search,  # type: ignore[arg-type]
    )  # fmt: skip


def _user() -> UserRecord:
    when = datetime(2026, 12, 1, tzinfo=UTC)
    return UserRecord(
        id=1, name="Ada", notes="", body_mass_kg=None, limb=None, created_at=when, updated_at=when
    )


def test_a_session_at_a_bound_tells_the_trainer_to_widen_the_bracket() -> None:
    at = _record(at_bound="upper", target_min=2.0, target_max=6.0)
    text = html.unescape(session_markdown(at))
    assert "upper bound" in text and "Widen the bracket's upper end" in text
    assert "not stored" in text and " converged" not in text
    in_rad = sessions_table(_user(), 1, [at], None, Units(velocity="rad/s"))
    assert "6.000 (at the upper bound)" in html.unescape(in_rad)
    in_rpm = html.unescape(sessions_table(_user(), 1, [at], None))  # the dashboard's default
    assert f"{6.0 * 60.0 / (2.0 * math.pi):.1f} (at the upper bound)" in in_rpm
    found = _record(converged=True, t_converged=11.6, wd_converged=3.2)
    text = html.unescape(session_markdown(found))
    assert "bound" not in text and "First converged at 11.6 s on 3.200 rad/s" in text
