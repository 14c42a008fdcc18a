"""One dashboard on one viser server: the 3D machine in the middle, the live charts docked on
the left, and on the right the tabs Live, History and (for trainers) Users.

A view is built once; the feed thread calls :meth:`render` ~25 times a second while a browser
is connected (charts and the 3D handle every tick, text about 6 times a second, each only
when it changed)."""

from __future__ import annotations

import math

import viser

from sessions.store import SessionRecord, UserRecord
from webui.charts import LIVE, LiveCharts
from webui.context import Context
from webui.feed import LiveState
from webui.progress import SeekerPanel
from webui.scene import MachineScene
from webui.tabs.history import HistoryTab
from webui.tabs.live import LiveTab
from webui.tabs.users import UsersTab

TEXT_EVERY = 4  # ticks between text updates
CHARTS_WIDTH, MAIN_WIDTH = 540, 440  # px: the docked panels (charts left, tabs right)
SEEKER_WIDTH, SEEKER_HEIGHT = 470, 390  # px: the seeker's window, floating bottom-left
LOGOUT_HTML = (
    '<div style="display:flex;justify-content:space-between;align-items:center;'
    'padding:2px 0 6px 0;font-size:0.85em">'
    "<span>ergoseek · {role}</span>"
    '<a href="/?logout=1" role="button" aria-label="Log out" '
    'style="padding:3px 12px;border:1px solid #adb5bd;border-radius:4px;'
    'text-decoration:none;color:inherit">Log out</a></div>'
)


def readout(st: LiveState) -> str:
    row = st.window.last
    if row is None:
        return "No live data yet: start a session."

    def v(name: str, fmt: str) -> str:
        x = float(row[LIVE[name]])
        return format(x, fmt) if math.isfinite(x) else "—"

    measured = st.active is not None and st.active.cfg.controller.kind == "measured"
    tau = "τ" if measured else "τ̂"
    u = f"{0.0:+.3f} N·m (disarmed)" if st.disarmed else f"{v('u_out', '+.3f')} N·m"
    return (
        f"t = {v('t', '.2f')} s · w = {v('w', '.3f')} rad/s · wd = {v('wd', '.3f')} rad/s · "
        f"γ = {v('gamma', '.3f')} rad/s  \n"
        f"u = {u} · {tau} = {v('tau', '+.3f')} N·m · "
        f"p = {v('p', '.3f')} W · W = {v('W', '.2f')} J"
    )


class View:
    def __init__(self, server: viser.ViserServer, ctx: Context, *, control: bool) -> None:
        self.server = server
        self.ctx = ctx
        self.control = control
        gui = server.gui
        gui.configure_theme(
            show_share_button=False,
            show_logo=False,
            control_width="large",
            brand_color=(28, 126, 214),
        )
        gui.set_panel_label("ergoseek")
        server.initial_camera.position = (1.2, -1.6, 0.55)
        server.initial_camera.look_at = (0.1, 0.0, 0.05)
        self.scene = MachineScene(server.scene, float(ctx.settings.max_torque))

        charts_panel = gui.add_panel()
        with charts_panel.add_tab("Live charts", viser.Icon.CHART_LINE):
            self.readout = gui.add_markdown("No live data yet.")
            self.charts = LiveCharts(gui)
        charts_panel.dock_left()
        charts_panel.set_width(CHARTS_WIDTH)
        seeker_panel = gui.add_panel()
        with seeker_panel.add_tab("Seeker progress", viser.Icon.TARGET):
            self.seeker = SeekerPanel(gui)
        seeker_panel.float(x=12, y=-12, width=SEEKER_WIDTH, height=SEEKER_HEIGHT)

        gui.add_html(LOGOUT_HTML.format(role="trainer controls" if control else "view only"))
        tabs = gui.add_tab_group()
        with tabs.add_tab("Live", viser.Icon.ACTIVITY):
            self.live = LiveTab(gui, server, ctx, control=control)
        with tabs.add_tab("History", viser.Icon.HISTORY):
            self.history = HistoryTab(gui, ctx)
        self.users: UsersTab | None = None
        if control:
            with tabs.add_tab("Users", viser.Icon.USERS):
                self.users = UsersTab(gui, server, ctx)
        gui.main_panel.dock_right()
        gui.main_panel.set_width(MAIN_WIDTH)
        self._window_version = -1
        self._readout = ""

    def has_clients(self) -> bool:
        """Any connection at all (viser lists a client in ``get_clients()`` only after its
        first camera message, but sends it every update from the start)."""
        live = getattr(self.server._websock_server, "_live_connections", None)
        return bool(live) if live is not None else bool(self.server.get_clients())

    def render(self, st: LiveState, tick: int) -> None:
        with self.server.atomic():
            if st.window_version != self._window_version:
                self._window_version = st.window_version
                self.charts.show(st.window)
            row = st.window.last
            if row is not None:  # (a no-op when nothing changed)
                u = 0.0 if st.disarmed else float(row[LIVE["u_out"]])
                tau = 0.0 if st.disarmed else float(row[LIVE["tau"]])
                self.scene.show(float(row[LIVE["q"]]), u, tau)
            if st.active is not None:
                self.charts.label_user_torque(st.active.cfg.controller.kind == "measured")
            if tick % TEXT_EVERY == 0:
                text = readout(st)
                if text != self._readout:
                    self._readout = text
                    self.readout.content = text
                user = self.ctx.user_by_id(st.active.user_id) if st.active is not None else None
                self.live.render(st, user.name if user is not None else None)
                self.seeker.render(st.seeker)

    def users_changed(self, options: tuple[str, ...], select: UserRecord | None) -> None:
        self.live.users_changed(options, select)
        self.history.users_changed(options, select)
        if self.users is not None:
            self.users.users_changed(options, select)

    def session_finished(self, record: SessionRecord) -> None:
        self.live.session_finished(record)
        self.history.session_finished(record)
