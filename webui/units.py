"""How one browser shows numbers: velocity in rpm or rad/s (its account's preference, rpm by
default in the dashboard; ``sessions.units`` holds the conversion) and power per body mass
(W/kg) where the user's body mass is known. The engine, the store and the REST API stay SI;
only text a person reads is converted here. Values come out as plain text for ``md(...)``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from sessions.store import Store
from sessions.units import VELOCITY_UNITS, VelocityUnit, per_kg, velocity_factor

if TYPE_CHECKING:
    from webui.context import Context
    from webui.escape import Markdown
    from webui.feed import LiveState

DASHBOARD_DEFAULT: VelocityUnit = "rpm"


@dataclass
class Units:
    """One browser's choice (changed in place when its account picks another unit)."""

    velocity: VelocityUnit = DASHBOARD_DEFAULT

    @property
    def label(self) -> str:
        return self.velocity

    @property
    def factor(self) -> float:
        return velocity_factor(self.velocity)

    @property
    def digits(self) -> int:
        """rpm to 0.1 (≈ 0.01 rad/s), rad/s to 0.001."""
        return 1 if self.velocity == "rpm" else 3

    def number(self, w: float | None) -> str:
        """A velocity (rad/s) in this unit, without the unit; "—" when unknown."""
        if w is None or not math.isfinite(w):
            return "—"
        return f"{w * self.factor:.{self.digits}f}"

    def v(self, w: float | None) -> str:
        """A velocity (rad/s) with its unit: ``28.6 rpm``."""
        text = self.number(w)
        return text if text == "—" else f"{text} {self.label}"

    def to_si(self, value: float) -> float:
        """A velocity typed in this unit, in rad/s."""
        return value / self.factor

    def from_si(self, w: float) -> float:
        return round(w * self.factor, self.digits + 1)


def power_text(power: float | None, body_mass_kg: float | None) -> str:
    """``41.2 W`` or ``41.2 W (0.55 W/kg)`` where the body mass is known."""
    if power is None or not math.isfinite(power):
        return "—"
    kg = per_kg(power, body_mass_kg)
    return f"{power:.1f} W" if kg is None else f"{power:.1f} W ({kg:.2f} W/kg)"


def load_units(store: Store, account_id: int) -> Units:
    """The account's stored preference (rpm if it never set one, or an unknown value)."""
    unit = store.preferences.get(account_id).velocity_unit
    return Units(unit if unit in VELOCITY_UNITS else DASHBOARD_DEFAULT)


def save_units(store: Store, account_id: int, unit: VelocityUnit) -> Units:
    return Units(store.preferences.set(account_id, velocity_unit=unit).velocity_unit)


def live_numbers(st: LiveState, units: Units, ctx: Context) -> Markdown:
    """The latest sample as this browser reads it: velocities in its unit, power in W and
    W/kg of the session's user (where their body mass is known)."""
    from webui.charts import LIVE
    from webui.escape import md

    row = st.window.last
    if row is None:
        return md("No live data yet: start a session.")
    user = ctx.user_by_id(st.active.user_id) if st.active is not None else None
    mass = user.body_mass_kg if user is not None else None
    power = float(row[LIVE["p"]])
    return md(
        "Velocity **{}** (target {}) · power **{}**",
        units.v(float(row[LIVE["w"]])),
        units.v(float(row[LIVE["wd"]])),
        power_text(power, mass),
    )
