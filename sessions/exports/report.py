"""A printable one-page session report: A4 portrait PDF through matplotlib's PDF backend.

Layout, top to bottom (docs/exports.md has a picture of it):
  header     the user's name, date and time, session number, protocol, status, duration;
  figures    optimum velocity (rpm or rad/s) and power (W, W/kg when the body mass is known),
             peak and mean power, work, passivity minimum, seeker, controller;
  phases     one row per protocol phase: kind, time span, mean and peak power, work, optimum;
  charts     the search (candidates on power–velocity with the bracket and the optimum) and
             the profile (P–v and τ–v, the fit with its confidence band and the step means;
             a note when the session had no profile phase);
  time       velocity (w, wd, γ), torque, power and the passivity integral W(t) (5), with the
             phase boundaries.
Every string a person typed (names, phases, protocol) is drawn as plain text: matplotlib's
mathtext is off for them (a "$" in a name would otherwise start a formula), and each is cut
with an ellipsis to the width it has, so no name or phase breaks the layout. Full-rate
telemetry is decimated to min/max pairs per column of the chart (every extreme kept), so an
hour at 1 kHz renders in well under a second.
"""

from __future__ import annotations

import io
import math
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime, tzinfo
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_pdf import FigureCanvasPdf
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.lines import Line2D
from matplotlib.textpath import TextToPath
from matplotlib.ticker import MaxNLocator

from sessions.exports.data import (
    ExportError,
    Phase,
    check_phases,
    telemetry_columns,
    write_atomically,
)
from sessions.profile import ProfileFit
from sessions.store.decimate import minmax_pairs
from sessions.summary import SessionSummary
from sessions.units import VELOCITY_UNITS, VelocityUnit, per_kg, velocity_factor

A4 = (8.27, 11.69)  # inches, portrait
CHART_COLUMNS = 1200  # min/max pairs per time chart: finer than a printer resolves at this width
CHANNELS = ("t", "w", "wd", "gamma", "tau", "W")
NO_PROFILE = "No profile phase in this session"
MAX_PHASE_ROWS = 10
COLORS = {
    "w": "#1f77b4",
    "wd": "#ff7f0e",
    "gamma": "#7f7f7f",
    "tau": "#2ca02c",
    "p": "#d62728",
    "W": "#9467bd",
    "fit": "#d62728",
    "band": "#f4a3a3",
}


class EvaluationLike(Protocol):
    """A measured candidate: :class:`sessions.seekers.Evaluation` or the store's
    :class:`~sessions.store.EvaluationRecord` both fit."""

    t: float
    candidate: float
    power: float
    stderr: float | None


@dataclass(frozen=True)
class ReportData:
    """Everything the report shows, as plain data. SI units throughout (rad/s, N·m, W, J, s);
    ``velocity_unit`` only says how velocities are printed."""

    user_name: str
    started_at: datetime  # aware; printed in ``timezone`` (default: its own zone)
    telemetry: Any  # columns t, w, wd, gamma, tau, W (sessions.exports.data); full rate or not
    summary: SessionSummary
    phases: Sequence[Phase] = ()
    protocol: str = ""  # the protocol template's name
    evaluations: Sequence[EvaluationLike] = ()
    bracket: tuple[float, float] | None = None  # the trainer's bracket (γ1, γ3), rad/s
    profile: ProfileFit | None = None  # the profile phase's fit, if the session had one
    body_mass_kg: float | None = None
    velocity_unit: VelocityUnit = "rpm"
    session_id: int | None = None
    status: str = ""  # completed, stopped, aborted, faulted
    controller: str = ""
    passivity_bound: float | None = None  # c² of (5), J: drawn as the floor -c²
    timezone: tzinfo | None = None


# -- text that fits --------------------------------------------------------------------------
_TEXT = TextToPath()


