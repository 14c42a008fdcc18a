"""Changes to accounts, told to whoever holds a connection open on an account's behalf, the
moment they happen: the live WebSocket (:mod:`server.api.live`) and the dashboard's proxy
(:mod:`webui.proxy`) re-check the login of their connections and close the ones that lost it.

    unsubscribe = runtime.accounts.subscribe(lambda change: ...)   # on the event loop

A listener is called synchronously on the event loop, with an :class:`AccountChange`; it must
not block (set an asyncio.Event, create a task). What changed is a hint: a listener re-checks
the login (:func:`server.security.identify_async`) rather than trusting it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

log = logging.getLogger("ergoseek.accounts")

ChangeKind = Literal["role", "disabled", "password", "deleted", "logout", "login"]


@dataclass(frozen=True)
class AccountChange:
    account_id: int
    kind: ChangeKind


Listener = Callable[[AccountChange], None]


class AccountEvents:
    def __init__(self) -> None:
        self._listeners: list[Listener] = []

    def subscribe(self, listener: Listener) -> Callable[[], None]:
        """Call ``listener`` on every change from now on; returns the unsubscribe call."""
        self._listeners.append(listener)

        def unsubscribe() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return unsubscribe

    def changed(self, account_id: int, kind: ChangeKind) -> None:
        """Tell every listener (a failing one is logged, the others still hear)."""
        change = AccountChange(account_id, kind)
        for listener in list(self._listeners):
            try:
                listener(change)
            except Exception:
                log.exception("account listener")


class LiveGate:
    """How many live connections are open, per account and in all, against the caps."""

    def __init__(self, per_account: int, total: int) -> None:
        self.per_account = per_account
        self.total = total
        self._open: dict[int, int] = {}

    @property
    def open(self) -> int:
        return sum(self._open.values())

    def enter(self, account_id: int) -> str | None:
        """Count one more connection for ``account_id``; or why not (nothing counted)."""
        if self.open >= self.total:
            return f"too many live connections ({self.total} open in all)"
        if self._open.get(account_id, 0) >= self.per_account:
            return f"too many live connections for this account ({self.per_account} open)"
        self._open[account_id] = self._open.get(account_id, 0) + 1
        return None

    def leave(self, account_id: int) -> None:
        n = self._open.get(account_id, 0) - 1
        if n > 0:
            self._open[account_id] = n
        else:
            self._open.pop(account_id, None)
