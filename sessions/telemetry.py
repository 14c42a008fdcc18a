"""The telemetry channels, defined once for every consumer.

:data:`CHANNELS` are what a session produces at full rate (simulation arrays, the store's
chunks, CSV export). A live *record* (the worker's shared-memory ring, the live WebSocket, the
dashboard) carries them and :data:`RECORD_EXTRA`: what the worker wrote to the machine and
when. Consumers name columns (``INDEX["w"]``, ``RECORD_INDEX["u_out"]``), never positions.
"""

from __future__ import annotations

from sessions.codes import FLAGS_LEGEND, PHASES_LEGEND

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

RECORD_EXTRA: tuple[tuple[str, str, str], ...] = (
    ("u_out", "N*m", "torque written to the machine (the loop's u, or the stop ramp's, or 0)"),
    ("phase", "", f"seeker phase: {PHASES_LEGEND}"),
    ("flags", "", FLAGS_LEGEND),
    ("late", "us", "lateness of this cycle's wake-up behind its deadline"),
    ("mono", "s", "monotonic clock when the cycle started (CLOCK_MONOTONIC, all processes)"),
    ("session", "", "the worker's session number"),
    ("stage", "", "the protocol phase: its index in the protocol (the closing stop after them)"),
)
RECORD_NAMES: tuple[str, ...] = NAMES + tuple(c[0] for c in RECORD_EXTRA)
RECORD_UNITS: dict[str, str] = {**UNITS, **{c[0]: c[1] for c in RECORD_EXTRA}}
RECORD_INDEX: dict[str, int] = {name: i for i, name in enumerate(RECORD_NAMES)}
RECORD_WIDTH = len(RECORD_NAMES)


def csv_header() -> str:
    """Header row with units, e.g. ``t [s],q [rad],…``."""
    return ",".join(f"{name} [{unit}]" for name, unit, _ in CHANNELS)
