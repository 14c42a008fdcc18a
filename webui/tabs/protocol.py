"""The protocol in one trainer's session setup: pick a saved template or edit one — warm-up,
seek, train, profile, cool-down, each with its fields — and save it as a template; and the
live phase line (phase, time left, next) every browser's Live tab shows.

The editor is a fixed form, one folder per phase kind in the order a session runs them
(warm-up → seek → profile → train → cool-down), each with an *include* box. A template is
loaded into it; one whose phases do not fit the form (a kind twice, another order) runs as
stored, and the form says so. Velocities are typed in the browser's unit
(:mod:`webui.units`) and sent in rad/s: the protocol goes to the machine as
:class:`sessions.protocol.config.Protocol`, validated by its own model, and a template is
stored through ``Store.templates`` with the account's own rights.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import viser
from pydantic import ValidationError

from sessions.protocol.config import Protocol, describe
from sessions.protocol.stage import Stage
from sessions.store import ConflictError, ForbiddenError, StoreValueError, TemplateRecord
from webui.bridge import Who
from webui.context import Context
from webui.escape import Markdown, MarkdownBox, md
from webui.units import Units

if TYPE_CHECKING:
    from webui.feed import LiveState

NONE = "none: one search for the duration"
EDITED = "as edited below"
FORM_ORDER = ("warmup", "seek", "profile", "train", "cooldown")
ORDERS = ("interleaved", "ascending", "descending", "random")
ROLE_TEXT = {
    "countdown": "get ready",
    "work": "WORK",
    "rest": "rest",
    "relax": "relax",
    "step": "step",
    "stop": "stopping",
}


def template_label(t: TemplateRecord) -> str:
    """Dropdown text (React text in viser's client: no escaping needed)."""
    return f"{t.name} (#{t.id}{', shared' if t.shared else ''})"


def fits_form(protocol: Protocol) -> bool:
    kinds = [ph.kind for ph in protocol.phases]
    return len(set(kinds)) == len(kinds) and kinds == [k for k in FORM_ORDER if k in kinds]


def error_text(exc: ValidationError) -> str:
    err = exc.errors()[0]
    where = ".".join(str(x) for x in err["loc"])
    return f"{where}: {str(err['msg']).removeprefix('Value error, ')}"


class ProtocolEditor:
    """The protocol part of a trainer's session setup (built inside its folder)."""

    def __init__(self, gui: viser.GuiApi, ctx: Context, who: Who, units: Units) -> None:
        self.ctx, self.who, self.units = ctx, who, units
        self._loading = False
        self._templates: dict[str, TemplateRecord] = {}
        self.pick = gui.add_dropdown("Protocol", (NONE, EDITED))
        self.summary = MarkdownBox(gui, md("One search for the session's duration."))
        self.include: dict[str, viser.GuiCheckboxHandle] = {}
        self.folders: dict[str, Any] = {}
        self.fields: dict[str, dict[str, Any]] = {}
        self._speed_labels: dict[tuple[str, str], str] = {}
        with gui.add_folder("Protocol phases", expand_by_default=False) as self.phases_folder:
            self._build_phases(gui)
        with gui.add_folder("Save as template", expand_by_default=False):
            self.name = gui.add_text("Template name", "")
            self.shared = gui.add_checkbox("Shared with all trainers", False)
            self.save = gui.add_button("Save as template", icon=viser.Icon.DEVICE_FLOPPY)
            self.saved = MarkdownBox(gui, md(" "))
        self.pick.on_update(lambda _: self._picked())
        self.save.on_click(lambda _: self._save())
        for box in self.include.values():
            box.on_update(lambda _: self._edited())
        for fields in self.fields.values():
            for handle in fields.values():
                handle.on_update(lambda _: self._edited())
        self._loading = False

    # -- the form ---
    def _build_phases(self, gui: viser.GuiApi) -> None:
        v = {"min": 0.0, "max": 1000.0, "step": 0.1}
        s = {"min": 0.0, "max": 14400.0, "step": 1.0}
        short = {"min": 0.0, "max": 60.0, "step": 1.0}
        specs: dict[str, tuple[str, bool, dict[str, tuple[str, float, dict[str, float]]]]] = {
            "warmup": ("Warm-up", True, {
                "duration": ("warm-up (s)", 60.0, s),
                "velocity": ("velocity ({u}; 0: γ1)", 0.0, v),
                "ramp": ("warm-up ramp (s)", 0.0, s),
            }),
            "seek": ("Seek", True, {
                "duration": ("seek: longest (s)", 180.0, s),
                "hold": ("seek: hold once converged (s)", 5.0, s),
            }),
            "profile": ("Profile (velocity spectrum)", False, {
                "count": ("profile steps K", 8.0, {"min": 3.0, "max": 50.0, "step": 1.0}),
                "hold": ("profile s per step M", 8.0, {"min": 1.0, "max": 600.0, "step": 1.0}),
            }),
            "train": ("Train (work / rest intervals)", True, {
                "intervals": ("intervals", 6.0, {"min": 1.0, "max": 200.0, "step": 1.0}),
                "work": ("work (s)", 20.0, s),
                "rest": ("rest (s)", 40.0, s),
                "velocity": ("work velocity ({u}; 0: the optimum)", 0.0, v),
                "rest_velocity": ("rest velocity ({u}; 0: stop)", self.units.from_si(1.0), v),
                "countdown": ("countdown (s)", 3.0, {**short, "max": 30.0}),
            }),
            "cooldown": ("Cool-down", True, {
                "duration": ("cool-down (s)", 60.0, s),
                "hold": ("cool-down: hold at rest (s)", 3.0, short),
            }),
        }  # fmt: skip
        for kind, (title, on, fields) in specs.items():
            with gui.add_folder(title) as folder:
                self.folders[kind] = folder
                self.include[kind] = gui.add_checkbox(f"include {kind}", on)
                self.fields[kind] = {}
                for key, (label, value, bounds) in fields.items():
                    if "{u}" in label:
                        self._speed_labels[(kind, key)] = label
                    text = label.format(u=self.units.label)
                    self.fields[kind][key] = gui.add_number(text, value, **bounds)
                if kind == "profile":
                    self.order = gui.add_dropdown("profile order", ORDERS)
                if kind == "seek":
                    self.until = gui.add_checkbox("end once converged", True)

    def _value(self, kind: str, key: str) -> float:
        return float(self.fields[kind][key].value)

    def _phase(self, kind: str) -> dict[str, Any]:
        f = {key: self._value(kind, key) for key in self.fields[kind]}
        speed = self.units.to_si
        if kind == "warmup":
            out = {"duration": f["duration"], "ramp": f["ramp"]}
            if f["velocity"] > 0:
                out["velocity"] = speed(f["velocity"])
        elif kind == "seek":
            out = {"duration": f["duration"], "hold": f["hold"]}
            out["until_converged"] = self.until.value
        elif kind == "profile":
            out = {"count": int(f["count"]), "hold": f["hold"], "order": self.order.value}
        elif kind == "train":
            out = {k: f[k] for k in ("work", "rest", "countdown")}
            out["intervals"] = int(f["intervals"])
            out["rest_velocity"] = speed(f["rest_velocity"])
            if f["velocity"] > 0:
                out["velocity"] = speed(f["velocity"])
        else:
            out = {"duration": f["duration"], "hold": f["hold"]}
        return {"kind": kind, **out}

    def form_protocol(self) -> Protocol:
        """The protocol the form shows (raises ValidationError, ValueError)."""
        phases = [self._phase(k) for k in FORM_ORDER if self.include[k].value]
        if not phases:
            raise ValueError("protocol: include at least one phase")
        return Protocol.model_validate({"name": self.name.value.strip(), "phases": phases})

    def fill(self, protocol: Protocol) -> None:
        """Show a protocol in the form (one that fits it)."""
        self._loading = True
        try:
            by_kind = {ph.kind: ph for ph in protocol.phases}
            for kind in FORM_ORDER:
                self.include[kind].value = kind in by_kind
                ph = by_kind.get(kind)
                if ph is None:
                    continue
                for key, handle in self.fields[kind].items():
                    value = getattr(ph, key, None)
                    if key.endswith("velocity"):
                        value = self.units.from_si(value) if value else 0.0
                    handle.value = float(value) if value is not None else 0.0
                if kind == "seek":
                    self.until.value = bool(ph.until_converged)
                if kind == "profile":
                    self.order.value = ph.order
        finally:
            self._loading = False

    def units_changed(self, before: float) -> None:
        """The browser's unit changed (from ``before`` × rad/s): the velocity fields follow."""
        self._loading = True
        try:
            for (kind, key), template in self._speed_labels.items():
                handle = self.fields[kind][key]
                handle.value = self.units.from_si(float(handle.value) / before)
                handle.label = template.format(u=self.units.label)
        finally:
            self._loading = False

    # -- what runs ---
    def selection(self) -> Protocol | None:
        """The protocol for the session request: none, the form's, or a template that does
        not fit the form, as stored (named as the template when it has no name of its own,
        as ``server.service.templates.resolve_template`` names it)."""
        label = self.pick.value
        if label == NONE:
            return None
        template = self._templates.get(label)
        if template is not None:
            stored = Protocol.model_validate(template.protocol)
            if not stored.name:
                stored = stored.model_copy(update={"name": template.name})
            if not fits_form(stored):
                return stored
            form = self.form_protocol()
            return form if form.name else form.model_copy(update={"name": template.name})
        return self.form_protocol()

    def _edited(self) -> None:
        if self._loading:
            return
        if self.pick.value != EDITED:
            self.pick.value = EDITED
        self.preview()

    def _picked(self) -> None:
        template = self._templates.get(self.pick.value)
        if template is not None:
            stored = Protocol.model_validate(template.protocol)
            self.fill(stored)
            if not fits_form(stored):
                self.summary.show(md("{} · runs as stored (its phases do not fit the form)",
                                     describe(stored)))  # fmt: skip
                return
        self.preview()

    def preview(self) -> None:
        if self.pick.value == NONE:
            self.summary.show(md("One search for the session's duration."))
            return
        try:
            protocol = self.form_protocol()
        except ValidationError as exc:
            self.summary.show(md("Protocol not valid: {}", error_text(exc)))
            return
        except ValueError as exc:
            self.summary.show(md("Protocol not valid: {}", exc))
            return
        self.summary.show(md("{} (duration: the longest it can take)", describe(protocol)))

    # -- templates ---
    def load_templates(self) -> None:
        """Read the templates this account may use (an I/O thread)."""
        items = self.ctx.store.templates.list(
            account_id=self.who.account_id,
            role=self.who.role,  # type: ignore[arg-type]
        )
        self._templates = {template_label(t): t for t in items}
        keep = self.pick.value
        options = (NONE, EDITED, *self._templates)
        self.pick.options = options
        if keep in options and self.pick.value != keep:
            self.pick.value = keep

    def _save(self) -> None:
        account = self.ctx.bridge.trainer(self.who)
        if account is None:
            self.saved.show(md("Save: not allowed (this login is no longer a trainer's)"))
            return
        name = self.name.value.strip()
        try:
            if not name:
                raise ValueError("name: give the template a name")
            protocol = self.form_protocol()
            record = self.ctx.store.templates.create(
                account.id, name, protocol.model_dump(mode="json"), shared=self.shared.value
            )
        except ValidationError as exc:
            self.saved.show(md("Not saved: {}", error_text(exc)))
            return
        except (ValueError, ConflictError, ForbiddenError, StoreValueError) as exc:
            self.saved.show(md("Not saved: {}", exc))
            return
        self.load_templates()
        self.pick.value = template_label(record)
        self.saved.show(md("Saved template **{}** (#{})", record.name, record.id))


def phase_markdown(st: LiveState, units: Units) -> Markdown:
    """The running phase, its time left and the next one; the effort asked."""
    active = st.active
    stage: Stage | None = active.stage if active is not None else None
    if active is None or stage is None:
        return md("Phase: —")
    row = st.window.last
    # the stage's event can arrive before its first telemetry row: a countdown never starts
    # above the segment's length
    now = max(float(row[0]), stage.start) if row is not None else stage.start
    left = max(0.0, stage.phase_end - now) if math.isfinite(stage.phase_end) else math.nan
    seg_left = max(0.0, stage.end - now) if math.isfinite(stage.end) else math.nan
    count = active.cfg.protocol.phases if active.cfg.protocol is not None else ()
    role = ROLE_TEXT.get(stage.role, stage.role)
    interval = md(" {}/{}", stage.interval, stage.intervals) if stage.intervals else md("")
    nxt = stage.next_name or stage.next_kind or "end (at rest)"
    return md(
        "Phase **{}** ({}/{}) · {}{} · {} s left in it · phase {} s left · next: {} · "
        "target {} · effort {:.0%}",
        stage.name,
        min(stage.phase + 1, max(len(count), 1)),
        max(len(count), 1),
        role,
        interval,
        "—" if math.isnan(seg_left) else math.ceil(seg_left),  # a countdown's whole seconds
        "—" if math.isnan(left) else math.ceil(left),
        nxt,
        units.v(stage.velocity),
        stage.effort,
    )
