"""The History tab: a user's sessions, their optimum across sessions, any past session's
charts (the store's telemetry decimated to 2000 points, min/max kept) and its CSV download.

Everything here only reads, so the viewers' dashboard has it too. Each browser has its own
(its picks are its own). Loads run on the dashboard's I/O threads, never on viser's loop nor
the web process's."""

from __future__ import annotations

import numpy as np
import viser

from server.service.phases import session_phases
from sessions.store import NotFoundError, SessionRecord, UserRecord
from sessions.telemetry import NAMES
from webui.charts import HISTORY_POINTS, SessionCharts, plottable, trend_chart, trend_scales
from webui.context import Context, relabel
from webui.escape import Markdown, MarkdownBox, md, md_join, md_lines
from webui.tabs.phases import PhasesPanel
from webui.tabs.progress import ProgressPanel
from webui.units import Units

NO_SESSIONS = "(no sessions)"
SESSION_LIMIT = 50


def session_label(s: SessionRecord, units: Units | None = None) -> str:
    optimum = f" · {(units or Units()).v(s.optimum_w)}" if s.optimum_w is not None else ""
    when = s.started_at.strftime("%Y-%m-%d %H:%M")
    return f"#{s.id} · {when} · {s.status}{optimum}"


def session_markdown(s: SessionRecord, units: Units | None = None) -> Markdown:
    units = units or Units()
    cfg = s.config
    seeker = cfg.get("seeker", {}) if isinstance(cfg, dict) else {}
    controller = cfg.get("controller", {}) if isinstance(cfg, dict) else {}
    if s.optimum_w is not None and s.optimum_p is not None:
        converged = md(" converged") if s.converged else md("")
        optimum = md("**{}** ({:.3f} W){}", units.v(s.optimum_w), s.optimum_p, converged)
    else:
        optimum = md("none")
    reason = md(" ({})", s.abort_reason) if s.abort_reason else md("")
    search = search_markdown(s)
    lines = [
        md("Session **#{}** · {}{}", s.id, s.status, reason),
        md(
            "{} controller · {} seeker · {:.1f} s · {} evaluations",
            controller.get("kind", "?"),
            seeker.get("kind", "?"),
            s.duration,
            s.evaluation_count,
        ),
        md("Optimum: {}", optimum),
        *search,
        md(
            "Mean power {:.3f} W · peak {:.3f} W · work {:.1f} J · min W(t) {:.3g} J",
            s.mean_power,
            s.peak_power,
            s.work,
            s.passivity_min,
        ),
        md(
            "[Download report (PDF)](/api/v1/sessions/{}/report.pdf) · "
            "[Download activity (FIT)](/api/v1/sessions/{}/activity.fit) · "
            "[Download CSV (full rate)](/api/v1/sessions/{}/telemetry.csv)",
            int(s.id),
            int(s.id),
            int(s.id),
        ),
    ]
    return md_lines(lines)


def search_markdown(s: SessionRecord) -> list[Markdown]:
    """The search's figures: a hint to widen the bracket when the best point lay at a bound
    (not stored as the user's optimum), when and where it first converged, its targets."""
    lines = []
    if s.at_bound is not None:
        lines.append(
            md(
                "**The best point is at the {} bound** and the power still rises beyond it: "
                "not an optimum (not stored). Widen the bracket's {} end.",
                s.at_bound,
                s.at_bound,
            )
        )
    if s.t_converged is not None and s.wd_converged is not None:
        lines.append(
            md("First converged at {:.1f} s on {:.3f} rad/s", s.t_converged, s.wd_converged)
        )
    if s.target_min is not None and s.target_max is not None:
        lines.append(md("Targets {:.3f}–{:.3f} rad/s", s.target_min, s.target_max))
    return lines


