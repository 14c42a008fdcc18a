"""What a browser sees: one picture everyone shares, and a dashboard of its own.

- :class:`SharedView` (``server.gui``, ``server.scene``), built once: the 3D machine in the
  middle, and in the main panel the live readout and charts. Display only — no element a
  browser could change (an input in the shared GUI would be every browser's: tested) — and
  rendered once per tick for everyone (viser serialises each update once per browser anyway;
  per-browser charts would cost the feed ~0.4 ms per browser per tick).
- :class:`ClientView` (``client.gui``), built when a browser connects (viser calls
  ``on_client_connect`` after its first camera message) from the account the proxy vouched for
  (:meth:`webui.bridge.Bridge.identify`), and dropped when it leaves: the tabs Live, History
  and — for trainers — Users, and the seeker's window. Its inputs exist only in that
  browser's GUI, so a message from another connection cannot reach them: one trainer's
  session setup is never another's, a viewer's History pick is that viewer's. A viewer's
  view is built without any control at all.

The feed thread (:mod:`webui.feed`) renders the shared view every tick (charts and the 3D
handle when there is new data) and each client view about six times a second (status, log,
buttons, seeker), each element only when its content changed. :class:`Picture` holds what
all client views show alike, computed once per text tick.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import viser

from sessions.store import SessionRecord
from webui import layout
from webui.bridge import Who
from webui.charts import LIVE, LiveCharts
from webui.context import Context
from webui.escape import Html, HtmlBox, Markdown, MarkdownBox, html, md, md_join, md_lines
from webui.feed import LiveState
from webui.frames import guard_updates
from webui.layout import TOUCH_CSS
from webui.progress import SeekerPanel
from webui.scene import MachineScene
from webui.tabs.history import HistoryTab
from webui.tabs.live import LiveTab, status_markdown
from webui.tabs.users import UsersTab
from webui.units import VELOCITY_UNITS, Units, load_units, save_units

log = logging.getLogger("ergoseek.dashboard")

LOGOUT_HTML = (
    '<div style="display:flex;justify-content:space-between;align-items:center;'
    'padding:2px 0 6px 0;font-size:0.85em">'
    "<span>ergoseek · {} · {}</span>"
    '<a href="/?logout=1" role="button" aria-label="Log out" '
    'style="padding:3px 12px;border:1px solid #adb5bd;border-radius:4px;'
    'text-decoration:none;color:inherit">Log out</a></div>'
)


def readout(st: LiveState) -> Markdown:
    row = st.window.last
    if row is None:
        return md("No live data yet: start a session.")

    def v(name: str, fmt: str) -> str:
        x = float(row[LIVE[name]])
        return format(x, fmt) if math.isfinite(x) else "—"

    measured = st.active is not None and st.active.cfg.controller.kind == "measured"
    u = f"{0.0:+.3f} N·m (disarmed)" if st.disarmed else f"{v('u_out', '+.3f')} N·m"
    return md_lines(
        [
            md(
                "t = {} s · w = {} rad/s · wd = {} rad/s · γ = {} rad/s",
                v("t", ".2f"),
                v("w", ".3f"),
                v("wd", ".3f"),
                v("gamma", ".3f"),
            ),
            md(
                "u = {} · {} = {} N·m · p = {} W · W = {} J",
                u,
                "τ" if measured else "τ̂",
                v("tau", "+.3f"),
                v("p", ".3f"),
                v("W", ".2f"),
            ),
        ]
    )


NUMBERS_HTML = (
    '<div class="ergoseek-numbers" role="status" aria-label="live velocity and power">'
    '<div><div class="k">velocity w [rad/s]</div><div class="v ergoseek-w">{}</div>'
    '<div class="k">target {}</div></div>'
    '<div><div class="k">power p [W]</div><div class="v ergoseek-p">{}</div>'
    '<div class="k">{}</div></div></div>'
)


def numbers_html(st: LiveState | None) -> Html:
    """The large numbers at the top of the main panel: the latest velocity and power (and
    the velocity the controller is after, and the session time)."""
    row = st.window.last if st is not None else None
    if row is None:
        return html(NUMBERS_HTML, "—", "—", "—", "no live data")

    def v(name: str, fmt: str) -> str:
        x = float(row[LIVE[name]])
        return format(x, fmt) if math.isfinite(x) else "—"

    running = st.active is not None
    return html(
        NUMBERS_HTML,
        v("w", ".2f"),
        v("wd", ".2f"),
        v("p", ".1f"),
        f"t = {v('t', '.1f')} s" if running else "no session running",
    )


@dataclass(frozen=True)
class Picture:
    """What every browser's own dashboard shows alike (markdown, escaped)."""

    status: Markdown
    log: Markdown


