"""``ergoseek emulate-odrive [options]``: an ODrive (fw 0.5.1 … 0.5.6) on a pseudo-terminal.

Prints the device path on the first line of stdout, then serves until killed (SIGTERM or
Ctrl-C end it cleanly). The emulated person and handle come from ``--scenario`` (its [user],
machine.inertia and seed) or the defaults; device events (closed loop, watchdog expiry,
overspeed) are logged on stderr. Point ``ergoseek run --machine odrive --device PATH`` at it.

The drive itself: ``--firmware 0.5.x`` (each version's ASCII behaviour, ``--build`` release
or source), ``--torque-constant``/``--current-lim`` (or ``--factory-defaults``: 0.04 N·m/A,
10 A), ``--uncalibrated``, ``--axis`` (the other one has no motor), ``--partial-line TEXT``
(bytes a host that died mid-line left in its buffer).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser(
        "emulate-odrive",
        help="emulate an ODrive (ASCII protocol, fw 0.5.x) on a pseudo-terminal",
        description="Serve an emulated ODrive on a pty: prints its device path, runs until killed.",
    )
    p.add_argument("--scenario", help="TOML scenario: the person, inertia and seed to emulate")
    # the rig's mechanics: EmulatorConfig's fields (its defaults when not given)
    p.add_argument("--gear-ratio", type=float, help="motor turns per handle turn")
    p.add_argument("--direction", type=int, choices=(1, -1))
    p.add_argument("--axis", type=int, choices=(0, 1), help="axis the handle is on")
    p.add_argument("--physics-rate", type=float, help="physics steps per s")
    p.add_argument("--seed", type=int, help="override the scenario's seed")
    p.add_argument("--firmware", help="firmware version to mimic: 0.5.1 … 0.5.6 (default 0.5.6)")
    p.add_argument("--build", choices=("release", "source"), help="the firmware's build")
    p.add_argument("--torque-constant", type=float, help="motor.config.torque_constant, N·m/A")
    p.add_argument("--current-lim", type=float, help="motor.config.current_lim, A")
    p.add_argument(
        "--factory-defaults", action="store_true", help="the firmware's defaults: 0.04 N·m/A, 10 A"
    )
    p.add_argument("--uncalibrated", action="store_true", help="the axis is not calibrated")
    p.add_argument("--partial-line", help="a partial line already in the device's buffer")
    p.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the device")
    p.add_argument("--quiet", action="store_true", help="no device events on stderr")
    p.add_argument(
        "--no-realtime",
        action="store_true",
        help="do not ask for SCHED_FIFO (a device answers at once)",
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from server.cli import UsageError
    from sessions.config import SessionConfig, load_scenario
    from sessions.machine.odrive.emulator import (
        FACTORY,
        EmulatorConfig,
        OdriveEmulator,
        device_priority,
    )

    cfg = load_scenario(args.scenario) if args.scenario else SessionConfig()
    if args.seed is not None and args.seed < 0:
        raise UsageError("--seed must be ≥ 0")
    given = ("gear_ratio", "direction", "axis", "physics_rate", "seed", "build",
             "torque_constant", "current_lim", "partial_line")  # fmt: skip
    mechanics: dict[str, Any] = {k: v for k in given if (v := getattr(args, k)) is not None}
    if args.factory_defaults:
        mechanics = {**FACTORY, **mechanics}
    if args.uncalibrated:
        mechanics["calibrated"] = False
    if args.firmware is not None:
        mechanics["firmware"] = _version(args.firmware)
    try:
        rig = EmulatorConfig.from_session(cfg, **mechanics)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.link and os.path.lexists(args.link):
        raise UsageError(f"{args.link} already exists")
    if not args.no_realtime:
        device_priority()
    emu = OdriveEmulator(rig)
    stop = False

    def _stop(signum: int, frame: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    try:
        if args.link:
            os.symlink(emu.path, args.link)
        print(emu.path, flush=True)
        seen = 0
        while not stop:
            emu.poll_once(0.002)
            new = emu.log_total - seen
            if new and not args.quiet:
                for t, what in list(emu.log)[-min(new, len(emu.log)) :]:
                    print(f"[{t:.3f}] {what}", file=sys.stderr, flush=True)
            seen += new
    finally:
        if args.link and os.path.islink(args.link):
            os.unlink(args.link)
        emu.close()
    return 0


def _version(text: str) -> tuple[int, int, int]:
    from server.cli import UsageError

    try:
        major, minor, revision = (int(x) for x in text.split("."))
    except ValueError:
        raise UsageError(f"--firmware {text!r}: expected a version like 0.5.6") from None
    return major, minor, revision
