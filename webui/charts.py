"""uPlot charts: the live window (last 10 s, at most 500 points), a past session's telemetry,
the seeker's power-vs-velocity picture and the setpoint trend.

Every chart update resends the whole window, so windows stay small: the live charts hold the
last :data:`WINDOW_S` seconds sampled at :data:`SAMPLE_RATE` (a LiveHub subscription at that
rate), and a past session is read from the store decimated to :data:`HISTORY_POINTS`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import viser
import viser.uplot as up

from sessions.telemetry import RECORD_INDEX

WINDOW_S = 10.0  # s of live data on screen
SAMPLE_RATE = 50.0  # samples per second in the live window
MAX_POINTS = 500  # at most this many points per live series
HISTORY_POINTS = 2000  # a past session, decimated by the store (min/max pairs)

# The channels of a live record (sessions.telemetry) the live window keeps, in this order.
LIVE_COLUMNS: tuple[str, ...] = (
    "t",
    "q",
    "w",
    "wd",
    "u_out",
    "tau",
    "p",
    "W",
    "gamma",
    "phase",
    "flags",
    "session",
)
LIVE = {name: i for i, name in enumerate(LIVE_COLUMNS)}
_RECORD_COLS = np.array([RECORD_INDEX[name] for name in LIVE_COLUMNS])

NUMBERS = {"time": False}
AXIS_GREY = "#888"


class LiveWindow:
    """The last ``seconds`` of one session's samples (rows of :data:`LIVE_COLUMNS`). A sample
    of another worker session starts the window afresh."""

    def __init__(self, seconds: float = WINDOW_S, max_points: int = MAX_POINTS) -> None:
        self.seconds = seconds
        self.max_points = max_points
        self.rows = np.empty((0, len(LIVE_COLUMNS)))

    def extend(self, records: np.ndarray) -> None:
        """Live records (all their channels, as the hub publishes them) of one or more
        sessions."""
        if not len(records):
            return
        new = records[:, _RECORD_COLS]
        session = new[:, LIVE["session"]]
        change = np.flatnonzero(session != session[-1])
        if len(change):  # keep only the newest session's samples
            new = new[change[-1] + 1 :]
        if len(self.rows) and self.rows[-1, LIVE["session"]] != session[-1]:
            self.rows = self.rows[:0]
        rows = np.concatenate((self.rows, new)) if len(self.rows) else new
        t = rows[:, LIVE["t"]]
        keep = t >= t[-1] - self.seconds
        rows = rows[keep] if not keep.all() else rows
        self.rows = rows[-4 * self.max_points :]

    def clear(self) -> None:
        self.rows = self.rows[:0]

    @property
    def last(self) -> np.ndarray | None:
        return self.rows[-1] if len(self.rows) else None

    def series(self, *names: str) -> tuple[np.ndarray, ...]:
        """Columns for a chart, thinned to at most ``max_points`` (every k-th sample, the
        newest always kept). NaN (no value, e.g. wd during the stop ramp) stays NaN."""
        rows = self.rows
        n = len(rows)
        if n > self.max_points:
            k = -(-n // self.max_points)
            rows = rows[(n - 1) % k :: k]
        return plottable(tuple(rows[:, LIVE[name]] for name in names))


# uPlot as viser 1.1.1 ships it has two traps, both found in a browser:
# - a chart given zero points never draws again, whatever it gets later;
# - an auto-ranged series whose first point is NaN makes its y range NaN (nothing drawn).
# NaN elsewhere is fine (uPlot joins the points around it).
def nonempty(data: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """Zero points become two NaN points at x = 0, 1 (nothing drawn, the chart alive)."""
    if len(data[0]):
        return data
    return (np.array([0.0, 1.0]), *(np.full(2, np.nan) for _ in data[1:]))


def lead_finite(col: np.ndarray) -> np.ndarray:
    """Leading NaNs take the first finite value (all NaN: zeros), so uPlot can range it."""
    col = np.ascontiguousarray(col, dtype=np.float64)
    if not len(col) or np.isfinite(col[0]):
        return col
    finite = np.flatnonzero(np.isfinite(col))
    out = col.copy()
    if not len(finite):
        out[:] = 0.0
    else:
        out[: finite[0]] = col[finite[0]]
    return out


def plottable(data: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """A time-series chart's arrays, safe for viser's uPlot (see above)."""
    if not len(data[0]):
        return nonempty(data)
    return (np.ascontiguousarray(data[0], dtype=np.float64), *map(lead_finite, data[1:]))


def span_range(*ys: np.ndarray, min_span: float = 1.0) -> tuple[float, float]:
    """A y range over the finite values of ``ys``, 5 % padded, at least ``min_span`` wide,
    its ends on multiples of ``min_span / 4`` (so it moves only when the data leaves it)."""
    finite = [y[np.isfinite(y)] for y in ys if len(y)]
    values = np.concatenate(finite) if finite else np.zeros(0)
    if not len(values):
        return (0.0, float(min_span))
    lo, hi = float(values.min()), float(values.max())
    pad = 0.05 * (hi - lo)
    lo, hi = lo - pad, hi + pad
    if hi - lo < min_span:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 0.5 * min_span, mid + 0.5 * min_span
    step = min_span / 4.0
    return (float(np.floor(lo / step) * step), float(np.ceil(hi / step) * step))


def min_span_scales(*ys: np.ndarray, min_span: float = 1.0) -> dict[str, up.Scale]:
    """A time chart's scales with the y range of :func:`span_range`."""
    return {
        "x": up.Scale(time=False),
        "y": up.Scale(auto=False, range=span_range(*ys, min_span=min_span)),
    }


