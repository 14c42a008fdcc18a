"""``ergoseek demo``: the server with a simulated machine, a demo trainer account and a few
simulated users, ready for a trainer to open the dashboard."""

from __future__ import annotations

import argparse
import os
import secrets
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from server.settings import Settings

DEMO_LOGIN = "demo"
PASSWORD_ENV = "ERGOSEEK_DEMO_PASSWORD"

# People with different simulated traits (sessions.config.UserConfig).
DEMO_USERS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("Ada", "Hill user, steady", {"kind": "hill", "tau0": 3.0, "wmax": 10.0}),
    (
        "Ben",
        "linear user with noise and ripple",
        {"kind": "linear", "tau0": 2.0, "wmax": 6.0, "noise": 0.03, "ripple": 0.1},
    ),
    (
        "Chloé",
        "strong Hill user who tires",
        {"kind": "hill", "tau0": 6.0, "wmax": 14.0, "curvature": 0.35, "fatigue_tau": 900.0},
    ),
    (
        "Dev",
        "Hill user with everything a real person has",
        {
            "kind": "hill", "tau0": 4.0, "wmax": 12.0, "noise": 0.04, "ripple": 0.12,
            "fatigue_model": "three-compartment", "fatigue_effort": 0.3,
            "fatigue_f": 0.003, "fatigue_r": 0.002,
        },
    ),
)  # fmt: skip


def register(sub: Any) -> None:
    from server.cli.serve import add_server_flags

    p = sub.add_parser(
        "demo",
        help="serve a simulated machine with a demo trainer and simulated users",
        description=(
            f"Serve ergoseek with a simulated machine. The trainer account '{DEMO_LOGIN}' gets "
            f"the password in ${PASSWORD_ENV}, or a new one printed at start."
        ),
    )
    add_server_flags(p)
    p.set_defaults(run=run)


def prepare(settings: Settings) -> str:
    """Create (or reset) the demo account and seed the users; returns the password."""
    from sessions.config import UserConfig
    from sessions.store import open_store

    password = os.environ.get(PASSWORD_ENV) or secrets.token_urlsafe(12)
    hasher = settings.password_hash.hasher()
    with open_store(settings.store_url(), password_hasher=hasher) as store:
        account = store.accounts.by_login(DEMO_LOGIN)
        if account is None:
            store.accounts.create(DEMO_LOGIN, password, "trainer")
        else:
            store.accounts.set_password(account.id, password)
            store.accounts.update(account.id, role="trainer", disabled=False)
        if store.users.list(limit=1).total == 0:
            for name, notes, profile in DEMO_USERS:
                store.users.create(name, notes=notes, sim_profile=UserConfig(**profile))
    return password


def run(args: argparse.Namespace) -> int:
    from server.cli import UsageError
    from server.cli.serve import serve, settings_from
    from sessions.store import StoreValueError

    settings = settings_from(args, machine="sim", demo=True)
    try:
        password = prepare(settings)
    except StoreValueError as exc:
        raise UsageError(f"${PASSWORD_ENV}: {exc.reason}") from None
    source = f"from ${PASSWORD_ENV}" if os.environ.get(PASSWORD_ENV) else "generated"
    shown = password if not os.environ.get(PASSWORD_ENV) else "(as set)"
    host = "127.0.0.1" if settings.host in ("0.0.0.0", "::") else settings.host
    print(
        f"ergoseek demo: open http://{host}:{settings.port}/ and log in as "
        f"'{DEMO_LOGIN}' with password {shown} ({source})",
        flush=True,
    )
    return serve(settings)
