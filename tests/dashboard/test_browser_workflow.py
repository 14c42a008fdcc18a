"""The trainer's workflow in a real browser (Debian's Chromium, Playwright) against
``ergoseek demo``: ONE page load, in order —

- a protocol edited in the session setup (warm-up 3 s → seek ≤ 20 s → train 2 × (10 s work /
  10 s rest) → cool-down 5 s) and started from the dashboard; the Live tab says which phase
  runs, what is left and what comes next; the session ends at rest with the stored phases
  matching the protocol;
- velocities in rpm (the dashboard's default) until the account picks rad/s: the stored
  optimum the page shows is the session's, converted independently here, in either unit;
  the preference is the account's (REST reads it back);
- History: the progress across sessions with W/kg (the user's body mass is known), and the
  session's report (PDF) and activity (FIT) fetched through the page's own login, refused
  without it; each phase's stored summary as a table row equal to REST's (formatted here);
  and a profile session's τ–v and P–v charts holding the stored fit and its step means
  (read from the page's own uPlot objects). The profile session is written to the store as
  the pump writes one (its phase row, then its summary with a real fit of a simulated Hill
  person's steps, a phase name with markup in it): its telemetry is not needed to show it,
  and a real profile phase would add half a minute.

With ``ERGOSEEK_UPDATE_SCREENSHOT=1`` the protocol editor's screenshot and the report's
first page (pdftoppm) replace ``docs/img/protocol-editor.png`` and ``docs/img/report.png``.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from sessions.store import open_store
from testing.browser import TRAINER, VIEWPORT, DemoServer, login, open_tab, pick, set_number
from testing.browser import wait_text as wait_for_text

RPM = 60.0 / (2.0 * math.pi)  # independent of sessions.units
HILL = {"kind": "hill", "tau0": 3.0, "wmax": 10.0, "curvature": 0.25}
NAME = "Protocol person"
MASS = 70.0
DOCS = Path(__file__).resolve().parents[2] / "docs" / "img"
FORM = {  # what the trainer types (seconds; the velocities stay at their defaults)
    "warm-up (s)": 3,
    "seek: longest (s)": 20,
    "seek: hold once converged (s)": 1,
    "intervals": 2,
    "work (s)": 10,
    "rest (s)": 10,
    "countdown (s)": 2,
    "cool-down (s)": 5,
    "cool-down: hold at rest (s)": 1,
}
PAGE_WAIT_MS = 120_000  # a loaded 2-core VM has stalled this page's renderer for 22 s
PLANNED = "warmup 3 s → seek ≤ 20 s → train 2 × 10/10 s → cooldown 5 s"


def wait_text(page: Any, pattern: str, timeout_ms: int = PAGE_WAIT_MS) -> re.Match[str]:
    return wait_for_text(page, pattern, timeout_ms)


def wait_phases(server: DemoServer, sid: int, timeout: float = 30.0) -> list[dict[str, Any]]:
    """The session's phases once each has its summary (the pump writes them last)."""
    deadline = time.monotonic() + timeout
    with server.client() as api:
        while True:
            phases = api.get(f"/api/v1/sessions/{sid}/phases").json()
            if all(p["mean_power"] is not None for p in phases) or time.monotonic() > deadline:
                return phases
            time.sleep(0.2)