# Minimum y spans of the time charts (their units): a steady signal is drawn flat in a range
# this wide, not magnified until uPlot's 3-decimal tick labels repeat ("3.095" three times).
VELOCITY_SPAN = 0.5  # rad/s
TORQUE_SPAN = 0.5  # N·m
POWER_SPAN = 1.0  # W
WORK_SPAN = 1.0  # J


def finite_extent(*ys: np.ndarray) -> tuple[float, float] | None:
    """(min, max) over the finite values of ``ys``; None without any."""
    lo, hi = math.inf, -math.inf
    for y in ys:
        finite = y[np.isfinite(y)]
        if len(finite):
            lo, hi = min(lo, float(finite.min())), max(hi, float(finite.max()))
    return (lo, hi) if lo <= hi else None


class SpanClass:
    """A time chart's minimum y span, by class: none while the data spans at least
    ``min_span`` (uPlot's own range); below that, a fixed range of :func:`span_range`, kept
    while the data stays inside it.

    The range reaches the chart as data, never as its scales: a last, invisible series
    (:func:`span_pad`) holds the range's two ends, and uPlot's auto range takes them in. (In
    viser 1.1.1's client a change of a chart's scales rebuilds the chart, and a chart rebuilt
    under a stream of data can keep an old x range and stop showing the new data.) So the
    frame stays one message, and the chart is never rebuilt."""

    def __init__(self, min_span: float) -> None:
        self.min_span = min_span
        self.fixed: tuple[float, float] | None = None  # None: uPlot's own range

    def update(self, *ys: np.ndarray) -> tuple[float, float] | None:
        """The class for this frame's data (kept when there is nothing to range)."""
        extent = finite_extent(*ys)
        if extent is None:
            return self.fixed
        lo, hi = extent
        if self.fixed is not None and self.fixed[0] <= lo and hi <= self.fixed[1]:
            return self.fixed
        narrow = 1.1 * (hi - lo) < self.min_span  # padded 5 % each side, as span_range pads
        self.fixed = span_range(*ys, min_span=self.min_span) if narrow else None
        return self.fixed

    def pad(self, *data: np.ndarray) -> tuple[np.ndarray, ...]:
        """``data`` (x and its series) with the span series appended."""
        fixed = self.update(*data[1:])
        return (*data, span_pad(len(data[0]), fixed, finite_extent(*data[1:])))


def span_pad(
    n: int, fixed: tuple[float, float] | None, extent: tuple[float, float] | None
) -> np.ndarray:
    """The invisible series: the fixed range's ends at the first and last x, NaN between;
    without a fixed range the data's own extent (inside uPlot's range: changes nothing). Its
    first point is finite whenever the chart has data (the leading-NaN trap above)."""
    out = np.full(n, np.nan)
    if extent is not None and n:  # (no data: nothing to span, the chart stays empty)
        out[0], out[-1] = fixed if fixed is not None else extent
    return out


SPAN_SERIES = up.Series(
    label="(y span)", stroke="rgba(0,0,0,0)", width=0, points=up.Series_Points(show=False)
)  # the span's: never drawn. Its legend row stays: hiding it takes a `:has()` rule, which
# made Chromium restyle the dashboard so often that its tabs appeared 20-40 s late here


def series(label: str, stroke: str, **extra: Any) -> up.Series:
    return up.Series(label=label, stroke=stroke, width=1.5, **extra)  # type: ignore[typeddict-item]


