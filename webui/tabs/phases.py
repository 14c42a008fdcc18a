"""History's view of one session's protocol phases, for one browser: each phase's stored
summary as a table (kind, duration, mean and peak power, work, the optimum it ended on and
whether that optimum is the bracket's edge) and, when the session had a profile phase, its
velocity-spectrum fit as a τ–v and a P–v chart (the fitted law with its confidence band, and
the step means it was fitted to). Velocities in the browser's unit; phase names are stored
strings, escaped by :func:`webui.escape.md` like every other."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import viser
import viser.uplot as up

from sessions.store import PhaseRecord
from webui.charts import nonempty
from webui.escape import Markdown, MarkdownBox, md, md_join
from webui.units import Units

EDGE = {"upper": "≥ ", "lower": "≤ "}  # as the PDF report writes an optimum at an edge


def phase_optimum(p: PhaseRecord, units: Units) -> Markdown:
    if p.optimum_w is None:
        return md("—")
    if p.at_bound is None:
        return md("{}", units.v(p.optimum_w))
    return md("{}{} (at the {} bound)", EDGE[p.at_bound], units.v(p.optimum_w), p.at_bound)


def _num(x: float | None, spec: str) -> str:
    return "—" if x is None or not math.isfinite(x) else format(x, spec)


def phases_markdown(phases: list[PhaseRecord], units: Units) -> Markdown:
    """The phases' summaries as a table (a phase still without one shows dashes)."""
    if not phases:
        return md("No protocol phases stored for this session.")
    rows = [
        md("**Phases**"),
        md(""),
        md("| # | phase | kind | duration [s] | mean P [W] | peak P [W] | work [J] | optimum |"),
        md("|---|---|---|---|---|---|---|---|"),
    ]
    for p in phases:
        duration = None if p.t_end is None else p.t_end - p.t_start
        rows.append(
            md(
                "| {} | {} | {} | {} | {} | {} | {} | {} |",
                p.position + 1,
                p.name or p.kind,
                p.kind,
                _num(duration, ".1f"),
                _num(p.mean_power, ".2f"),
                _num(p.peak_power, ".2f"),
                _num(p.work, ".1f"),
                phase_optimum(p, units),
            )
        )
    bounded = [p for p in phases if p.at_bound is not None]
    text = md_join("\n", rows)
    if bounded:
        note = md("≥ / ≤: the search ended at the bracket's edge; the peak lies beyond it.")
        text = md_join("\n\n", [text, note])  # a blank line ends the table
    return text


def profile_fit(phases: list[PhaseRecord]) -> tuple[PhaseRecord, dict[str, Any]] | None:
    """The session's last profile phase with a stored fit, and the fit (as stored)."""
    for p in reversed(phases):
        fit = p.detail.get("profile") if p.kind == "profile" else None
        if isinstance(fit, dict) and isinstance(fit.get("curve"), dict):
            return p, fit
    return None


def _arr(values: Any) -> np.ndarray:
    return np.array([np.nan if v is None else float(v) for v in (values or ())], dtype=np.float64)


def profile_series(fit: dict[str, Any], units: Units) -> dict[str, tuple[np.ndarray, ...]]:
    """The τ–v and P–v charts' data, velocity in the browser's unit: on one sorted x (the
    fit's grid and the steps' measured velocities), (x, fit, low, high, measured), each series
    NaN where it has no point."""
    curve = fit["curve"]
    w = _arr(curve.get("w"))
    steps = fit.get("steps") or []
    sw = _arr([s.get("w") for s in steps])
    stau = _arr([s.get("tau") for s in steps])
    x_si = np.concatenate((w, sw))
    order = np.argsort(x_si, kind="stable")
    n = len(w)
    x = x_si[order] * units.factor

    def series(keys: tuple[str, str, str], measured: np.ndarray) -> tuple[np.ndarray, ...]:
        fitted = [np.concatenate((_arr(curve.get(k)), np.full(len(sw), np.nan)))[order]
                  for k in keys]  # fmt: skip
        points = np.concatenate((np.full(n, np.nan), measured))[order]
        return nonempty((x, *fitted, points))

    return {
        "tau": series(("tau", "tau_low", "tau_high"), stau),
        "power": series(("power", "power_low", "power_high"), stau * sw),
    }