def test_a_protocol_from_the_dashboard_in_rpm_then_rad_s(
    server: DemoServer, browser: Any, tmp_path: Path
) -> None:
    with server.client() as api:
        user = api.post("/api/v1/users", json={"name": NAME, "body_mass_kg": MASS,
                                               "sim_profile": HILL}).json()  # fmt: skip
        assert api.get("/api/v1/accounts/me/preferences").json()["velocity_unit"] == "rpm"
    label = f"{NAME} (#{user['id']})"
    context = browser.new_context(viewport=VIEWPORT)
    page = context.new_page()
    page.set_default_timeout(PAGE_WAIT_MS)  # waits on conditions; the shared VM stalls pages
    login(page, server.url, TRAINER, server.password, timeout=PAGE_WAIT_MS / 1e3)
    pick(page, "User", label)
    wait_text(page, rf"Stored optimum for {NAME}: none yet")

    # -- the protocol, edited in the session setup ---
    page.get_by_text("Protocol phases", exact=True).click()
    for field, value in FORM.items():
        set_number(page, field, value)
    wait_text(page, re.escape(PLANNED))
    assert page.get_by_role("combobox", name="Protocol", exact=True).input_value() == (
        "as edited below"
    )
    page.keyboard.press("Escape")  # (Tab from the last field opened the next dropdown)
    page.get_by_text("Train (work / rest intervals)").scroll_into_view_if_needed()
    page.screenshot(path=str(tmp_path / "protocol-editor.png"))
    page.get_by_role("button", name="Start", exact=True).click()
    sid = int(wait_text(page, r"Session #(\d+) started by demo").group(1))

    # -- live: the phase, what is left, what comes next; velocities in rpm ---
    work = wait_text(page, r"Phase (\S+ \d) \((\d)/4\) · WORK 1/2 · (\d+) s left.* next: (\S+)",
                     PAGE_WAIT_MS)  # fmt: skip
    assert (work.group(2), work.group(4)) == ("3", "cooldown"), work.group(0)
    assert int(work.group(3)) <= 10
    wait_text(page, r"Velocity [\d.]+ rpm \(target [\d.]+ rpm\) · power [-\d.]+ W \([-\d.]+ W/kg\)")
    wait_text(page, rf"Last session #{sid}: completed", 2 * PAGE_WAIT_MS)
    # the live velocity chart's legend: its series, then the span series, never drawn
    assert page.evaluate(LEGEND) == [
        [["t [s]", ""], ["desired wd", "rgb(28, 126, 214)"], ["actual w", "rgb(232, 89, 12)"],
         ["(y span)", "rgba(0, 0, 0, 0)"]]
    ]  # fmt: skip

    # -- the stored optimum, in rpm, then in rad/s once the account says so ---
    with server.client() as api:
        optimum = api.get(f"/api/v1/sessions/{sid}").json()["session"]["optimum_w"]
    shown_rpm = wait_text(page, rf"Stored optimum for {NAME}: ([\d.]+) rpm").group(1)
    assert shown_rpm == f"{optimum * RPM:.1f}"
    pick(page, "Velocity in", "rad/s")
    shown = wait_text(page, rf"Stored optimum for {NAME}: ([\d.]+) rad/s").group(1)
    assert shown == f"{optimum:.3f}"
    with server.client() as api:
        assert api.get("/api/v1/accounts/me/preferences").json()["velocity_unit"] == "rad/s"

    # -- the stored phases match the protocol, and the session ended at rest ---
    phases = wait_phases(server, sid)
    assert [p["kind"] for p in phases] == ["warmup", "seek", "train", "cooldown"]
    warm, seek, train, cool = phases
    assert warm["t_end"] == pytest.approx(3.0)
    assert seek["t_end"] - seek["t_start"] <= 20.0 + 1e-6
    assert train["t_end"] - train["t_start"] == pytest.approx(2.0 + 2 * 20.0)
    assert cool["t_end"] - cool["t_start"] >= 5.0 + 1.0
    assert all(a["t_end"] == b["t_start"] for a, b in itertools.pairwise(phases))
    with open_store(server.database_url, upgrade=False) as store:
        c = store.telemetry.columns(sid, ("t", "w", "u"))
    last = c["t"] >= c["t"][-1] - 0.5
    assert np.abs(c["w"][last]).max() < 0.05 and np.abs(c["u"][last]).max() < 0.05

    # -- History: progress with W/kg; the report and the activity through the login ---
    open_tab(page, "History")
    pick(page, "History of", label)
    wait_text(page, rf"1 ended session · W/kg with {MASS:g} kg")
    page.get_by_role("combobox", name="Session", exact=True).click()
    page.get_by_role("option", name=re.compile(rf"^#{sid} ")).click()
    report = page.get_by_role("link", name="Download report (PDF)")
    report.wait_for()
    fit = page.get_by_role("link", name="Download activity (FIT)")
    pdf = context.request.get(server.url + report.get_attribute("href"))
    assert pdf.status == 200 and pdf.body().startswith(b"%PDF")
    activity = context.request.get(server.url + fit.get_attribute("href"))
    assert activity.status == 200 and activity.body()[8:12] == b".FIT"
    assert httpx.get(server.url + report.get_attribute("href")).status_code == 401
    check_phase_rows(page, phases)
    check_profile_charts(page, server)
    if os.environ.get("ERGOSEEK_UPDATE_SCREENSHOT"):
        shutil.copy(tmp_path / "protocol-editor.png", DOCS / "protocol-editor.png")
        (tmp_path / "report.pdf").write_bytes(pdf.body())
        pdf_file = str(tmp_path / "report.pdf")
        cmd = ["pdftoppm", "-png", "-r", "80", "-singlefile", pdf_file, str(DOCS / "report")]
        subprocess.run(cmd, check=True)
    context.close()