def text_width(s: str, size: float, weight: str = "normal") -> float:
    """Width of ``s`` in points at font size ``size`` (the default font, as drawn)."""
    font = FontProperties(size=size, weight=weight)
    w, _, _ = _TEXT.get_text_width_height_descent(s, font, ismath=False)
    return float(w)


def fit_text(s: str, width_pt: float, size: float, weight: str = "normal") -> str:
    """``s`` on one line, cut with an ellipsis to at most ``width_pt`` points."""
    s = " ".join(str(s).split())  # newlines and tabs would stack lines
    if text_width(s, size, weight) <= width_pt:
        return s
    lo, hi = 0, len(s)
    while lo < hi:  # the longest prefix that fits with its ellipsis
        mid = (lo + hi + 1) // 2
        if text_width(s[:mid] + "…", size, weight) <= width_pt:
            lo = mid
        else:
            hi = mid - 1
    return s[:lo].rstrip() + "…"


def _plain(
    fig: Figure,
    x: float,
    y: float,
    s: str,
    width: float,
    size: float,
    weight: str = "normal",
    **kw: Any,
) -> None:
    """User text at figure position (x, y), cut to ``width`` (figure fraction)."""
    text = fit_text(s, width * A4[0] * 72, size, weight)
    fig.text(x, y, text, size=size, weight=weight, parse_math=False, **kw)


# -- formatting --------------------------------------------------------------------------------
def _num(x: float | None, digits: int = 3, unit: str = "") -> str:
    if x is None or not math.isfinite(x):
        return "–"
    s = f"{x:.{digits}g}" if abs(x) < 10**digits else f"{x:.0f}"
    return f"{s} {unit}".rstrip()


