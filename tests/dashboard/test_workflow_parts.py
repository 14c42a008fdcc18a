"""The workflow's dashboard parts, no browser: units as a browser reads them, the charts'
minimum span, the live phase line, a protocol's fit to the editor's form."""

from __future__ import annotations

import math

import numpy as np

from server.service.session import ActiveSession
from sessions.config import parse_session_config
from sessions.protocol.config import Protocol
from sessions.protocol.stage import Stage
from sessions.worker.ring import INDEX as RING
from sessions.worker.ring import WIDTH as RING_WIDTH
from webui.charts import span_range
from webui.escape import WORD_JOINER
from webui.feed import LiveState
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