def _range(data: tuple[np.ndarray, ...]) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x range, y range from 0): every point and band of the chart, 5 % padded."""
    x = data[0][np.isfinite(data[0])]
    ys = np.concatenate([y[np.isfinite(y)] for y in data[1:]])
    x_lo, x_hi = (float(x.min()), float(x.max())) if len(x) else (0.0, 1.0)
    y_hi = float(ys.max()) if len(ys) else 1.0
    pad = max(0.05 * (x_hi - x_lo), 1e-3)
    return (x_lo - pad, x_hi + pad), (min(0.0, float(ys.min()) if len(ys) else 0.0),
                                      max(1.05 * y_hi, 1e-3))  # fmt: skip


def profile_chart(gui: viser.GuiApi, title: str, name: str) -> viser.GuiUplotHandle:
    band = {"stroke": "#74c0fc", "width": 1, "dash": [4, 3], "spanGaps": True, "auto": False}
    return gui.add_uplot(
        data=nonempty((np.zeros(0),) * 5),
        series=(
            up.Series(label="velocity"),
            up.Series(label=f"fitted {name}", stroke="#1c7ed6", width=2, spanGaps=True, auto=False),
            up.Series(label="95 % low", **band),  # type: ignore[typeddict-item]
            up.Series(label="95 % high", **band),  # type: ignore[typeddict-item]
            up.Series(
                label=f"measured {name}",
                stroke="#e8590c",
                width=0,
                auto=False,
                points=up.Series_Points(show=True, size=8, fill="#e8590c"),
            ),
        ),
        title=title,
        scales={
            "x": up.Scale(time=False, auto=False, range=(0.0, 1.0)),
            "y": up.Scale(auto=False, range=(0.0, 1.0)),
        },
        height=170,
        legend=up.Legend(show=True),
        visible=False,
    )


class PhasesPanel:
    """Inside the History tab, under the session's summary."""

    def __init__(self, gui: viser.GuiApi, units: Units) -> None:
        self.units = units
        self.table = MarkdownBox(gui, md(" "))
        self.profile_note = MarkdownBox(gui, md(" "))
        self.tau = profile_chart(gui, self._title("torque τ [N·m]"), "τ")
        self.power = profile_chart(gui, self._title("power P [W]"), "P")

    def _title(self, what: str) -> str:
        return f"profile: {what} vs velocity [{self.units.label}]"

    def show(self, phases: list[PhaseRecord]) -> None:
        self.table.show(phases_markdown(phases, self.units))
        found = profile_fit(phases)
        if found is None:
            self.hide_profile()
            return
        phase, fit = found
        data = profile_series(fit, self.units)
        for chart, key, what in ((self.tau, "tau", "torque τ [N·m]"),
                                 (self.power, "power", "power P [W]")):  # fmt: skip
            x_range, y_range = _range(data[key])
            chart.title = self._title(what)
            chart.scales = {"x": up.Scale(time=False, auto=False, range=x_range),
                            "y": up.Scale(auto=False, range=y_range)}  # fmt: skip
            chart.data = data[key]
            chart.visible = True
        self.profile_note.show(profile_markdown(phase, fit, self.units))

    def hide_profile(self) -> None:
        self.tau.visible = self.power.visible = False
        self.profile_note.show(md(" "))

    def clear(self) -> None:
        self.table.show(md(" "))
        self.hide_profile()


def profile_markdown(phase: PhaseRecord, fit: dict[str, Any], units: Units) -> Markdown:
    """The fitted parameters with their confidence intervals."""

    def est(key: str) -> dict[str, float] | None:
        value = fit.get(key)
        return value if isinstance(value, dict) and value.get("value") is not None else None

    parts = []
    for key, label, unit in (("tau0", "τ0", "N·m"), ("pmax", "Pmax", "W")):
        e = est(key)
        if e is not None:
            parts.append(md("{} {:.3g} {} ({:.3g}–{:.3g})", label, e["value"], unit,
                            e["low"], e["high"]))  # fmt: skip
    for key, label in (("wmax", "wmax"), ("w_opt", "w_opt")):
        e = est(key)
        if e is not None:
            parts.append(md("{} {} ({}–{})", label, units.v(e["value"]), units.number(e["low"]),
                            units.number(e["high"])))  # fmt: skip
    head = md("Profile **{}** ({} fit, {:.0f} % intervals): ", phase.name or phase.kind,
              fit.get("model", "?"), 100.0 * float(fit.get("confidence", 0.95)))  # fmt: skip
    return md("{}{}", head, md_join(" · ", parts))
