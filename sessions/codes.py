"""Every code that crosses a module or process boundary, defined once.

- **Session status**: what the store keeps, the API filters on and the worker ends with.
- **Protocol phases**: the kinds a session's protocol phases have (sessions.protocol).
- **Bounds**: where a search ended against the trainer's bracket (``at_bound``).
- **Seeker phases**: ``Seeker.phase``, and the ring's ``phase`` column (with the worker's
  :data:`STOPPING` for the stop ramp, which is not a seeker phase).
- **Flags**: the engine's limit bits (:class:`sessions.limits.Limits`) and the worker's own,
  OR-ed in the ring's ``flags`` column.
- **Worker states**: the code the worker writes in the ring's header, and its name.
- **Roles** of the accounts, and how they nest; the kinds of login token.

The telemetry channels (the columns of a record) are defined once too, in
:mod:`sessions.telemetry`.
"""

from __future__ import annotations

from typing import Literal, get_args

# -- session status ------------------------------------------------------------------------
SessionStatus = Literal["running", "completed", "stopped", "aborted", "faulted"]
EndStatus = Literal["completed", "stopped", "aborted", "faulted"]  # how a session ends
STATUSES: tuple[SessionStatus, ...] = get_args(SessionStatus)
END_STATUSES: tuple[EndStatus, ...] = get_args(EndStatus)

# -- protocol phases ----------------------------------------------------------------------------
PhaseKindName = Literal["warmup", "seek", "train", "profile", "cooldown", "stop"]
PHASE_KINDS: tuple[PhaseKindName, ...] = get_args(PhaseKindName)  # "stop": the runner's own

# -- seeker phases -----------------------------------------------------------------------------
DELAY, SETTLING, MEASURING, DONE = 0, 1, 2, 3
PHASES: tuple[str, ...] = ("delay", "settling", "measuring", "done")  # index = code
STOPPING = -1  # the ring's phase column during the worker's stop ramp

# -- the bound a search ended at (the best point there, the power still rising outward) ------
Bound = Literal["lower", "upper"]
BOUNDS: tuple[Bound, ...] = get_args(Bound)


def phase_name(code: float) -> str | None:
    """The name of a phase column value (``stopping`` for :data:`STOPPING`), or None."""
    if code == STOPPING:
        return "stopping"
    for i, name in enumerate(PHASES):
        if code == i:
            return name
    return None  # NaN or not a phase


# -- flags -----------------------------------------------------------------------------------
TORQUE_LIMIT = 1  # |u| clamped to the torque limit
VELOCITY_LIMIT = 2  # the velocity governor acted
FLAG_STOPPING = 4  # the worker's controlled stop
FLAG_ESTOP = 8  # the e-stop's zero-torque record
FLAG_FAULT = 16  # a machine fault's zero-torque record
FLAG_PASSIVITY = 32  # W(t) < -c²
FLAG_CATCHUP = 64  # a period the worker missed, stepped late with the torque the drive held
FLAGS: dict[int, str] = {
    TORQUE_LIMIT: "torque limit",
    VELOCITY_LIMIT: "velocity limit",
    FLAG_STOPPING: "stopping",
    FLAG_ESTOP: "e-stop",
    FLAG_FAULT: "fault",
    FLAG_PASSIVITY: "passivity",
    FLAG_CATCHUP: "caught up",
}
ZERO_TORQUE_FLAGS = FLAG_ESTOP | FLAG_FAULT  # records that end in zero torque at once
FLAGS_LEGEND = ", ".join(f"{bit} {name}" for bit, name in FLAGS.items())
PHASES_LEGEND = ", ".join(f"{i} {name}" for i, name in enumerate(PHASES)) + f"; {STOPPING} stopping"

# -- worker states -----------------------------------------------------------------------------
WorkerStateName = Literal[
    "starting", "idle", "running", "stopping", "estopped", "faulted", "closed", "lost"
]
# index = the code in the ring header; "lost" is the parent's verdict, never written there
STATES: tuple[WorkerStateName, ...] = get_args(WorkerStateName)[:-1]
STATE_STARTING, STATE_IDLE, STATE_RUNNING, STATE_STOPPING = 0, 1, 2, 3
STATE_ESTOPPED, STATE_FAULTED, STATE_CLOSED = 4, 5, 6
LATCHED: tuple[WorkerStateName, ...] = ("estopped", "faulted", "lost")  # a reset clears them


def describe_flags(flags: int) -> str:
    """The names of the bits set in a flags value, e.g. ``torque limit, stopping``."""
    return ", ".join(name for bit, name in FLAGS.items() if flags & bit)


# -- roles ---------------------------------------------------------------------------------------
Role = Literal["admin", "trainer", "viewer"]
ROLES: tuple[Role, ...] = get_args(Role)
RANK: dict[str, int] = {"viewer": 0, "trainer": 1, "admin": 2}  # viewer ⊂ trainer ⊂ admin
TokenKind = Literal["cookie", "bearer"]
TOKEN_KINDS: tuple[TokenKind, ...] = get_args(TokenKind)
