"""History's progress across sessions and the overlay of two sessions, for one browser.

Progress (:func:`server.service.progress.progress`, what ``GET /api/v1/users/{id}/progress``
serves): per ended session the optimum first found and at the end, peak and mean power (W and,
where the user's body mass is known, W/kg) and the profile phases' fits (τ0, wmax, w_opt,
Pmax). Overlay (:mod:`server.service.progress`, as ``/api/v1/sessions/{id}/overlay``): two
sessions' bucket means on one time axis, aligned at their start or at a phase. Velocities are
shown in the browser's unit. Empty charts are hidden and a line says what to do instead."""

from __future__ import annotations

from typing import Any

import numpy as np
import viser
import viser.uplot as up

from server.service.progress import ALIGNMENTS, alignment, bucket_means, overlay_grid, progress
from sessions.requests import RequestError
from sessions.store import NotFoundError, ProgressPoint, SessionRecord, UserRecord
from webui.charts import min_span_scales, nonempty, plottable, time_chart, trend_scales
from webui.context import Context
from webui.escape import MarkdownBox, md
from webui.units import Units

OVERLAY_POINTS = 600
NO_OTHER = "(pick a second session)"
SESSIONS_ON_CHART = 200


def date_chart(gui: viser.GuiApi, title: str, labels: tuple[tuple[str, str], ...]) -> Any:
    """Values against the sessions' start dates (points joined)."""
    return gui.add_uplot(
        data=nonempty((np.zeros(0),) * (len(labels) + 1)),
        series=(
            up.Series(label="date"),
            *(
                up.Series(
                    label=name, stroke=color, width=1.5, points=up.Series_Points(show=True, size=6)
                )
                for name, color in labels
            ),
        ),
        title=title,
        scales=trend_scales(np.zeros(0)),
        height=150,
        visible=False,
    )


def estimate(fits: list[dict[str, Any]], key: str) -> float:
    """A session's last profile fit's value of ``key`` (NaN without one)."""
    for fit in reversed(fits):
        value = (fit.get(key) or {}).get("value") if isinstance(fit.get(key), dict) else None
        if value is not None:
            return float(value)
    return np.nan


def column(points: list[ProgressPoint], get: Any) -> np.ndarray:
    return np.array([np.nan if (x := get(p)) is None else float(x) for p in points])