LEGEND = """() => Object.values(window.__viserTestpoints?.uplots ?? {})
    .map(({chart}) => chart.root)
    .filter(root => root.querySelector('.u-title')?.textContent === 'velocity [rad/s]'
                    && root.offsetParent !== null)
    .map(root => [...root.querySelectorAll('.u-legend .u-series')]
         .map(row => [row.querySelector('.u-label')?.textContent ?? '',
                      row.querySelector('.u-marker')?.style.borderColor ?? '']))"""
TABLE_ROWS = """() => [...document.querySelectorAll('table tr')]
    .map(tr => [...tr.cells].map(c => c.innerText.replace(/\u2060/g, '').trim()))"""


def check_phase_rows(page: Any, phases: list[dict[str, Any]]) -> None:
    """Each stored phase is a row of History's table, its figures as REST has them (rad/s)."""

    def row(p: dict[str, Any]) -> list[str]:
        opt = "—" if p["optimum_w"] is None else f"{p['optimum_w']:.3f} rad/s"
        if p["at_bound"] is not None:
            opt = (
                ("≥ " if p["at_bound"] == "upper" else "≤ ")
                + opt
                + f" (at the {p['at_bound']} bound)"
            )
        figures = (p["t_end"] - p["t_start"], p["mean_power"], p["peak_power"], p["work"])
        spec = (".1f", ".2f", ".2f", ".1f")
        cells = [format(v, f) for v, f in zip(figures, spec, strict=True)]
        return [str(p["position"] + 1), p["name"] or p["kind"], p["kind"], *cells, opt]

    wanted = [row(p) for p in phases]
    deadline = time.monotonic() + PAGE_WAIT_MS / 1e3
    while True:
        rows = page.evaluate(TABLE_ROWS)
        if all(w in rows for w in wanted) or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    for w in wanted:
        assert w in rows, (w, rows)


PROFILE_PHASE = "spectrum <b>8</b> | *K*"
UPLOTS = """() => Object.values(window.__viserTestpoints?.uplots ?? {}).map(({chart}) => ({
    title: chart.root.querySelector('.u-title')?.textContent ?? '',
    data: chart.data.map(col => Array.from(col, v => Number.isFinite(v) ? v : null)),
    created: chart.root.isConnected}))"""


def stored_profile_session(server: DemoServer, user_id: int) -> tuple[int, dict[str, Any]]:
    """A session with one profile phase, stored as the pump stores one, with a real fit."""
    from sessions.config import SessionConfig, UserConfig
    from sessions.people import SimulatedUser
    from sessions.profile import StepSamples, fit_profile, plan_profile
    from sessions.protocol.analysis import PhaseResult

    person = SimulatedUser(UserConfig(**HILL, noise=0.03), 1e-3, 4)
    steps, q = [], 0.0
    for st in plan_profile((1.0, 6.0), 6, 4.0).steps:
        n = round((st.end - st.settled) * 1000)
        tau = np.empty(n)
        for k in range(n):
            tau[k] = person.torque(q, st.velocity)
            person.advance(1e-3)
            q += st.velocity * 1e-3
        steps.append(StepSamples(st.velocity, tau, np.full(n, st.velocity)))
    fit = fit_profile(steps).to_dict()
    cfg = SessionConfig.model_validate({"protocol": {"phases": [{"kind": "profile", "count": 6}]}})
    with open_store(server.database_url, upgrade=False) as store:
        sid = store.sessions.start(user_id, cfg).id
        store.phases.begin(sid, 0, "profile", PROFILE_PHASE, 0.0)
        store.sessions.finish(sid, "completed")
        result = PhaseResult(
            index=0, kind="profile", name=PROFILE_PHASE, start=0.0, end=30.0, mean_power=2.0,
            peak_power=3.0, work=60.0, mean_w=3.0, optimum_w=None, detail={"profile": fit},
        )  # fmt: skip
        store.phases.summarize(sid, result)
    return sid, fit


