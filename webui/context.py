"""What every part of the dashboard shares: the web process's runtime (typed: its settings,
store and machine service), the bridge to its loop, a small thread pool for store reads the
GUI triggers, the directory of users (for the pickers) and the registry of the browsers'
own dashboards (:class:`webui.views.ClientView`, one per connected browser)."""

from __future__ import annotations

import contextlib
import logging
import re
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

from server.runtime import Runtime
from server.settings import Settings
from sessions.store import SessionRecord, Store, UserRecord
from webui.bridge import Bridge

if TYPE_CHECKING:
    from webui.views import ClientView

log = logging.getLogger("ergoseek.dashboard")

_ID = re.compile(r"\(#\d+\)$")
NO_USERS = "(no users yet)"
USER_LIMIT = 1000


def user_label(user: UserRecord) -> str:
    """How a picker shows a user (dropdown options are text in viser's client: no
    escaping needed)."""
    return f"{user.name} (#{user.id})"


def relabel(label: str, options: tuple[str, ...]) -> str | None:
    """The option that names the same user as ``label`` (after a rename: its new label)."""
    if label in options:
        return label
    found = _ID.search(label)
    if found is None:
        return None
    return next((o for o in options if o.endswith(found.group(0))), None)


class Context:
    def __init__(self, runtime: Runtime, bridge: Bridge) -> None:
        self.runtime = runtime
        self.bridge = bridge
        self.settings: Settings = runtime.settings
        self.io = ThreadPoolExecutor(2, thread_name_prefix="ergoseek-dashboard-io")
        self._views: dict[int, ClientView] = {}
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

    # -- the browsers' dashboards ---
    def add_view(self, client_id: int, view: ClientView) -> None:
        with self._lock:
            self._views[client_id] = view

    def drop_view(self, client_id: int) -> ClientView | None:
        with self._lock:
            return self._views.pop(client_id, None)

    def views(self) -> list[ClientView]:
        """The connected browsers' dashboards now (a copy: iterate it from any thread)."""
        with self._lock:
            return list(self._views.values())

    # -- users ---
    def load_users(self) -> bool:
        """Read the users from the store; whether they changed since the last read."""
        users = self.store.users.list(limit=USER_LIMIT).items
        key = [(u.id, u.name, u.updated_at) for u in users]
        with self._lock:
            changed = key != [(u.id, u.name, u.updated_at) for u in self._users]
            self._users = users
        return changed

    def user_options(self) -> tuple[str, ...]:
        with self._lock:
            return tuple(user_label(u) for u in self._users) or (NO_USERS,)

    def user_by_label(self, label: str) -> UserRecord | None:
        with self._lock:
            return next((u for u in self._users if user_label(u) == label), None)

    def user_by_id(self, user_id: int) -> UserRecord | None:
        with self._lock:
            return next((u for u in self._users if u.id == user_id), None)

    def refresh_users(self, *, force: bool = True) -> None:
        """Reload the users and, if they changed (or ``force``), update every browser's
        pickers (call from a thread): users added or renamed anywhere — this dashboard, the
        REST API, another process on the same store — appear in every open dashboard."""
        if not self.load_users() and not force:
            return
        options = self.user_options()
        for view in self.views():
            try:
                view.users_changed(options)
            except Exception:
                log.exception("updating the pickers of dashboard client %s", view.client_id)

    # -- sessions ---
    def session_finished(self, session_id: int, status: str) -> None:
        """A session ended (from the feed thread): views reload what depends on it."""

        def reload() -> None:
            record: SessionRecord = self.store.sessions.get(session_id)
            for view in self.views():
                view.session_finished(record)

        self.background(reload)

    def close(self) -> None:
        self.io.shutdown(wait=True, cancel_futures=True)
