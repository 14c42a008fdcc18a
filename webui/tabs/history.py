"""The History tab: a user's sessions, their optimum across sessions, any past session's
charts (the store's telemetry decimated to 2000 points, min/max kept) and its CSV download.

Everything here only reads, so the viewers' dashboard has it too. Loads run on the dashboard's
I/O threads, never on viser's loop nor the web process's."""

from __future__ import annotations

import numpy as np
import viser

from sessions.store import NotFoundError, SessionRecord, UserRecord
from sessions.telemetry import NAMES
from webui.charts import HISTORY_POINTS, SessionCharts, plottable, trend_chart, trend_scales
from webui.context import Context

NO_SESSIONS = "(no sessions)"
SESSION_LIMIT = 50


def session_label(s: SessionRecord) -> str:
    optimum = f" · {s.optimum_w:.3f} rad/s" if s.optimum_w is not None else ""
    when = s.started_at.strftime("%Y-%m-%d %H:%M")
    return f"#{s.id} · {when} · {s.status}{optimum}"


def session_markdown(s: SessionRecord) -> str:
    cfg = s.config
    seeker = cfg.get("seeker", {}) if isinstance(cfg, dict) else {}
    controller = cfg.get("controller", {}) if isinstance(cfg, dict) else {}
    optimum = (
        f"**{s.optimum_w:.3f} rad/s** ({s.optimum_p:.3f} W){' converged' if s.converged else ''}"
        if s.optimum_w is not None and s.optimum_p is not None
        else "none"
    )
    lines = [
        f"Session **#{s.id}** · {s.status}" + (f" ({s.abort_reason})" if s.abort_reason else ""),
        f"{controller.get('kind', '?')} controller · {seeker.get('kind', '?')} seeker · "
        f"{s.duration:.1f} s · {s.evaluation_count} evaluations",
        f"Optimum: {optimum}",
        f"Mean power {s.mean_power:.3f} W · peak {s.peak_power:.3f} W · work {s.work:.1f} J · "
        f"min W(t) {s.passivity_min:.3g} J",
        f"[Download CSV (full rate)](/api/v1/sessions/{s.id}/telemetry.csv)",
    ]
    return "  \n".join(lines)


class HistoryTab:
    def __init__(self, gui: viser.GuiApi, ctx: Context) -> None:
        self.ctx = ctx
        self.user = gui.add_dropdown("History of", ctx.user_options())
        self.summary = gui.add_markdown("Pick a user.")
        self.trend = trend_chart(gui)
        self.session = gui.add_dropdown("Session", (NO_SESSIONS,))
        self.detail = gui.add_markdown(" ")
        self.charts = SessionCharts(gui)
        self.user.on_update(lambda _: ctx.background(self.load_user))
        self.session.on_update(lambda _: ctx.background(self.load_session))
        self._sessions: dict[str, int] = {}

    def load_user(self) -> None:
        user = self.ctx.user_by_label(self.user.value)
        if user is None:
            self.summary.content = "Pick a user."
            self._sessions = {}
            self.session.options = (NO_SESSIONS,)
            return
        store = self.ctx.store
        page = store.sessions.list(user_id=user.id, limit=SESSION_LIMIT)
        history = store.setpoints.history(user.id)
        current = store.setpoints.current(user.id)
        count = f"{page.total} session" + ("s" if page.total != 1 else "")
        head = f"**{user.name}** · {count}"
        if current is not None:
            head += f" · current optimum **{current.velocity:.3f} rad/s**"
        lines = [head]
        if page.items:
            lines.append("")
            lines.append("| # | started | status | optimum |")
            lines.append("|---|---|---|---|")
            for s in page.items[:10]:
                opt = f"{s.optimum_w:.3f}" if s.optimum_w is not None else "—"
                lines.append(
                    f"| {s.id} | {s.started_at.strftime('%m-%d %H:%M:%S')} | {s.status} | {opt} |"
                )
        self.summary.content = "\n".join(lines)
        ordered = sorted(history, key=lambda r: r.created_at)
        when = np.array([r.created_at.timestamp() for r in ordered], dtype=np.float64)
        self.trend.scales = trend_scales(when)
        self.trend.data = plottable(
            (when, np.array([r.velocity for r in ordered], dtype=np.float64))
        )
        self._sessions = {session_label(s): s.id for s in page.items}
        previous = self.session.value
        self.session.options = tuple(self._sessions) or (NO_SESSIONS,)
        if self.session.value == previous:  # options kept it: reload it anyway (it may have ended)
            self.load_session()

    def load_session(self) -> None:
        session_id = self._sessions.get(self.session.value)
        if session_id is None:
            self.detail.content = " "
            self.charts.clear()
            return
        store = self.ctx.store
        try:
            record = store.sessions.get(session_id)
            data = store.telemetry.load(session_id, points=HISTORY_POINTS)
        except NotFoundError:
            self.detail.content = f"Session #{session_id} is gone."
            return
        self.detail.content = session_markdown(record) + (
            f"  \nCharts: {len(data)} of {data.samples} samples"
            + (" (min/max per bucket)" if data.decimated else "")
        )
        self.charts.show({name: data.columns[i] for i, name in enumerate(NAMES)})

    def users_changed(self, options: tuple[str, ...], select: UserRecord | None) -> None:
        current = self.user.value
        self.user.options = options
        if current in options and self.user.value != current:
            self.user.value = current
        self.ctx.background(self.load_user)

    def session_finished(self, record: SessionRecord) -> None:
        user = self.ctx.user_by_label(self.user.value)
        if user is not None and user.id == record.user_id:
            self.load_user()