def check_profile_charts(page: Any, server: DemoServer) -> None:
    with server.client() as api:
        user = api.post("/api/v1/users", json={"name": "Profile person"}).json()
    sid, fit = stored_profile_session(server, user["id"])
    label = f"Profile person (#{user['id']})"
    page.get_by_role("combobox", name="History of", exact=True).click()  # listed once it is
    page.get_by_role("option", name=label, exact=True).click()
    page.get_by_role("combobox", name="Session", exact=True).click()
    page.get_by_role("option", name=re.compile(rf"^#{sid} ")).click()
    wait_text(
        page, re.escape(f"Profile {PROFILE_PHASE} (") + rf"{fit['model']} fit, 95 % intervals\)"
    )
    assert page.locator("b", has_text="8").count() == 0  # the stored name stayed text
    curve = fit["curve"]
    x = sorted(curve["w"] + [st["w"] for st in fit["steps"]])
    measured = {st["w"]: st for st in fit["steps"]}
    want = {
        "torque": (curve["tau"], [measured[w]["tau"] for w in sorted(measured)]),
        "power": (curve["power"], [measured[w]["tau"] * w for w in sorted(measured)]),
    }
    deadline = time.monotonic() + PAGE_WAIT_MS / 1e3
    while True:
        charts = {
            c["title"]: c for c in page.evaluate(UPLOTS) if c["title"].startswith("profile: ")
        }
        if len(charts) == 2 and all(len(c["data"][0]) == len(x) for c in charts.values()):
            break
        assert time.monotonic() < deadline, charts.keys()
        time.sleep(0.2)
    for title, chart in charts.items():
        assert title.endswith("vs velocity [rad/s]")
        fitted, points = want["torque" if "torque" in title else "power"]
        xs, line, _low, _high, dots = chart["data"]
        assert xs == pytest.approx(x, rel=1e-12)  # rad/s: this account's unit now
        assert [v for v in line if v is not None] == pytest.approx(fitted, rel=1e-12)
        assert [v for v in dots if v is not None] == pytest.approx(points, rel=1e-12)


SPAN_POLL = """() => Object.values(window.__viserTestpoints?.uplots ?? {}).map(
  ({chart}) => ({
    title: chart.root.querySelector('.u-title')?.textContent ?? '',
    id: (chart.__ergoseekProbe ??= Math.random()),
    y: [chart.scales.y.min, chart.scales.y.max], x_max: chart.scales.x.max,
    last: chart.data[0][chart.data[0].length - 1], ticks: chart.axes[1]._values ?? [],
    w: Array.from(chart.data[2] ?? [], v => Number.isFinite(v) ? v : null)}))"""
STAGES = ((0.0, 3.095, 1e-4), (2.5, 2.0, 1.0), (5.0, 1.2, 1e-4))  # from t: level, zigzag/sine


def synthetic_velocity(t: float) -> float:
    _, level, swing = next(s for s in reversed(STAGES) if t >= s[0])
    if swing > 0.1:
        return level + swing * math.sin(2.0 * math.pi * t)
    return level + swing * (-1.0) ** round(t * 50.0)


def velocity_last(page: Any) -> float:
    """The newest sample's time the velocity chart draws."""
    chart = next(c for c in page.evaluate(SPAN_POLL) if c["title"].startswith("velocity"))
    return float(chart["last"])