class ProgressPanel:
    """Inside the History tab, under the user's picker."""

    def __init__(self, gui: viser.GuiApi, ctx: Context, units: Units) -> None:
        self.ctx, self.units = ctx, units
        with gui.add_folder("Progress across sessions"):
            self.note = MarkdownBox(gui, md("Pick a user."))
            pair = (("found", "#1c7ed6"), ("at the end", "#e8590c"))
            self.optimum = date_chart(gui, self._optimum_title(), pair)
            self.power = date_chart(gui, "power [W]", (("peak", "#c2255c"), ("mean", "#7048e8")))
            self.per_kg = date_chart(gui, "power per body mass [W/kg]",
                                     (("peak", "#c2255c"), ("mean", "#7048e8")))  # fmt: skip
            self.profile = date_chart(gui, "profile fit: τ0 [N·m], Pmax [W]",
                                      (("τ0", "#2f9e44"), ("Pmax", "#f08c00")))  # fmt: skip
        with gui.add_folder("Overlay two sessions", expand_by_default=False):
            self.first = gui.add_dropdown("First", (NO_OTHER,))
            self.second = gui.add_dropdown("Second", (NO_OTHER,))
            self.align = gui.add_dropdown("Align at", ALIGNMENTS)
            self.go = gui.add_button("Overlay", icon=viser.Icon.CHART_LINE)
            self.overlay_note = MarkdownBox(gui, md("Pick two sessions, then Overlay."))
            self.ov_velocity = time_chart(gui, self._velocity_title(), (("first w", "#1c7ed6"),
                                          ("second w", "#e8590c")))  # fmt: skip
            self.ov_power = time_chart(gui, "power τ·w [W]", (("first", "#1c7ed6"),
                                       ("second", "#e8590c")))  # fmt: skip
        self.go.on_click(lambda _: ctx.background(self.overlay))
        self._labels: dict[str, int] = {}

    def _optimum_title(self) -> str:
        return f"optimum velocity [{self.units.label}]"

    def _velocity_title(self) -> str:
        return f"velocity [{self.units.label}], t from the alignment [s]"

    def show(self, user: UserRecord, sessions: list[SessionRecord], labels: dict[str, int]) -> None:
        """The user's progress (an I/O thread); ``labels`` name their sessions for the overlay."""
        record, _ = progress(self.ctx.store, user.id, since=None, until=None,
                             limit=SESSIONS_ON_CHART)  # fmt: skip
        points = record.sessions
        charts = (self.optimum, self.power, self.per_kg, self.profile)
        self._labels = labels
        options = tuple(labels) or (NO_OTHER,)
        self.first.options, self.second.options = options, options
        if len(options) > 1 and self.second.value == self.first.value:
            self.second.value = options[1]
        if not points:
            for chart in charts:
                chart.visible = False
            self.note.show(md("No ended sessions for {} yet: run a session (Live tab) and "
                              "its optimum and power appear here.", user.name))  # fmt: skip
            return
        when = np.array([p.started_at.timestamp() for p in points])
        f = self.units.factor
        mass = record.body_mass_kg
        found = column(points, lambda p: p.wd_converged) * f
        end = column(points, lambda p: p.optimum_w) * f
        self._plot(self.optimum, when, found, end, title=self._optimum_title())
        peak, mean = column(points, lambda p: p.peak_power), column(points, lambda p: p.mean_power)
        self._plot(self.power, when, peak, mean)
        self.per_kg.visible = bool(mass)
        if mass:
            self._plot(self.per_kg, when, peak / mass, mean / mass)
        tau0 = column(points, lambda p: estimate(p.profiles, "tau0"))
        self.profile.visible = bool(np.isfinite(tau0).any())
        if self.profile.visible:
            self._plot(self.profile, when, tau0,
                       column(points, lambda p: estimate(p.profiles, "pmax")))  # fmt: skip
        kg = md(" · W/kg with {:g} kg", mass) if mass else md(" · W/kg: add the body mass (Users)")
        self.note.show(md("{} ended session{}{}", len(points), "" if len(points) == 1 else "s", kg))

    @staticmethod
    def _plot(chart: Any, when: np.ndarray, *ys: np.ndarray, title: str | None = None) -> None:
        chart.scales = {**trend_scales(when), "y": min_span_scales(*ys)["y"]}
        chart.data = plottable((when, *ys))
        if title is not None:
            chart.title = title
        chart.visible = True

    def hide(self, text: str) -> None:
        for chart in (self.optimum, self.power, self.per_kg, self.profile):
            chart.visible = False
        self.note.show(md("{}", text))

    def overlay(self) -> None:
        """Both sessions' bucket means on one axis (an I/O thread)."""
        ids = (self._labels.get(self.first.value), self._labels.get(self.second.value))
        if ids[0] is None or ids[1] is None or ids[0] == ids[1]:
            self.overlay_note.show(md("Pick two different sessions, then Overlay."))
            return
        store, align = self.ctx.store, self.align.value
        pair = (int(ids[0]), int(ids[1]))
        try:
            offsets = (alignment(store, pair[0], align, "First"),
                       alignment(store, pair[1], align, "Second"))  # fmt: skip
            edges = overlay_grid(store, pair, offsets, OVERLAY_POINTS)
            means = [
                bucket_means(store, sid, off, edges)[0]
                for sid, off in zip(pair, offsets, strict=True)
            ]
        except RequestError as exc:
            self.overlay_note.show(md("Not overlaid: {}: {}", exc.field, exc.reason))
            return
        except NotFoundError as exc:
            self.overlay_note.show(md("Not overlaid: {}", exc))
            return
        t = 0.5 * (edges[:-1] + edges[1:])
        f = self.units.factor
        self.ov_velocity.title = self._velocity_title()
        self.ov_velocity.data = plottable((t, means[0]["w"] * f, means[1]["w"] * f))
        self.ov_power.data = plottable((t, means[0]["power"], means[1]["power"]))
        self.overlay_note.show(md("Sessions #{} and #{}, aligned at {}", pair[0], pair[1], align))
