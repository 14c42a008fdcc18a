"""Units a trainer reads: velocity in rpm or rad/s, power per body mass. The engine, the store
and the REST API stay SI (rad/s, N·m, W, J); conversion happens only where a person reads."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

VelocityUnit = Literal["rpm", "rad/s"]
VELOCITY_UNITS: tuple[VelocityUnit, ...] = ("rpm", "rad/s")
RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)  # one revolution is 2π rad; a minute is 60 s


def rad_s_to_rpm(w: float) -> float:
    return w * RPM_PER_RAD_S


def rpm_to_rad_s(rpm: float) -> float:
    return rpm / RPM_PER_RAD_S


def velocity_factor(unit: VelocityUnit) -> float:
    """Multiply a velocity in rad/s by this to express it in ``unit``."""
    if unit == "rpm":
        return RPM_PER_RAD_S
    if unit == "rad/s":
        return 1.0
    raise ValueError(f"velocity unit: must be one of {list(VELOCITY_UNITS)}, got {unit!r}")


def velocity_in(unit: VelocityUnit, w: float | np.ndarray) -> float | np.ndarray:
    """``w`` (rad/s) expressed in ``unit``."""
    return w * velocity_factor(unit)


def per_kg(power: float | None, body_mass_kg: float | None) -> float | None:
    """W/kg, or None when the power or a positive body mass is unknown."""
    if power is None or body_mass_kg is None or not body_mass_kg > 0:
        return None
    return power / body_mass_kg