def test_the_live_charts_keep_their_minimum_span_and_keep_drawing(browser: Any) -> None:
    """The dashboard's own LiveCharts in viser's client, fed 50 samples/s of a steady velocity
    (3.095 rad/s ± 1e-4), then a wide one (2 ± 1 rad/s), then steady again at 1.2 rad/s,
    through a 1.5 s live window: a steady signal is drawn in a range at least VELOCITY_SPAN
    wide whose tick labels all differ, a wide one in uPlot's own range; the chart is never
    rebuilt and draws every new sample (its x range ends at the newest one)."""
    import socket
    import threading

    import viser

    from sessions.telemetry import RECORD_INDEX, RECORD_WIDTH
    from webui.charts import VELOCITY_SPAN, LiveCharts, LiveWindow

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    srv = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    charts, window = LiveCharts(srv.gui), LiveWindow(seconds=1.5)
    done, sent = threading.Event(), []

    def feed() -> None:
        t, dt = 0.0, 0.02
        while not done.wait(dt) and t < 7.5:
            rec = np.zeros((1, RECORD_WIDTH))
            w = synthetic_velocity(t)
            rec[0, [RECORD_INDEX["t"], RECORD_INDEX["w"], RECORD_INDEX["wd"]]] = t, w, w
            rec[0, RECORD_INDEX["session"]] = 1.0
            window.extend(rec)
            charts.show(window)
            sent.append(t)
            t += dt

    page = browser.new_page()
    try:
        page.goto(f"http://127.0.0.1:{port}/")
        page.wait_for_function("() => Object.keys(window.__viserTestpoints?.uplots ?? {}).length")
        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        polls = []
        while feeder.is_alive():
            velocity = next(
                c for c in page.evaluate(SPAN_POLL) if c["title"].startswith("velocity")
            )
            polls.append((sent[-1] if sent else 0.0, velocity))
            time.sleep(0.15)
        # ...and every sample is drawn, up to the last one sent (however late a loaded
        # machine's browser draws it: counted in the data, not against the wall clock)
        deadline = time.monotonic() + 15.0
        while (last := velocity_last(page)) < sent[-1] - 1e-9:
            assert time.monotonic() < deadline, (last, sent[-1])
            time.sleep(0.1)
    finally:
        done.set()
        page.close()
        srv.stop()
    by_stage: dict[int, list[dict[str, Any]]] = {0: [], 1: [], 2: []}
    for at, c in polls:
        ws = [v for v in c["w"] if v is not None]
        if not ws or c["last"] < 0.5:  # no sample drawn yet (the empty chart's NaN pair)
            continue
        stage = max(i for i, s in enumerate(STAGES) if c["last"] >= s[0])
        settled = c["last"] - 1.5 >= STAGES[stage][0]  # the window holds this stage only
        assert c["id"] == polls[-1][1]["id"]  # the same uPlot object throughout: never rebuilt
        assert c["x_max"] == pytest.approx(c["last"], abs=0.1)  # drawn up to the newest sample
        assert c["last"] <= at + 1e-9  # (a sample sent, never one made up)
        assert len(set(c["ticks"])) == len(c["ticks"]) >= 2, c  # no repeated label
        assert c["y"][0] <= min(ws) and max(ws) <= c["y"][1]  # nothing clipped
        if settled:
            by_stage[stage].append(c)
    drawn = [c for _, c in polls if any(v is not None for v in c["w"]) and c["last"] >= 0.5]
    lasts = [c["last"] for c in drawn]  # (not the empty chart's placeholder pair)
    assert lasts == sorted(lasts) and len(set(lasts)) >= 10  # new data kept coming, in order
    for stage in (0, 2):
        assert by_stage[stage], polls
        for c in by_stage[stage]:
            assert c["y"][1] - c["y"][0] >= VELOCITY_SPAN
    assert by_stage[1]
    for c in by_stage[1]:  # wide: uPlot's own range around ±1, not a fixed 0.5
        assert c["y"][0] <= 1.05 and c["y"][1] >= 2.95 and c["y"][1] - c["y"][0] < 4.0