def time_chart(
    gui: viser.GuiApi,
    title: str,
    labels: Sequence[tuple[str, str]],
    *,
    height: int = 150,
    x: str = "t [s]",
    spanned: bool = False,
) -> viser.GuiUplotHandle:
    """A chart of several series against time (seconds, not dates); ``spanned``: with the
    minimum span's series last (:class:`SpanClass`)."""
    extra = (SPAN_SERIES,) if spanned else ()
    return gui.add_uplot(
        data=nonempty((np.zeros(0),) * (len(labels) + 1 + len(extra))),
        series=(up.Series(label=x), *(series(name, color) for name, color in labels), *extra),
        title=title,
        scales={"x": up.Scale(time=False)},
        height=height,
        legend=up.Legend(show=True),
    )


class SpannedCharts:
    """The four time charts (velocity, torque, power, passivity), each with its
    :class:`SpanClass`: :meth:`plot` sends a chart its data with the span series."""

    velocity: viser.GuiUplotHandle
    torque: viser.GuiUplotHandle
    power: viser.GuiUplotHandle
    passivity: viser.GuiUplotHandle

    def _spans(self) -> None:
        self.spans = {
            "velocity": SpanClass(VELOCITY_SPAN),
            "torque": SpanClass(TORQUE_SPAN),
            "power": SpanClass(POWER_SPAN),
            "passivity": SpanClass(WORK_SPAN),
        }

    def plot(self, name: str, data: tuple[np.ndarray, ...]) -> None:
        getattr(self, name).data = self.spans[name].pad(*data)


class LiveCharts(SpannedCharts):
    """Velocity, torque, power and passivity over the live window."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self.velocity = time_chart(
            gui, "velocity [rad/s]", (("desired wd", "#1c7ed6"), ("actual w", "#e8590c")),
            spanned=True,
        )  # fmt: skip
        self.torque = time_chart(
            gui, "torque [N·m]", (("motor u (written)", "#c2255c"), ("user τ̂", "#2f9e44")),
            spanned=True,
        )  # fmt: skip
        self.power = time_chart(gui, "power p [W]", (("p", "#7048e8"),), spanned=True)
        self.passivity = time_chart(gui, "passivity W(t) = ∫τw dt [J]", (("W", "#495057"),),
                                    spanned=True)  # fmt: skip
        self._spans()
        self._measured: bool | None = None

    def label_user_torque(self, measured: bool) -> None:
        if measured == self._measured:
            return
        self._measured = measured
        name = "user τ (measured)" if measured else "user τ̂ (observed)"
        self.torque.series = (
            up.Series(label="t [s]"),
            series("motor u (written)", "#c2255c"),
            series(name, "#2f9e44"),
            SPAN_SERIES,
        )

    def show(self, window: LiveWindow) -> None:
        t, wd, w, u, tau, p, W = window.series("t", "wd", "w", "u_out", "tau", "p", "W")
        self.plot("velocity", (t, wd, w))
        self.plot("torque", (t, u, tau))
        self.plot("power", (t, p))
        self.plot("passivity", (t, W))


class SessionCharts(SpannedCharts):
    """A past session, from the store's decimated telemetry (the same four charts)."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self.velocity = time_chart(
            gui, "velocity [rad/s]", (("desired wd", "#1c7ed6"), ("actual w", "#e8590c")),
            spanned=True,
        )  # fmt: skip
        self.torque = time_chart(
            gui, "torque [N·m]", (("motor u", "#c2255c"), ("user τ̂", "#2f9e44")), spanned=True
        )
        self.power = time_chart(gui, "power p [W]", (("p", "#7048e8"),), spanned=True)
        self.passivity = time_chart(gui, "passivity W(t) [J]", (("W", "#495057"),), spanned=True)
        self._spans()

    def show(self, columns: dict[str, np.ndarray]) -> None:
        def c(name: str) -> np.ndarray:
            return np.ascontiguousarray(columns.get(name, np.zeros(0)), dtype=np.float64)

        t = c("t")
        self.plot("velocity", plottable((t, c("wd"), c("w"))))
        self.plot("torque", plottable((t, c("u"), c("tau"))))
        self.plot("power", plottable((t, c("p"))))
        self.plot("passivity", plottable((t, c("W"))))

    def clear(self) -> None:
        self.show({})


