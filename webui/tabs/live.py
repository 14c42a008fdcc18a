"""The Live tab of one browser: machine status, the red E-STOP, session setup (user, the
paper's presets, controller, seeker, bracket around the user's stored optimum, gains,
limits), Start / Stop / Reset, and the event log.

Each browser has its own (``client.gui``): one trainer's setup is never another's. Only a
trainer's or an admin's gets the controls; a viewer's shows the same status and log with
nothing to press.

Threads: E-STOP is an async callback on viser's loop that only schedules
``MachineService.estop`` on the web process's loop (no waiting, no store I/O, so nothing can
delay it). Start / Stop / Reset are plain callbacks (viser runs them on its thread pool): they
check the account in the store, then wait for the web process's loop to do the action.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, get_args

import viser
from pydantic import ValidationError

from server.service import BusyError
from sessions.codes import LATCHED
from sessions.config import ControllerConfig, SeekerConfig, default_ks
from sessions.experiments import BRACKETS, PAPER_GAINS
from sessions.requests import LimitsIn, RequestError, SessionStart, auto_bracket
from sessions.store import (
    AccountRecord,
    ConflictError,
    NotFoundError,
    SessionRecord,
    SetpointRecord,
    StoreValueError,
)
from sessions.worker import WorkerError
from webui import layout
from webui.bridge import Who
from webui.context import Context, relabel
from webui.escape import Markdown, MarkdownBox, md, md_join, md_lines
from webui.tabs.protocol import ProtocolEditor, phase_markdown
from webui.units import Units, live_numbers

if TYPE_CHECKING:
    from webui.feed import LiveState

log = logging.getLogger("ergoseek.dashboard")

DEFAULTS = "ergoseek defaults"
PRESETS: dict[str, str | None] = {DEFAULTS: None, "Paper Exp. 1": "exp1", "Paper Exp. 2": "exp2"}
BRACKET_AUTO = "around the stored optimum"
BRACKET_CUSTOM = "custom (γ1, γ2, γ3)"
CONTROLLERS = {"rise": "RISE, τ̂ observed (eq. 23)", "measured": "τ measured (eq. 7)"}
SEEKERS: tuple[str, ...] = get_args(SeekerConfig.model_fields["kind"].annotation)
DEFAULT_SEEKER = SeekerConfig().kind
DEFAULT_DURATION = 120.0


def status_markdown(st: LiveState, user_name: str | None) -> Markdown:
    """Machine state, armed, fault, loop timing, the running (or last) session."""
    ms = st.status
    if ms is None:
        return md("Machine: **starting**")
    latched = md(" (latched: **Reset** to clear)") if ms.state in LATCHED else md("")
    lines = [
        md(
            "Machine **{}**{} · {} · fault: {}",
            ms.state,
            latched,
            md("**armed**") if ms.armed else "not armed",
            ms.fault or "none",
        )
    ]
    timing = ms.timing or {}
    if timing:
        lines.append(
            md(
                "Loop {:g} Hz · lateness p99 **{:.0f} µs** · missed {} · overruns {}",
                ms.rate_hz,
                timing.get("p99_us", 0),
                timing.get("missed", 0),
                timing.get("overruns", 0),
            )
        )
    else:
        lines.append(md("Loop {:g} Hz · no timing yet", ms.rate_hz))
    active = st.active
    if active is not None:
        t = st.window.last[0] if st.window.last is not None else 0.0
        who = md(" ({})", user_name) if user_name else md("")
        lines.append(
            md(
                "Session **#{}**{} running · {:.1f} / {:g} s",
                active.session_id,
                who,
                t,
                active.cfg.duration,
            )
        )
    elif st.last_finished is not None:
        sid, status = st.last_finished
        lines.append(md("Last session #{}: **{}**", sid, status))
    else:
        lines.append(md("No session running"))
    return md_lines(lines)


def running_markdown(st: LiveState) -> Markdown:
    """What a viewer sees of the running session's setup."""
    if st.active is None:
        return md("Viewer: the dashboard without controls.")
    cfg = st.active.cfg
    bracket = ", ".join(f"{x:.3f}" for x in cfg.seeker.bracket)
    return md(
        "Running: {} controller, {} seeker, bracket ({}), {:g} s",
        cfg.controller.kind,
        cfg.seeker.kind,
        bracket,
        cfg.duration,
    )


