"""``ergoseek``: the command line. Each subcommand lives in a module of this package and
registers itself; heavy imports happen only when a subcommand runs.

Errors the user can fix (a bad scenario, a missing file, a wrong flag) print one line on
stderr and exit with status 2; there is no traceback for them.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# Modules of this package, each with ``register(subparsers)``.
COMMANDS: tuple[str, ...] = (
    "simulate", "reproduce", "run", "emulate-odrive", "serve", "demo", "account", "db",
)  # fmt: skip


class UsageError(Exception):
    """A problem with what the user asked for: reported in one line, exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ergoseek",
        description="Extremum-seeking exercise machine: simulate, reproduce, serve.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"server.cli.{name.replace('-', '_')}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from sessions.config import ScenarioError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except (UsageError, ScenarioError) as exc:
        print(f"ergoseek {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
