"""``ergoseek account create NAME --role admin|trainer|viewer``: a login for the server.
The password is prompted for (twice) on a terminal, or read as one line from standard input."""

from __future__ import annotations

import argparse
import getpass
import sys
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("account", help="manage the server's accounts")
    acts = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    c = acts.add_parser("create", help="create an account (password prompted or from stdin)")
    c.add_argument("name", help="login name")
    c.add_argument("--role", choices=("admin", "trainer", "viewer"), required=True)
    c.add_argument("--database-url", dest="database_url", help="default: the server's")
    c.set_defaults(run=create)
    ls = acts.add_parser("list", help="list the accounts")
    ls.add_argument("--database-url", dest="database_url")
    ls.set_defaults(run=list_accounts)


def read_password() -> str:
    from server.cli import UsageError

    if sys.stdin.isatty():
        first = getpass.getpass("password: ")
        if first != getpass.getpass("again: "):
            raise UsageError("the two passwords differ")
        return first
    line = sys.stdin.readline()
    if not line:
        raise UsageError("no password on standard input")
    return line.rstrip("\r\n")


def create(args: argparse.Namespace) -> int:
    from server.cli import UsageError
    from sessions.store import ConflictError, StoreValueError, open_store

    password = read_password()
    try:
        with open_store(args.database_url) as store:
            acc = store.accounts.create(args.name, password, args.role)
    except StoreValueError as exc:
        raise UsageError(f"{exc.field}: {exc.reason}") from None
    except ConflictError as exc:
        raise UsageError(str(exc)) from None
    print(f"created {acc.role} account '{acc.login}' (id {acc.id})")
    return 0


def list_accounts(args: argparse.Namespace) -> int:
    from sessions.store import open_store

    with open_store(args.database_url) as store:
        for acc in store.accounts.list():
            flag = " (disabled)" if acc.disabled else ""
            print(f"{acc.id:4d}  {acc.login:24s} {acc.role}{flag}")
    return 0