def sessions_table(
    user: UserRecord,
    total: int,
    sessions: list[SessionRecord],
    velocity: float | None,
    units: Units | None = None,
) -> Markdown:
    """A user's head line and their latest sessions as a table."""
    units = units or Units()
    count = md("{} session{}", total, "" if total == 1 else "s")
    current = md(" · current optimum **{}**", units.v(velocity)) if velocity is not None else md("")
    lines = [md("**{}** · {}{}", user.name, count, current)]
    if sessions:
        head = md("| # | started | status | optimum [{}] |", units.label)
        lines += [md(""), head, md("|---|---|---|---|")]
        for s in sessions[:10]:
            opt = units.number(s.optimum_w)
            if s.at_bound is not None:
                opt += f" (at the {s.at_bound} bound)"
            started = s.started_at.strftime("%m-%d %H:%M:%S")
            lines.append(md("| {} | {} | {} | {} |", s.id, started, s.status, opt))
    return md_join("\n", lines)


class HistoryTab:
    def __init__(self, gui: viser.GuiApi, ctx: Context, units: Units) -> None:
        self.ctx = ctx
        self.units = units
        self.user = gui.add_dropdown("History of", ctx.user_options())
        self.summary = MarkdownBox(gui, md("Pick a user."))
        self.trend = trend_chart(gui)
        self.trend.visible = False
        self.progress = ProgressPanel(gui, ctx, units)
        self.session = gui.add_dropdown("Session", (NO_SESSIONS,))
        self.detail = MarkdownBox(gui, md(" "))
        self.phases = PhasesPanel(gui, units)
        self.charts = SessionCharts(gui)
        self.user.on_update(lambda _: ctx.background(self.load_user))
        self.session.on_update(lambda _: ctx.background(self.load_session))
        self._sessions: dict[str, int] = {}

    def load_user(self) -> None:
        user = self.ctx.user_by_label(self.user.value)
        if user is None:
            self.summary.show(md("Pick a user, or add one in the Users tab."))
            self.progress.hide("Pick a user to see their progress.")
            self._sessions = {}
            self.session.options = (NO_SESSIONS,)
            return
        store = self.ctx.store
        page = store.sessions.list(user_id=user.id, limit=SESSION_LIMIT)
        history = store.setpoints.history(user.id)
        current = store.setpoints.current(user.id)
        velocity = current.velocity if current is not None else None
        table = sessions_table(user, page.total, page.items, velocity, self.units)
        if not history:
            table = md_lines([table, md("No optimum stored yet: run a session to find one.")])
        self.summary.show(table)
        ordered = sorted(history, key=lambda r: r.created_at)
        when = np.array([r.created_at.timestamp() for r in ordered], dtype=np.float64)
        self.trend.scales = trend_scales(when)
        self.trend.data = plottable(
            (when, np.array([r.velocity for r in ordered], dtype=np.float64) * self.units.factor)
        )
        self.trend.visible = bool(history)
        self.trend.title = f"setpoint trend: optimum [{self.units.label}]"
        self._sessions = {session_label(s, self.units): s.id for s in page.items}
        self.progress.show(user, page.items, self._sessions)
        previous = self.session.value
        self.session.options = tuple(self._sessions) or (NO_SESSIONS,)
        if self.session.value == previous:  # options kept it: reload it anyway (it may have ended)
            self.load_session()

    def load_session(self) -> None:
        session_id = self._sessions.get(self.session.value)
        if session_id is None:
            self.detail.show(md(" "))
            self.phases.clear()
            self.charts.clear()
            return
        store = self.ctx.store
        try:
            record = store.sessions.get(session_id)
            data = store.telemetry.load(session_id, points=HISTORY_POINTS)
            phases = session_phases(store, session_id)
        except NotFoundError:
            self.detail.show(md("Session #{} is gone.", session_id))
            self.phases.clear()
            return
        bucket = md(" (min/max per bucket)") if data.decimated else md("")
        charts = md("Charts: {} of {} samples{}", len(data), data.samples, bucket)
        self.detail.show(md_lines([session_markdown(record, self.units), charts]))
        self.phases.show(phases)
        self.charts.show({name: data.columns[i] for i, name in enumerate(NAMES)})

    def users_changed(self, options: tuple[str, ...]) -> None:
        keep = relabel(self.user.value, options)
        self.user.options = options
        if keep is not None and self.user.value != keep:
            self.user.value = keep
        self.ctx.background(self.load_user)

    def session_finished(self, record: SessionRecord) -> None:
        user = self.ctx.user_by_label(self.user.value)
        if user is not None and user.id == record.user_id:
            self.load_user()
