"""The session report: a one-page A4 PDF read back with pypdf, its text and its layout."""

from __future__ import annotations

import io
import math
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pypdf
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from sessions.config import UserConfig
from sessions.exports.data import ExportError, Phase
from sessions.exports.report import (
    CHART_COLUMNS,
    EDGE_NOTE,
    NO_PROFILE,
    ReportData,
    missing_glyphs_quiet,
    render_report,
    report_figure,
    write_report,
)
from sessions.people import SimulatedUser
from sessions.profile import StepSamples, fit_profile, plan_profile
from sessions.simulation import SimulationResult
from sessions.summary import SessionSummary
from sessions.telemetry import INDEX, NAMES
from testing.exports import simulated_session, tiled

RPM = 60.0 / (2.0 * math.pi)
NAME = "Zoë Ångström-Łukasiewicz Ψυχή Привет"
START = datetime(2026, 3, 1, 9, 30, 12, tzinfo=UTC)


@pytest.fixture(scope="module")
def run() -> SimulationResult:
    return simulated_session(40.0, seed=5)


def summary_of(run: SimulationResult) -> SessionSummary:
    ev = max(run.evaluations, key=lambda e: e.power)
    power = run.column("tau") * run.column("w")
    return SessionSummary(
        optimum_w=run.progress.target,
        optimum_p=ev.power,
        converged=run.progress.done,
        seeker="brent",
        mean_power=float(power.mean()),
        peak_power=float(power.max()),
        work=float(run.column("W")[-1]),
        duration=40.0,
        passivity_min=run.passivity_min,
        evaluations=len(run.evaluations),
    )


def data(run: SimulationResult, **kw: object) -> ReportData:
    base = ReportData(
        user_name=NAME,
        started_at=START,
        telemetry=run,
        summary=summary_of(run),
        phases=(
            Phase("warm-up", 0, 5, "warmup"),
            Phase("seek", 5, 35, "seek"),
            Phase("cool-down", 35, 40, "cooldown"),
        ),
        protocol="Standard",
        evaluations=run.evaluations,
        bracket=(1.0, 6.0),
        body_mass_kg=72.5,
        session_id=17,
    )
    return replace(base, **kw)  # type: ignore[arg-type]


def pdf_text(pdf: bytes) -> tuple[int, str, pypdf.PageObject]:
    reader = pypdf.PdfReader(io.BytesIO(pdf))
    page = reader.pages[0]
    return len(reader.pages), page.extract_text(), page


def flat(text: str) -> str:
    return " ".join(text.split())


def a_profile() -> object:
    user = SimulatedUser(UserConfig(noise=0.03), 1e-3, 2)
    steps, q = [], 0.0
    for s in plan_profile((1.0, 6.0), 6, 5.0).steps:
        n = round((s.end - s.settled) * 1000)
        tau = np.empty(n)
        for k in range(n):
            tau[k] = user.torque(q, s.velocity)
            user.advance(1e-3)
            q += s.velocity * 1e-3
        steps.append(StepSamples(s.velocity, tau, np.full(n, s.velocity)))
    return fit_profile(steps)


def test_one_a4_page_with_the_name_and_the_optimum(run: SimulationResult) -> None:
    d = data(run)
    pages, text, page = pdf_text(render_report(d))
    assert pages == 1
    assert (float(page.mediabox.width), float(page.mediabox.height)) == pytest.approx(
        (595.4, 841.7), abs=1.0
    )
    text = flat(text)
    assert NAME in text
    assert f"{d.summary.optimum_w * RPM:.3g} rpm" in text
    assert f"{d.summary.optimum_p:.3g} W ({d.summary.optimum_p / 72.5:.2f} W/kg)" in text
    assert f"{d.summary.peak_power:.3g} W" in text
    assert f"{d.summary.work / 1000:.3g} kJ" in text
    assert "2026-03-01 09:30" in text and "Protocol: Standard" in text
    for ph in ("warm-up", "seek", "cool-down"):
        assert ph in text
    assert NO_PROFILE in text  # no profile phase in this session


def test_an_optimum_at_the_brackets_edge_reads_as_a_bound(run: SimulationResult) -> None:
    inside = flat(pdf_text(render_report(data(run)))[1])
    assert "≥" not in inside and "≤" not in inside and EDGE_NOTE not in inside
    phases = (
        Phase("warm-up", 0, 5, "warmup"),
        Phase("seek", 5, 20, "seek", optimum_w=6.0, at_bound="upper"),
        Phase("train", 20, 35, "train", optimum_w=2.5),
        Phase("cool-down", 35, 40, "cooldown"),
    )
    text = flat(pdf_text(render_report(data(run, phases=phases, velocity_unit="rad/s")))[1])
    assert "≥ 6 rad/s" in text and "≥ 2.5" not in text and "2.5 rad/s" in text
    assert EDGE_NOTE in text
    # the session's own optimum at the lower edge
    low = summary_of(run).model_copy(update={"optimum_w": 1.0, "at_bound": "lower"})
    text = flat(pdf_text(render_report(data(run, summary=low, velocity_unit="rad/s")))[1])
    assert "≤ 1 rad/s" in text and EDGE_NOTE in text