def _clock(seconds: float) -> str:
    m, s = divmod(max(round(seconds), 0), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def _power(p: float | None, mass: float | None) -> str:
    kg = per_kg(p, mass)
    return _num(p, 3, "W") + ("" if kg is None else f"  ({kg:.2f} W/kg)")


def _velocity(w: float | None, unit: VelocityUnit) -> str:
    return _num(None if w is None else w * velocity_factor(unit), 3, unit)


EDGE = {"upper": "≥ ", "lower": "≤ "}  # an optimum at the bracket's edge: the peak lies beyond
EDGE_NOTE = "≥ / ≤: the search ended at the bracket's upper / lower edge; the peak lies beyond it."


def _optimum(w: float | None, unit: VelocityUnit, at_bound: str | None) -> str:
    """The optimum, ``≥ x`` / ``≤ x`` when it is the bracket's upper / lower edge."""
    return (EDGE.get(at_bound or "", "") if w is not None else "") + _velocity(w, unit)


# -- sections ----------------------------------------------------------------------------------
def _header(fig: Figure, d: ReportData) -> None:
    when = d.started_at.astimezone(d.timezone) if d.timezone else d.started_at
    fig.text(0.06, 0.972, "Session report", size=11, color="#555555")
    fig.text(0.94, 0.972, when.strftime("%Y-%m-%d %H:%M %Z").strip(), size=11, ha="right")
    _plain(fig, 0.06, 0.944, d.user_name or "(no name)", 0.88, 17, weight="bold")
    bits = [
        f"Session {d.session_id}" if d.session_id is not None else "",
        f"Protocol: {d.protocol}" if d.protocol else "",
        d.status,
        f"Duration {_clock(d.summary.duration)}",
    ]
    _plain(fig, 0.06, 0.925, "  ·  ".join(b for b in bits if b), 0.88, 9, color="#333333")
    _rule(fig, 0.917)


def _rule(fig: Figure, y: float) -> None:
    fig.add_artist(Line2D([0.06, 0.94], [y, y], transform=fig.transFigure, color="#999999", lw=0.6))


def _figures(fig: Figure, d: ReportData) -> None:
    s, m, unit = d.summary, d.body_mass_kg, d.velocity_unit
    left = [
        ("Optimum velocity", _optimum(s.optimum_w, unit, s.at_bound)),
        ("Power at the optimum", _power(s.optimum_p, m)),
        ("Peak power", _power(s.peak_power, m)),
        ("Mean power", _power(s.mean_power, m)),
        ("Body mass", _num(m, 3, "kg")),
    ]
    right = [
        ("Work", _num(s.work / 1000.0, 3, "kJ")),
        ("Passivity minimum", _num(s.passivity_min, 3, "J")),
        ("Seeker", f"{s.seeker or '–'}, {'converged' if s.converged else 'not converged'}"),
        ("Candidates measured", str(s.evaluations)),
        ("Controller", d.controller or "–"),
    ]
    for col, rows in ((0.06, left), (0.52, right)):
        for i, (label, value) in enumerate(rows):
            y = 0.897 - i * 0.017
            fig.text(col, y, label, size=8.5, color="#555555")
            _plain(fig, col + 0.17, y, value, 0.25, 9, weight="bold")
    if s.abort_reason:
        _plain(fig, 0.06, 0.808, f"Ended early: {s.abort_reason}", 0.88, 8.5, color="#b00020")


def _phase_table(fig: Figure, d: ReportData, phases: tuple[Phase, ...]) -> None:
    top, row = 0.795, 0.0128
    cols = [
        (0.06, "Phase", 0.2),
        (0.27, "Kind", 0.09),
        (0.37, "Time", 0.13),
        (0.51, "Mean P", 0.09),
        (0.61, "Peak P", 0.09),
        (0.71, "Work", 0.09),
        (0.81, "Optimum", 0.13),
    ]
    fig.text(0.06, top + 0.004, "Phases", size=9.5, weight="bold")
    if not phases:
        fig.text(
            0.06,
            top - row,
            "No protocol phases recorded: one continuous session.",
            size=8,
            color="#555555",
        )
        return
    for x, title, _ in cols:
        fig.text(x, top - row, title, size=7.5, color="#555555")
    edge = bool(d.summary.at_bound or any(ph.at_bound for ph in phases))
    room = MAX_PHASE_ROWS - edge  # the edge's note takes a row
    shown = phases if len(phases) <= room else phases[: room - 1]
    for i, ph in enumerate(shown):
        y = top - (i + 2) * row
        cells = [
            ph.name,
            ph.kind,
            f"{_clock(ph.start)}–{_clock(ph.end)}",
            _num(ph.mean_power, 3, "W"),
            _num(ph.peak_power, 3, "W"),
            _num(None if ph.work is None else ph.work / 1000.0, 3, "kJ"),
            _optimum(ph.optimum_w, d.velocity_unit, ph.at_bound),
        ]
        for (x, _, width), cell in zip(cols, cells, strict=True):
            _plain(fig, x, y, cell, width, 7.5)
    notes = [f"… and {len(phases) - len(shown)} more phases"] if len(shown) < len(phases) else []
    if edge:
        notes.append(EDGE_NOTE)
    if notes:
        y = top - (len(shown) + 2) * row
        fig.text(0.06, y, "   ".join(notes), size=7.5, color="#555555")


def _velocity_axis(ax: Axes, unit: VelocityUnit) -> None:
    ax.set_xlabel(f"velocity [{unit}]", size=7.5)


def _search_chart(ax: Axes, d: ReportData) -> None:
    f, s = velocity_factor(d.velocity_unit), d.summary
    ax.set_title("Search: power at each candidate", size=8.5, loc="left")
    _velocity_axis(ax, d.velocity_unit)
    ax.set_ylabel("power [W]", size=7.5)
    if d.bracket is not None:
        ax.axvspan(d.bracket[0] * f, d.bracket[1] * f, color="#e8eef7", lw=0, label="bracket")
    evs = [e for e in d.evaluations if math.isfinite(e.candidate) and math.isfinite(e.power)]
    if evs:
        x = np.array([e.candidate for e in evs]) * f
        y = np.array([e.power for e in evs])
        err = np.array(
            [e.stderr if e.stderr is not None and math.isfinite(e.stderr) else 0.0 for e in evs]
        )
        ax.errorbar(x, y, yerr=err, fmt="none", ecolor="#999999", lw=0.6)
        ax.scatter(x, y, c=np.arange(len(evs)), cmap="viridis", s=14, zorder=3, label="candidates")
    else:
        ax.text(0.5, 0.5, "No candidates measured", transform=ax.transAxes, ha="center", size=8)
    if s.optimum_w is not None:
        ax.axvline(s.optimum_w * f, color=COLORS["fit"], lw=0.8, ls="--")
        if s.optimum_p is not None:
            ax.plot(
                [s.optimum_w * f],
                [s.optimum_p],
                marker="*",
                ms=10,
                color=COLORS["fit"],
                zorder=4,
                label="optimum",
            )
    if evs or d.bracket is not None:
        ax.legend(fontsize=6, loc="best", frameon=False)


def _no_profile(ax: Axes) -> None:
    ax.set_axis_off()
    ax.text(
        0.5,
        0.62,
        NO_PROFILE,
        transform=ax.transAxes,
        ha="center",
        size=10,
        weight="bold",
        color="#555555",
    )
    ax.text(
        0.5,
        0.45,
        "Add a velocity-spectrum (profile) phase to the protocol to measure the\n"
        "torque–velocity and power–velocity curves (τ0, wmax, Pmax, w_opt).",
        transform=ax.transAxes,
        ha="center",
        va="top",
        size=7.5,
        color="#555555",
    )


def _profile_charts(tv: Axes, pv: Axes, d: ReportData) -> None:
    fit, f = d.profile, velocity_factor(d.velocity_unit)
    assert fit is not None
    c = fit.curve
    pct = f"{fit.confidence:.0%}"
    w = np.array([s.w for s in fit.steps]) * f
    tau = np.array([s.tau for s in fit.steps])
    se = np.array([s.tau_se for s in fit.steps])
    tv.fill_between(c.w * f, c.tau_low, c.tau_high, color=COLORS["band"], lw=0, label=f"{pct} CI")
    tv.plot(c.w * f, c.tau, color=COLORS["fit"], lw=1.0, label=f"{fit.model} fit")
    tv.errorbar(w, tau, yerr=se, fmt="o", ms=3, color="k", lw=0.6, label="steps")
    tv.set_title("Profile: torque–velocity", size=8.5, loc="left")
    tv.set_ylabel("torque [N·m]", size=7.5)
    pv.fill_between(c.w * f, c.power_low, c.power_high, color=COLORS["band"], lw=0)
    pv.plot(c.w * f, c.power, color=COLORS["fit"], lw=1.0)
    pv.errorbar(w, tau * w / f, yerr=se * w / f, fmt="o", ms=3, color="k", lw=0.6)
    pv.axvspan(fit.w_opt.low * f, fit.w_opt.high * f, color="#e8eef7", lw=0)
    pv.plot([fit.w_opt.value * f], [fit.pmax.value], marker="*", ms=10, color=COLORS["fit"])
    pv.set_title("Profile: power–velocity", size=8.5, loc="left")
    pv.set_ylabel("power [W]", size=7.5)
    for ax in (tv, pv):
        _velocity_axis(ax, d.velocity_unit)
        ax.set_xlim(0, c.w[-1] * f)
        ax.set_ylim(bottom=0)
    tv.legend(fontsize=6, frameon=False, loc="lower left")
    tv.text(
        0.97,
        0.96,
        _profile_text(fit, d),
        transform=tv.transAxes,
        size=5.8,
        va="top",
        ha="right",
        multialignment="left",
        family="DejaVu Sans Mono",
        parse_math=False,
    )


def _profile_text(fit: ProfileFit, d: ReportData) -> str:
    f, unit, m = velocity_factor(d.velocity_unit), d.velocity_unit, d.body_mass_kg

    def ci(e: Any, scale: float = 1.0, digits: int = 3) -> str:
        v, lo, hi = (x * scale for x in (e.value, e.low, e.high))
        return f"{v:.{digits}g} [{lo:.{digits}g}, {hi:.{digits}g}]"

    lines = [
        f"{fit.model} law, {fit.confidence:.0%} CI",
        f"τ0    {ci(fit.tau0)} N·m",
        f"wmax  {ci(fit.wmax, f)} {unit}",
        f"w_opt {ci(fit.w_opt, f)} {unit}",
        f"Pmax  {ci(fit.pmax)} W",
    ]
    if per_kg(fit.pmax.value, m) is not None:
        assert m is not None
        lines.append(f"      {ci(fit.pmax, 1.0 / m)} W/kg")
    return "\n".join(lines)


def _decimated(cols: dict[str, np.ndarray], columns: int) -> dict[str, np.ndarray]:
    """Min/max pairs per chart column (every extreme kept), power τ·w computed at full rate;
    one channel at a time, so an hour at 1 kHz is never copied whole."""
    series = {name: cols[name] for name in CHANNELS} | {"p": cols["tau"] * cols["w"]}
    n = len(cols["t"])
    if n <= 2 * columns:
        return series
    size = -(-n // columns)
    return {name: minmax_pairs(x[np.newaxis, :], size)[0] for name, x in series.items()}


def _time_charts(
    axes: Sequence[Axes], d: ReportData, cols: dict[str, np.ndarray], phases: tuple[Phase, ...]
) -> None:
    data = _decimated(cols, CHART_COLUMNS)
    t = data["t"]
    minutes = len(t) > 0 and t[-1] > 300
    x = t / 60.0 if minutes else t
    f, unit = velocity_factor(d.velocity_unit), d.velocity_unit
    vel, tor, pow_, work = axes
    vel.plot(x, data["w"] * f, color=COLORS["w"], lw=0.6, label="w")
    vel.plot(x, data["wd"] * f, color=COLORS["wd"], lw=0.6, label="wd")
    vel.plot(x, data["gamma"] * f, color=COLORS["gamma"], lw=0.6, ls="--", label="γ")
    vel.set_ylabel(f"velocity\n[{unit}]", size=7)
    vel.legend(fontsize=6, frameon=False, ncol=3, loc="lower right")
    tor.plot(x, data["tau"], color=COLORS["tau"], lw=0.5)
    tor.set_ylabel("torque\n[N·m]", size=7)
    pow_.plot(x, data["p"], color=COLORS["p"], lw=0.5)
    pow_.set_ylabel("power\n[W]", size=7)
    work.plot(x, data["W"], color=COLORS["W"], lw=0.8)
    work.set_ylabel("W(t)\n[J]", size=7)
    if d.passivity_bound is not None:
        work.axhline(-d.passivity_bound, color="#b00020", lw=0.6, ls=":")
    work.set_xlabel("time [min]" if minutes else "time [s]", size=7.5)
    scale = 60.0 if minutes else 1.0
    for ax in axes:
        _min_span(ax)
        for ph in phases:
            ax.axvline(ph.start / scale, color="#bbbbbb", lw=0.5)
        if ax is not work:
            ax.tick_params(labelbottom=False)
    _phase_labels(vel, phases, scale)


def _phase_labels(ax: Axes, phases: tuple[Phase, ...], scale: float) -> None:
    """Each phase's name above the velocity chart, where its span is wide enough for one."""
    lo, hi = ax.get_xlim()
    width_pt = ax.get_position().width * A4[0] * 72
    for ph in phases:
        a, b = max(ph.start / scale, lo), min(ph.end / scale, hi)
        span = (b - a) / (hi - lo) * width_pt
        if span < 18:  # a 20 s interval in an hour: the table lists it
            continue
        label, mid = fit_text(ph.name, span - 4, 6), (a + b) / 2
        ax.text(
            mid,
            1.02,
            label,
            transform=ax.get_xaxis_transform(),
            ha="center",
            size=6,
            parse_math=False,
        )


def _min_span(ax: Axes, span: float = 1e-3) -> None:
    """A steady signal gets a y range of at least ``span`` relative (or absolute near zero),
    not tick labels repeating one value over a zigzag of rounding noise."""
    lo, hi = ax.get_ylim()
    need = span * max(abs(lo), abs(hi), 1.0)
    if hi - lo < need:
        mid = (lo + hi) / 2
        ax.set_ylim(mid - need / 2, mid + need / 2)


def _check(d: ReportData) -> tuple[dict[str, np.ndarray], tuple[Phase, ...]]:
    if not isinstance(d.started_at, datetime) or d.started_at.tzinfo is None:
        raise ExportError("started_at: must be a timezone-aware datetime")
    if d.velocity_unit not in VELOCITY_UNITS:
        raise ExportError(
            f"velocity_unit: must be one of {list(VELOCITY_UNITS)}, got {d.velocity_unit!r}"
        )
    if d.body_mass_kg is not None and not (math.isfinite(d.body_mass_kg) and d.body_mass_kg > 0):
        raise ExportError(f"body_mass_kg: must be a positive number or None, got {d.body_mass_kg}")
    cols = telemetry_columns(d.telemetry, CHANNELS)
    if not len(cols["t"]):
        raise ExportError("telemetry: no samples")
    return cols, check_phases(d.phases)


@contextmanager
def missing_glyphs_quiet() -> Iterator[None]:
    """Glyphs the bundled font lacks (CJK, emoji) print as boxes, each with a warning that
    says only that: silenced while a page is built and drawn."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from font")
        yield


def report_figure(d: ReportData) -> Figure:
    """The report's page as a matplotlib figure (A4 portrait), for the PDF or a preview image."""
    with missing_glyphs_quiet():
        return _page(d)


def _page(d: ReportData) -> Figure:
    cols, phases = _check(d)
    fig = Figure(figsize=A4)
    _header(fig, d)
    _figures(fig, d)
    _phase_table(fig, d, phases)
    _search_chart(fig.add_axes((0.08, 0.46, 0.24, 0.17)), d)
    if d.profile is None:
        _no_profile(fig.add_axes((0.40, 0.46, 0.54, 0.17)))
    else:
        tv, pv = fig.add_axes((0.41, 0.46, 0.24, 0.17)), fig.add_axes((0.72, 0.46, 0.24, 0.17))
        _profile_charts(tv, pv, d)
    axes = [fig.add_axes((0.11, 0.075 + i * 0.082, 0.83, 0.075)) for i in (3, 2, 1, 0)]
    _time_charts(axes, d, cols, phases)
    for ax in fig.axes:
        ax.tick_params(labelsize=6.5, length=2.5)
        ax.yaxis.set_major_locator(MaxNLocator(nbins=4))
        ax.xaxis.set_major_locator(MaxNLocator(nbins=6))
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    footer = f"ergoseek · generated {stamp} · velocities in {d.velocity_unit}"
    fig.text(0.06, 0.02, footer, size=6.5, color="#777777")
    return fig


def render_report(d: ReportData) -> bytes:
    """The one-page A4 PDF report of a session (see the module's docstring). Glyphs the
    bundled font lacks (CJK, emoji) print as boxes, their text still in the PDF's text layer."""
    with missing_glyphs_quiet():
        fig = _page(d)
        FigureCanvasPdf(fig)
        buf = io.BytesIO()
        meta = {"Title": f"Session report: {d.user_name}", "Creator": "ergoseek"}
        fig.savefig(buf, format="pdf", metadata=meta)
    return buf.getvalue()


def write_report(path: str | Path, d: ReportData) -> int:
    """:func:`render_report` to ``path``, atomically; returns its size in bytes."""
    data = render_report(d)
    return write_atomically(path, data)