class SharedView:
    """The 3D machine and the live charts, the same for every browser."""

    def __init__(self, server: viser.ViserServer, ctx: Context) -> None:
        self.server = server
        self.ctx = ctx
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
        self.numbers = HtmlBox(gui, numbers_html(None), order=layout.ORDER_NUMBERS)
        HtmlBox(gui, html(TOUCH_CSS), order=layout.ORDER_STYLE)
        tabs = gui.add_tab_group()
        with tabs.add_tab("Live charts", viser.Icon.CHART_LINE):
            self.readout = MarkdownBox(gui, md("No live data yet."))
            self.charts = LiveCharts(gui)
        guard_updates(gui)
        self._window_version = -1

    def has_clients(self) -> bool:
        """Any connection at all (viser lists a client in ``get_clients()`` only after its
        first camera message, but sends it every update from the start)."""
        live = getattr(self.server._websock_server, "_live_connections", None)
        return bool(live) if live is not None else bool(self.server.get_clients())

    def render(self, st: LiveState, text: bool) -> None:
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
            if text:
                self.readout.show(readout(st))
                self.numbers.show(numbers_html(st))

    def picture(self, st: LiveState) -> Picture:
        user = self.ctx.user_by_id(st.active.user_id) if st.active is not None else None
        return Picture(
            status=status_markdown(st, user.name if user is not None else None),
            log=md_join("  \n", st.log) if st.log else md(" "),
        )


class ClientView:
    """One browser's own dashboard; built on viser's thread pool when the browser connects."""

    def __init__(self, client: viser.ClientHandle, who: Who, ctx: Context) -> None:
        self.client = client
        self.client_id = client.client_id
        self.who = who
        self.ctx = ctx
        gui = client.gui
        guard_updates(gui)
        self.units = self._units()
        self.live = LiveTab(gui, ctx, who, self.units)  # E-STOP, Start, Stop, Reset: on top
        self.controls = gui.add_panel(order=layout.PANEL_ORDER["controls"])
        with self.controls.add_tab("Live", viser.Icon.ACTIVITY):
            role = "trainer controls" if who.trainer else "view only"
            self.account = HtmlBox(gui, logout_html(who, role))
            self.unit = gui.add_dropdown(
                "Velocity in", VELOCITY_UNITS, initial_value=self.units.velocity,
                hint="Your account's preference: what this dashboard shows (the API stays SI)",
            )  # fmt: skip
            self.unit.on_update(lambda _: ctx.background(self._unit_changed))
            self.live.build_tab(gui)
        with self.controls.add_tab("History", viser.Icon.HISTORY):
            self.history = HistoryTab(gui, ctx, self.units)
        self.users: UsersTab | None = None
        if who.trainer:
            with self.controls.add_tab("Users", viser.Icon.USERS):
                self.users = UsersTab(gui, ctx, who)
        self.seeker_panel = gui.add_panel(order=layout.PANEL_ORDER["seeker"])
        with self.seeker_panel.add_tab("Seeker progress", viser.Icon.TARGET):
            self.seeker = SeekerPanel(gui)
        self.viewport = layout.place(
            client,
            {"controls": self.controls, "seeker": self.seeker_panel},
            layout.canvas_of(client),
        )
        ctx.background(self.history.load_user)
        if who.trainer:
            ctx.background(self.live._show_optimum)
            ctx.background(self.live.protocol.load_templates)

    def _units(self) -> Units:
        try:
            return load_units(self.ctx.store, self.who.account_id)
        except Exception:  # (an account deleted meanwhile: the proxy closes the socket)
            log.exception("reading the preferences of account %s", self.who.account_id)
            return Units()

    def _unit_changed(self) -> None:
        """The browser picked another velocity unit: store it for the account, show it."""
        unit = self.unit.value
        if unit == self.units.velocity:
            return
        before = self.units.factor
        self.units.velocity = save_units(self.ctx.store, self.who.account_id, unit).velocity
        if self.who.trainer:
            self.live.protocol.units_changed(before)
            self.live._show_optimum()
        self.history.load_user()

    def render(self, st: LiveState, picture: Picture | None) -> None:
        """Feed thread: the seeker when it changed; the text when ``picture`` is given."""
        with self.client.atomic():
            if picture is not None:
                self.live.render(st, picture.status, picture.log)
            self.seeker.render(st.seeker)

    def users_changed(self, options: tuple[str, ...]) -> None:
        self.live.users_changed(options)
        self.history.users_changed(options)
        if self.users is not None:
            self.users.users_changed(options)

    def session_finished(self, record: SessionRecord) -> None:
        self.live.session_finished(record)
        self.history.session_finished(record)


def logout_html(who: Who, role: str) -> Html:
    return html(LOGOUT_HTML, who.login, role)