def test_velocity_in_rad_s_and_no_w_per_kg_without_a_mass(run: SimulationResult) -> None:
    d = data(run, velocity_unit="rad/s", body_mass_kg=None)
    text = flat(pdf_text(render_report(d))[1])
    assert f"{d.summary.optimum_w:.3g} rad/s" in text
    assert "rpm" not in text and "W/kg" not in text


def test_a_profile_phase_shows_its_fit(run: SimulationResult) -> None:
    fit = a_profile()
    d = data(run, profile=fit)
    pages, text, _ = pdf_text(render_report(d))
    text = flat(text)
    assert pages == 1 and NO_PROFILE not in text
    assert "Profile: power–velocity" in text and "hill law, 95% CI" in text
    assert f"{fit.w_opt.value * RPM:.3g} [{fit.w_opt.low * RPM:.3g}" in text  # type: ignore[attr-defined]
    fig = report_figure(d)
    bands = [c for ax in fig.axes for c in ax.collections if c.get_label() == "95% CI"]
    assert bands  # the confidence band is drawn


HOSTILE = [
    "A" * 400,
    "名前はとても長い日本語の名前です " * 12 + "🏋️‍♀️",
    "$\\frac{1}{0}$ \\ _^{} $ unbalanced",
    "two\nlines\tand a tab",
    "W" * 60 + " Ψυχή " + "x" * 300,
]


@pytest.mark.parametrize("name", HOSTILE, ids=range(len(HOSTILE)))
def test_long_and_arbitrary_names_keep_the_layout(run: SimulationResult, name: str) -> None:
    d = data(run, user_name=name, protocol=name, phases=(Phase(name, 0, 40, name),))
    pages, text, _ = pdf_text(render_report(d))
    assert pages == 1
    start = " ".join(name.split())[:8]
    assert start in flat(text)
    fig = report_figure(d)
    FigureCanvasAgg(fig)
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    width = fig.bbox.width
    with missing_glyphs_quiet():
        for t in fig.texts:  # every line of text inside the page
            box = t.get_window_extent(renderer)
            assert box.x0 >= 0 and box.x1 <= width + 0.5, t.get_text()[:40]


def test_dollar_signs_print_as_typed(run: SimulationResult) -> None:
    text = flat(pdf_text(render_report(data(run, user_name="Bob $x^2$ Smith")))[1])
    assert "Bob $x^2$ Smith" in text


def test_an_hour_at_1khz_renders_decimated_with_every_extreme(run: SimulationResult) -> None:
    rows = run.telemetry
    cols = tiled(rows, 90)  # 40 s × 90 = 60 min, 3.6 million samples
    assert len(cols["t"]) == 3_600_000
    spike = 1_234_567
    cols["tau"] = cols["tau"].copy()
    cols["tau"][spike] = 50.0  # one sample: the chart must still show it
    summary = summary_of(run).model_copy(update={"duration": 3600.0})
    d = data(run, telemetry=cols, summary=summary, phases=())
    pages, text, _ = pdf_text(render_report(d))
    assert pages == 1 and "time [min]" in text
    fig = report_figure(d)
    lines = [ln for ax in fig.axes[-4:] for ln in ax.get_lines() if len(ln.get_xdata()) > 10]
    assert lines and all(len(ln.get_xdata()) <= 2 * CHART_COLUMNS + 2 for ln in lines)
    torque = next(ln for ln in fig.axes[-3].get_lines() if len(ln.get_xdata()) > 10)
    assert max(torque.get_ydata()) == 50.0
    assert min(torque.get_ydata()) == cols["tau"].min()


def test_write_report(run: SimulationResult, tmp_path: Path) -> None:
    path = tmp_path / "report.pdf"
    size = write_report(path, data(run))
    assert size == path.stat().st_size and path.read_bytes()[:5] == b"%PDF-"
    assert [p.name for p in tmp_path.iterdir()] == ["report.pdf"]


def test_plain_column_mapping_and_store_like_input(run: SimulationResult) -> None:
    cols = {name: run.telemetry[:, INDEX[name]] for name in NAMES}
    assert pdf_text(render_report(data(run, telemetry=cols)))[0] == 1


def test_bad_input_is_refused_with_the_argument_named(run: SimulationResult) -> None:
    cases = [
        (data(run, started_at=START.replace(tzinfo=None)), r"^started_at"),
        (data(run, velocity_unit="furlongs"), r"^velocity_unit"),
        (data(run, body_mass_kg=-3.0), r"^body_mass_kg"),
        (data(run, phases=(Phase("a", 5, 1),)), r"^phases\[0\]\.end"),
        (data(run, telemetry={"t": np.zeros(3)}), r"^telemetry\.w: missing"),
    ]
    for d, message in cases:
        with pytest.raises(ExportError, match=message):
            render_report(d)
