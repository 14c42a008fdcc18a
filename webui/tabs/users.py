"""The Users tab (trainers only, each browser its own form): add a user or edit one — name,
notes, body mass, limb, and the simulated person who stands in for them on the simulated
machine. Input is validated and saved as the REST API does it (:mod:`server.service.users`)."""

from __future__ import annotations

import time
from typing import Any

import viser
from pydantic import ValidationError

from server.service.users import UserIn, UserPatch, create_user, update_user
from sessions.config import UserConfig
from sessions.store import NotFoundError, StoreValueError
from webui.bridge import Who
from webui.context import Context, relabel, user_label
from webui.escape import Markdown, MarkdownBox, md

NEW_USER = "+ new user"


class UsersTab:
    def __init__(self, gui: viser.GuiApi, ctx: Context, who: Who) -> None:
        self.ctx = ctx
        self.who = who
        self.profile = gui.add_dropdown("Profile", (NEW_USER, *self._existing()))
        self.name = gui.add_text("Name", "")
        self.notes = gui.add_text("Notes", "", multiline=True)
        self.mass = gui.add_number(
            "Body mass (kg, 0 = not given)", 0.0, min=0.0, max=500.0, step=0.1
        )
        self.limb = gui.add_text("Limb", "")
        sim = UserConfig()
        with gui.add_folder("Simulated person (simulated machine)"):
            self.simulated = gui.add_checkbox("Has a simulated profile", True)
            self.kind = gui.add_dropdown("Torque law", ("hill", "linear"))
            self.tau0 = gui.add_number("τ0 (N·m)", sim.tau0, min=0.01, max=200.0, step=0.01)
            self.wmax = gui.add_number("wmax (rad/s)", sim.wmax, min=0.1, max=100.0, step=0.01)
            self.curvature = gui.add_number("Hill a", sim.curvature, min=0.01, max=10.0, step=0.01)
            self.noise = gui.add_number("Noise (relative)", sim.noise, min=0.0, max=0.5, step=0.01)
            self.ripple = gui.add_number(
                "Ripple (relative)", sim.ripple, min=0.0, max=0.99, step=0.01
            )
            self.fatigue = gui.add_number(
                "Fatigue τ (s, 0 = none)", sim.fatigue_tau, min=0.0, max=1e6, step=1.0
            )
        self.save = gui.add_button("Save user", icon=viser.Icon.DEVICE_FLOPPY)
        self.message = MarkdownBox(gui, md(" "))
        self.profile.on_update(lambda _: ctx.background(self._load))
        self.save.on_click(self._on_save)

    def _existing(self) -> tuple[str, ...]:
        return tuple(o for o in self.ctx.user_options() if self.ctx.user_by_label(o) is not None)

    def _load(self) -> None:
        """Fill the form with the picked user (or empty it for a new one)."""
        user = self.ctx.user_by_label(self.profile.value)
        sim = UserConfig()
        if user is None:
            self.name.value, self.notes.value, self.limb.value = "", "", ""
            self.mass.value = 0.0
            self.simulated.value = True
        else:
            self.name.value, self.notes.value = user.name, user.notes
            self.limb.value = user.limb or ""
            self.mass.value = float(user.body_mass_kg or 0.0)
            self.simulated.value = user.sim_profile is not None
            if user.sim_profile is not None:
                sim = UserConfig.model_validate(user.sim_profile)
        self.kind.value = sim.kind
        self.tau0.value, self.wmax.value = float(sim.tau0), float(sim.wmax)
        self.curvature.value, self.noise.value = float(sim.curvature), float(sim.noise)
        self.ripple.value, self.fatigue.value = float(sim.ripple), float(sim.fatigue_tau)

    def _fields(self) -> dict[str, Any]:
        sim = None
        if self.simulated.value:
            picked = self.ctx.user_by_label(self.profile.value)
            base = dict(picked.sim_profile or {}) if picked is not None else {}
            base.update(
                kind=self.kind.value,
                tau0=self.tau0.value,
                wmax=self.wmax.value,
                curvature=self.curvature.value,
                noise=self.noise.value,
                ripple=self.ripple.value,
                fatigue_tau=self.fatigue.value,
            )
            sim = base
        return {
            "name": self.name.value.strip(),
            "notes": self.notes.value,
            "body_mass_kg": self.mass.value if self.mass.value > 0 else None,
            "limb": self.limb.value.strip() or None,
            "sim_profile": sim,
        }

    def _say(self, text: Markdown) -> None:
        self.message.show(md("{} {}", time.strftime("%H:%M:%S"), text))

    def _on_save(self, event: viser.GuiEvent) -> None:
        if self.ctx.bridge.trainer(self.who) is None:
            self._say(md("Not saved: only a logged-in trainer may edit users"))
            return
        picked = self.ctx.user_by_label(self.profile.value)
        store = self.ctx.store
        try:
            if picked is None:
                record = create_user(store, UserIn.model_validate(self._fields()))
                verb = "Added"
            else:
                record = update_user(store, picked.id, UserPatch.model_validate(self._fields()))
                verb = "Saved"
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(x) for x in err["loc"])
            self._say(md("Not saved: {}: {}", where, err["msg"].removeprefix("Value error, ")))
            return
        except (StoreValueError, NotFoundError) as exc:
            self._say(md("Not saved: {}", exc))
            return
        self.ctx.refresh_users()
        self._select(user_label(record))
        self._say(md("{} user **{}** (#{})", verb, record.name, record.id))

    def _select(self, label: str) -> None:
        if label in self.profile.options and self.profile.value != label:
            self.profile.value = label

    def users_changed(self, options: tuple[str, ...]) -> None:
        existing = tuple(o for o in options if self.ctx.user_by_label(o) is not None)
        keep = relabel(self.profile.value, existing)
        self.profile.options = (NEW_USER, *existing)
        if keep is not None:
            self._select(keep)
