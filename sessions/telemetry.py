"""The telemetry channels a session produces at full rate: one definition for every consumer
(simulation arrays, the worker's shared-memory ring, the store's chunks, CSV export)."""

from __future__ import annotations

CHANNELS: tuple[tuple[str, str, str], ...] = (
    ("t", "s", "time since the session started"),
    ("q", "rad", "handle angle"),
    ("w", "rad/s", "handle velocity"),
    ("wd", "rad/s", "desired velocity"),
    ("ad", "rad/s^2", "desired acceleration"),
    ("u", "N*m", "motor torque"),
    ("tau", "N*m", "user torque: measured (controller A) or observed τ̂ (controller B)"),
    ("p", "W", "modified power the seeker sees, (4) or (31)"),
    ("W", "J", "passivity integral (5)"),
    ("gamma", "rad/s", "seeker candidate"),
)
NAMES: tuple[str, ...] = tuple(c[0] for c in CHANNELS)
UNITS: dict[str, str] = {c[0]: c[1] for c in CHANNELS}
INDEX: dict[str, int] = {name: i for i, name in enumerate(NAMES)}
WIDTH = len(CHANNELS)


def csv_header() -> str:
    """Header row with units, e.g. ``t [s],q [rad],…``."""
    return ",".join(f"{name} [{unit}]" for name, unit, _ in CHANNELS)
