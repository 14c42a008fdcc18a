"""Shared by the live-machine tests (worker, ring, ODrive backend and emulator): scenarios that
provoke each behaviour, and a helper that follows a worker session to its end.

Everything here drives real parts: a spawned worker process, a real shared-memory ring, a real
pseudo-terminal with the emulator in its own process. Waits are bounded and generous (a loaded
2-core VM must not make a test flaky); no assertion is about speed.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from server.settings import Settings
from sessions.config import SessionConfig, parse_session_config
from sessions.machine import MachineSpec
from sessions.machine.odrive.emulator import EmulatorConfig
from sessions.worker import Event, RingReader, SessionEnded, Worker, WorkerOptions

EMULATED_KT = EmulatorConfig().torque_constant  # the emulated motor's torque constant, N·m/A

# the server's setting worker.heartbeat_timeout, as its settings name it in the environment
HEARTBEAT_ENV = "{env_prefix}WORKER{env_nested_delimiter}HEARTBEAT_TIMEOUT".format(
    **Settings.model_config
)


def worker_options(**over: Any) -> WorkerOptions:
    """The worker's options for a test that starts a worker itself: the defaults, with the
    heartbeat timeout the suite's part runs its servers with (``HEARTBEAT_ENV``, set by
    ``make test`` for the parallel rooms: three of them on two cores stall a worker past the
    default 100 ms, and a test provoking a fault then reads ``lost``), the default where it is
    not set (the realtime part, where liveness is timed)."""
    if HEARTBEAT_ENV in os.environ and "heartbeat_timeout" not in over:
        over["heartbeat_timeout"] = float(os.environ[HEARTBEAT_ENV])
    return WorkerOptions(**over)


# A Hill user found by Brent in a few seconds: fast filter, short windows, noise-free.
QUICK_SEEK: dict[str, Any] = {
    "duration": 6.0,
    "seed": 3,
    "user": {"kind": "hill", "tau0": 3.0, "wmax": 10.0},
    "seeker": {
        "kind": "brent",
        "filter": {"pole": 6.0},
        "window": 0.3,
        "max_window": 2.0,
        "start_delay": 0.5,
    },
}


def scenario(**over: Any) -> SessionConfig:
    """QUICK_SEEK with top-level keys replaced (nested dicts replace whole sections)."""
    return parse_session_config({**QUICK_SEEK, **over})


# The safety scenarios (the worker's tests and the supervisor's in-process ones run the same):
# a strong person against a weak RISE controller overshoots 4 rad/s in ~75 ms
OVERSPEED: dict[str, Any] = {
    "duration": 3.0,
    "machine": {"max_velocity": 4.0, "max_torque": 20.0},
    "user": {"tau0": 20.0, "wmax": 12.0},
    "controller": {"ks": 0.1, "beta": 0.01, "alpha_r": 0.1},
    "seeker": {"kind": "fixed", "bracket": [1, 2, 3], "start_delay": 0.0},
}
# controller A from rest against a 20 N·m motor: −30 N·m on the very first period
STRONG: dict[str, Any] = {
    "duration": 0.5,
    "machine": {"max_torque": 20.0},
    "user": {"tau0": 30.0, "wmax": 12.0},
    "controller": {"kind": "measured"},
    "seeker": {"kind": "fixed", "setpoint": 1.0, "bracket": [0.5, 1, 2], "start_delay": 0.0},
}
# next to no person and a hard acceleration to 5 rad/s: W(t) from τ̂·w dips below -c² = -1 mJ
PASSIVITY_BREACH: dict[str, Any] = {
    "duration": 3.0,
    "machine": {"passivity_c2": 1e-3},
    "user": {"kind": "linear", "tau0": 0.01, "wmax": 0.5},
    "controller": {"ks": 0.2},
    "seeker": {
        "kind": "fixed",
        "setpoint": 5.0,
        "bracket": [1, 2, 6],
        "start_delay": 0.0,
        "filter": {"pole": 30.0},
    },
}


def odrive(device: str, **kw: Any) -> MachineSpec:
    """An ODrive spec for the emulated rig at ``device`` (its motor's torque constant)."""
    return MachineSpec(kind="odrive", device=device, **{"torque_constant": EMULATED_KT, **kw})


@dataclass
class Followed:
    """Everything a session produced, as seen from the parent."""

    events: list[Event] = field(default_factory=list)
    end: SessionEnded | None = None
    seq: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    data: np.ndarray = field(default_factory=lambda: np.zeros((0, 16)))
    missed: int = 0

    def kinds(self) -> list[str]:
        return [e.kind for e in self.events]

    def of(self, kind: str) -> list[Any]:
        return [e for e in self.events if e.kind == kind]


def follow(
    worker: Worker,
    reader: RingReader | None = None,
    timeout: float = 60.0,
    until: str = "session_ended",
    every: float = 0.02,
) -> Followed:
    """Poll the worker (and drain ``reader``) until an event of kind ``until`` arrives."""
    out = Followed()
    seqs, rows = [], []
    deadline = time.monotonic() + timeout
    done = False
    while not done:
        for ev in worker.poll():
            out.events.append(ev)
            if isinstance(ev, SessionEnded):
                out.end = ev
            if ev.kind == until:
                done = True
        if reader is not None:
            batch = reader.read()
            out.missed += batch.missed
            seqs.append(batch.seq)
            rows.append(batch.data)
        if not done:
            if time.monotonic() > deadline:
                raise AssertionError(f"no {until!r} within {timeout} s; got {out.kinds()}")
            time.sleep(every)
    if reader is not None:
        batch = reader.read()
        out.missed += batch.missed
        seqs.append(batch.seq)
        rows.append(batch.data)
        out.seq = np.concatenate(seqs)
        out.data = np.concatenate(rows)
    return out


def wait_for(predicate: Any, timeout: float, every: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(every)
    return bool(predicate())