class LiveTab:
    """Built in two places: the constructor (at the main panel's root, the current context)
    puts a trainer's E-STOP, Start, Stop, Reset and their message at the top of the main
    panel, always in reach (:mod:`webui.layout`'s orders); :meth:`build_tab` (inside the
    Live tab) the status, the session setup and the log."""

    def __init__(self, gui: viser.GuiApi, ctx: Context, who: Who, units: Units) -> None:
        self.gui = gui
        self.units = units
        self.ctx = ctx
        self.who = who
        self.control = who.trainer
        self._shown: dict[str, Any] = {}
        self._starting = False
        if self.control:
            self.estop = gui.add_button(
                "E-STOP",
                color="red",
                icon=viser.Icon.HAND_STOP,
                hint="Zero torque now; the machine stays stopped until Reset",
                order=layout.ORDER_ESTOP,
            )
            self.estop.on_click(self._on_estop)
            self._build_actions(gui)
            self._stored: SetpointRecord | None = None

    def build_tab(self, gui: viser.GuiApi) -> None:
        """The Live tab's content (call inside it)."""
        self.status = MarkdownBox(gui, md("Machine: **starting**"))
        self.numbers = MarkdownBox(gui, md("No live data yet."))
        self.phase = MarkdownBox(gui, md("Phase: —"))
        if self.control:
            with gui.add_folder("Session setup"):
                self._build_setup(gui)
        else:
            self.setup = MarkdownBox(gui, md("Viewer: the dashboard without controls."))
        self.log = MarkdownBox(gui, md(" "))

    def _build_setup(self, gui: viser.GuiApi) -> None:
        """The session's user, preset, controller, seeker, bracket, gains and limits."""
        ctx, settings = self.ctx, self.ctx.settings
        self.user = gui.add_dropdown("User", ctx.user_options())
        self.optimum = MarkdownBox(gui, md("Stored optimum: —"))
        self.preset = gui.add_dropdown("Preset", tuple(PRESETS))
        self.duration = gui.add_number(
            "Duration (s)", DEFAULT_DURATION, min=1.0, max=3600.0, step=1.0
        )
        self.protocol = ProtocolEditor(gui, ctx, self.who, self.units)
        self.controller = gui.add_dropdown("Controller", tuple(CONTROLLERS))
        self.controller_help = MarkdownBox(gui, md("{}", CONTROLLERS["rise"]))
        self.seeker = gui.add_dropdown("Seeker", SEEKERS, initial_value=DEFAULT_SEEKER)
        self.objective = gui.add_dropdown("Objective", ("power", "surrogate"))
        self.bracket_mode = gui.add_dropdown("Bracket", (BRACKET_AUTO, BRACKET_CUSTOM))
        g = {"min": 0.05, "max": 100.0, "step": 0.01}
        lo, mid, hi = SeekerConfig().bracket
        self.g1 = gui.add_number("γ1 (rad/s)", lo, **g)
        self.g2 = gui.add_number("γ2 (rad/s)", mid, **g)
        self.g3 = gui.add_number("γ3 (rad/s)", hi, **g)
        defaults = self._default_gains()
        with gui.add_folder("Gains", expand_by_default=False):
            gain = {"min": 0.001, "step": 0.001}
            self.ks = gui.add_number("ks", defaults["ks"], **gain)
            self.beta = gui.add_number("β1+β2 (N·m/s)", defaults["beta"], **gain)
            self.alpha_r = gui.add_number("αr (1/s)", defaults["alpha_r"], **gain)
            self.k = gui.add_number("k (N·m·s/rad)", defaults["k"], **gain)
        with gui.add_folder("Limits", expand_by_default=False):
            top_u, top_w = float(settings.max_torque), float(settings.max_velocity)
            self.max_torque = gui.add_number(
                "Max torque (N·m)", top_u, min=0.1, max=top_u, step=0.1
            )
            self.max_velocity = gui.add_number(
                "Max velocity (rad/s)", top_w, min=0.5, max=top_w, step=0.1
            )
        self.user.on_update(lambda _: ctx.background(self._show_optimum))
        self.preset.on_update(lambda _: self._apply_preset())
        self.bracket_mode.on_update(lambda _: ctx.background(self._show_optimum))
        self.max_velocity.on_update(lambda _: ctx.background(self._show_optimum))
        self.controller.on_update(lambda _: self._show_controller())

    def _build_actions(self, gui: viser.GuiApi) -> None:
        at = layout.ORDER_ACTIONS
        self.start = gui.add_button("Start", color="green", icon=viser.Icon.PLAYER_PLAY, order=at)
        self.stop = gui.add_button("Stop", icon=viser.Icon.PLAYER_STOP, disabled=True, order=at + 1)
        self.reset = gui.add_button("Reset", icon=viser.Icon.REFRESH, disabled=True, order=at + 2)
        self.message = MarkdownBox(gui, md(" "), order=at + 3)
        self.start.on_click(self._on_start)
        self.stop.on_click(self._on_stop)
        self.reset.on_click(self._on_reset)

    # -- setup ---
    def _show_controller(self) -> None:
        self.controller_help.show(md("{}", CONTROLLERS.get(self.controller.value, "?")))

    def _default_gains(self) -> dict[str, Any]:
        """The engine's default gains, ks as this rig's loop rate holds it."""
        gains = ControllerConfig().model_dump()
        rig = self.ctx.settings
        gains["ks"] = default_ks(gains["alpha_r"], float(rig.inertia), float(rig.rate))
        return gains

    def _apply_preset(self) -> None:
        name = PRESETS[self.preset.value]
        if name is None:
            gains = self._default_gains()
            self.seeker.value, self.objective.value = DEFAULT_SEEKER, "power"
            self.bracket_mode.value = BRACKET_AUTO
        else:
            gains = PAPER_GAINS[name]
            self.seeker.value = "parabolic"
            self.objective.value = "surrogate" if name == "exp1" else "power"
            self.bracket_mode.value = BRACKET_CUSTOM
            self.g1.value, self.g2.value, self.g3.value = (float(x) for x in BRACKETS[name])
        self.controller.value = "rise"
        self.ks.value = float(gains["ks"])
        self.beta.value = float(gains["beta"])
        self.alpha_r.value = float(gains["alpha_r"])
        self.ctx.background(self._show_optimum)

    def _show_optimum(self) -> None:
        """The picked user's stored optimum, and the bracket the server will use around it."""
        user = self.ctx.user_by_label(self.user.value)
        auto = self.bracket_mode.value == BRACKET_AUTO
        for g in (self.g1, self.g2, self.g3):
            g.disabled = auto
        if user is None:
            self.optimum.show(md("Stored optimum: — (pick or add a user)"))
            return
        current = self.ctx.store.setpoints.current(user.id)
        self._stored = current
        if current is None:
            text = md("Stored optimum for {}: **none yet**", user.name)
        else:
            power = md(", {:.3f} W", current.power) if current.power is not None else md("")
            source = md(", session #{}", current.session_id) if current.session_id else md("")
            text = md(
                "Stored optimum for {}: **{}**{}{}",
                user.name,
                self.units.v(current.velocity),
                power,
                source,
            )
        if auto:  # the bracket the server's policy will choose (sessions.requests)
            optimum = current.velocity if current is not None else None
            bracket, around = auto_bracket(optimum, float(self.max_velocity.value))
            note = md(" · bracket around it") if around else md(" · bracket: the default")
            text = md_join("", [text, note])
            self.g1.value, self.g2.value, self.g3.value = (round(float(x), 3) for x in bracket)
        self.optimum.show(text)

    def request(self) -> SessionStart:
        """The session to start, from the widgets (raises ValueError / ValidationError)."""
        user = self.ctx.user_by_label(self.user.value)
        if user is None:
            raise ValueError("pick a user first (or add one in the Users tab)")
        controller = ControllerConfig(
            kind=self.controller.value,
            ks=self.ks.value,
            beta=self.beta.value,
            alpha_r=self.alpha_r.value,
            k=self.k.value,
        )
        seeker: dict[str, Any] = {"kind": self.seeker.value, "objective": self.objective.value}
        if self.bracket_mode.value == BRACKET_CUSTOM:
            seeker["bracket"] = (self.g1.value, self.g2.value, self.g3.value)
        protocol = self.protocol.selection()
        timing: dict[str, Any] = (
            {"protocol": protocol} if protocol is not None else {"duration": self.duration.value}
        )  # a protocol's session lasts the longest it can take (sessions.requests)
        return SessionStart(
            user_id=user.id,
            **timing,
            controller=controller,
            seeker=SeekerConfig(**seeker),
            limits=LimitsIn(
                max_torque=float(self.max_torque.value),
                max_velocity=float(self.max_velocity.value),
            ),
        )

    # -- actions ---
    def _say(self, text: Markdown) -> None:
        self.message.show(md("{} {}", time.strftime("%H:%M:%S"), text))

    async def _on_estop(self, event: viser.GuiEvent) -> None:
        """On viser's loop: schedule the e-stop on the web process's loop, nothing else (this
        button exists only in a trainer's own dashboard)."""
        self.ctx.bridge.soon(self._estop_now)

    def _estop_now(self) -> None:
        """On the web process's loop."""
        log.warning("E-STOP from the dashboard (account %s)", self.who.account_id)
        try:
            self.ctx.bridge.machine.estop()
        except (BusyError, WorkerError) as exc:
            self._say(md("E-STOP could not reach the worker: {}", exc))
            return
        self._say(md("**E-STOP** sent: zero torque, latched until Reset"))

    def _allowed(self, what: str) -> AccountRecord | None:
        account = self.ctx.bridge.trainer(self.who)
        if account is None:
            self._say(md("{}: not allowed (this login is no longer a trainer's)", what))
        return account

    def _on_start(self, event: viser.GuiEvent) -> None:
        account = self._allowed("Start")
        if account is None:
            return
        try:
            req = self.request()
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(x) for x in err["loc"])
            self._say(md("Not started: {}: {}", where, err["msg"].removeprefix("Value error, ")))
            return
        except ValueError as exc:
            self._say(md("Not started: {}", exc))
            return
        self._starting = True
        self._set("start", True, lambda v: setattr(self.start, "disabled", v))
        self._say(md("starting…"))
        try:
            record = self.ctx.bridge.run(self.ctx.bridge.machine.start(req, account.id))
        except RequestError as exc:
            self._say(md("Not started: {}: {}", exc.field, exc.reason))
        except (BusyError, WorkerError, ConflictError, NotFoundError, StoreValueError) as exc:
            self._say(md("Not started: {}", exc))
        except TimeoutError:
            self._say(md("Not started: the machine did not answer in time"))
        else:
            self._say(md("Session **#{}** started by {}", record.id, account.login))
        finally:
            self._starting = False

    def _on_stop(self, event: viser.GuiEvent) -> None:
        if self._allowed("Stop") is None:
            return
        machine = self.ctx.bridge.machine
        active = self.ctx.bridge.call(machine.active_session)
        if active is None:
            self._say(md("No session to stop"))
            return
        try:
            self.ctx.bridge.call(machine.stop, active.session_id)
        except (ConflictError, BusyError, WorkerError) as exc:
            self._say(md("Stop: {}", exc))
        else:
            self._say(md("Stopping session #{} (torque ramped out)", active.session_id))

    def _on_reset(self, event: viser.GuiEvent) -> None:
        account = self._allowed("Reset")
        if account is None:
            return
        try:
            self.ctx.bridge.run(self.ctx.bridge.machine.reset())
        except (BusyError, WorkerError) as exc:
            self._say(md("Reset: {}", exc))
        except TimeoutError:
            self._say(md("Reset: the machine did not answer in time"))
        else:
            self._say(md("Reset by {}: the machine never restarts by itself", account.login))

    # -- rendering (feed thread) ---
    def _set(self, key: str, value: object, apply: Callable[[Any], object]) -> None:
        if self._shown.get(key) != value:
            self._shown[key] = value
            apply(value)

    def render(self, st: LiveState, status: Markdown, log_lines: Markdown) -> None:
        """The status, the log and what may be pressed now (feed thread, ~6 times a
        second; only what changed is sent)."""
        self.status.show(status)
        self.numbers.show(live_numbers(st, self.units, self.ctx))
        self.phase.show(phase_markdown(st, self.units))
        self.log.show(log_lines)
        if self.control:
            ms = st.status
            state = ms.state if ms is not None else "starting"
            idle = state == "idle" and st.active is None and not self._starting
            self._set("start", not idle, lambda v: setattr(self.start, "disabled", v))
            self._set("stop", st.active is None, lambda v: setattr(self.stop, "disabled", v))
            self._set("reset", state not in LATCHED, lambda v: setattr(self.reset, "disabled", v))
        else:
            self.setup.show(running_markdown(st))

    def users_changed(self, options: tuple[str, ...]) -> None:
        if not self.control:
            return
        keep = relabel(self.user.value, options)
        self.user.options = options
        if keep is not None and self.user.value != keep:
            self.user.value = keep
        self.ctx.background(self._show_optimum)

    def session_finished(self, record: SessionRecord) -> None:
        if self.control:
            self._show_optimum()
