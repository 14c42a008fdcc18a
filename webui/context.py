"""What every part of the dashboard shares: the web process's runtime (typed: its settings,
store and machine service), the bridge to its loop, a small thread pool for store reads the
GUI triggers, the directory of users (for the pickers) and the views (one per viser server)
to refresh together."""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

from server.runtime import Runtime
from server.settings import Settings
from sessions.store import SessionRecord, Store, UserRecord
from webui.bridge import Bridge

if TYPE_CHECKING:
    from webui.views import View

log = logging.getLogger("ergoseek.dashboard")

NO_USERS = "(no users yet)"
USER_LIMIT = 1000


def user_label(user: UserRecord) -> str:
    return f"{user.name} (#{user.id})"


class Context:
    def __init__(self, runtime: Runtime, bridge: Bridge) -> None:
        self.runtime = runtime
        self.bridge = bridge
        self.settings: Settings = runtime.settings
        self.io = ThreadPoolExecutor(2, thread_name_prefix="ergoseek-dashboard-io")
        self.views: list[View] = []
        self._users: list[UserRecord] = []
        self._lock = threading.Lock()

    @property
    def store(self) -> Store:
        return self.runtime.store

    def background(self, fn: Callable[..., Any], *args: object) -> None:
        """Run ``fn`` on the dashboard's I/O threads (store reads); errors are logged."""

        def run() -> None:
            try:
                fn(*args)
            except Exception:
                log.exception("dashboard: %s", getattr(fn, "__name__", fn))

        with contextlib.suppress(RuntimeError):  # shut down
            self.io.submit(run)

    # -- users ---
    def load_users(self) -> list[UserRecord]:
        users = self.store.users.list(limit=USER_LIMIT).items
        with self._lock:
            self._users = users
        return users

    def user_options(self) -> tuple[str, ...]:
        with self._lock:
            return tuple(user_label(u) for u in self._users) or (NO_USERS,)

    def user_by_label(self, label: str) -> UserRecord | None:
        with self._lock:
            return next((u for u in self._users if user_label(u) == label), None)

    def user_by_id(self, user_id: int) -> UserRecord | None:
        with self._lock:
            return next((u for u in self._users if u.id == user_id), None)

    def refresh_users(self, select: UserRecord | None = None) -> None:
        """Reload the users and update every picker (call from a thread)."""
        self.load_users()
        options = self.user_options()
        for view in self.views:
            view.users_changed(options, select)

    # -- sessions ---
    def session_finished(self, session_id: int, status: str) -> None:
        """A session ended (from the feed thread): views reload what depends on it."""

        def reload() -> None:
            record: SessionRecord = self.store.sessions.get(session_id)
            for view in self.views:
                view.session_finished(record)

        self.background(reload)

    def close(self) -> None:
        self.io.shutdown(wait=True, cancel_futures=True)