def seeker_data(
    evaluations: Sequence[tuple[float, float]],
    bracket: tuple[float, float] | None,
    best: tuple[float, float] | None,
) -> tuple[np.ndarray, ...]:
    """(x, measured p, best, bracket) for the power-vs-velocity chart: x holds every
    candidate and both bracket ends, sorted; a series is NaN where it has no point. The
    chart's series are not auto-ranged (:func:`seeker_range` gives the y range), so NaN
    anywhere is harmless."""
    xs = {round(c, 6) for c, _ in evaluations}
    if bracket is not None:
        xs.update((round(bracket[0], 6), round(bracket[1], 6)))
    x = np.array(sorted(xs), dtype=np.float64)
    measured = np.full(len(x), np.nan)
    for c, p in evaluations:  # the last measurement at a velocity wins
        measured[np.searchsorted(x, round(c, 6))] = p
    top = np.full(len(x), np.nan)
    if best is not None and len(x):
        top[np.searchsorted(x, round(best[0], 6))] = best[1]
    edge = np.full(len(x), np.nan)
    if bracket is not None and evaluations:
        floor = min(p for _, p in evaluations)
        edge[np.searchsorted(x, round(bracket[0], 6))] = floor
        edge[np.searchsorted(x, round(bracket[1], 6))] = floor
    return nonempty((x, measured, top, edge))


def seeker_range(evaluations: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """The power axis: the measured powers with 10 % of their spread around them."""
    powers = [p for _, p in evaluations]
    if not powers:
        return (0.0, 1.0)
    lo, hi = min(powers), max(powers)
    pad = max(0.1 * (hi - lo), 1e-3 * max(abs(hi), 1.0))
    return (lo - pad, hi + pad)


def seeker_x_range(
    evaluations: Sequence[tuple[float, float]], bracket: tuple[float, float] | None
) -> tuple[float, float]:
    """The velocity axis: every candidate and the bracket, with 5 % of their spread around
    them. (Explicit: viser 1.1.1's client keeps an auto x range *relative* to the previous
    data, which leaves a chart whose x values move as the seeker's do showing the wrong
    stretch.)"""
    xs = [c for c, _ in evaluations] + list(bracket or ())
    if not xs:
        return (0.0, 1.0)
    lo, hi = min(xs), max(xs)
    pad = max(0.05 * (hi - lo), 0.05)
    return (lo - pad, hi + pad)


def seeker_scales(
    evaluations: Sequence[tuple[float, float]], bracket: tuple[float, float] | None = None
) -> dict[str, up.Scale]:
    return {
        "x": up.Scale(time=False, auto=False, range=seeker_x_range(evaluations, bracket)),
        "y": up.Scale(auto=False, range=seeker_range(evaluations)),
    }


def seeker_chart(gui: viser.GuiApi) -> viser.GuiUplotHandle:
    return gui.add_uplot(
        data=nonempty((np.zeros(0),) * 4),
        series=(
            up.Series(label="velocity [rad/s]"),
            up.Series(
                label="measured p [W]",
                stroke="#7048e8",
                width=1,
                auto=False,
                points=up.Series_Points(show=True, size=7),
            ),
            up.Series(
                label="best",
                stroke="#e03131",
                width=0,
                auto=False,
                points=up.Series_Points(show=True, size=12, fill="#e03131"),
            ),
            up.Series(
                label="bracket",
                stroke="#f08c00",
                width=3,
                auto=False,
                spanGaps=True,
                points=up.Series_Points(show=True, size=6),
            ),
        ),
        title="seeker: power vs velocity",
        scales=seeker_scales(()),
        height=200,
    )


def trend_chart(gui: viser.GuiApi) -> viser.GuiUplotHandle:
    """A user's setpoints across sessions: velocity against date."""
    return gui.add_uplot(
        data=nonempty((np.zeros(0),) * 2),
        series=(
            up.Series(label="date"),
            up.Series(
                label="optimum",
                stroke="#1c7ed6",
                width=1.5,
                points=up.Series_Points(show=True, size=7),
            ),
        ),
        title="setpoint trend",
        scales=trend_scales(np.zeros(0)),
        height=160,
    )


def trend_scales(when: np.ndarray) -> dict[str, up.Scale]:
    """Dates of the setpoints, padded: uPlot spreads a lone point over years otherwise."""
    if not len(when):
        return {"x": up.Scale(time=True)}
    lo, hi = float(when.min()), float(when.max())
    pad = max(0.05 * (hi - lo), 3600.0)
    return {"x": up.Scale(time=True, auto=False, range=(lo - pad, hi + pad))}
