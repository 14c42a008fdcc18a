"""What the store raises. Every error a caller can cause is a :class:`StoreError`; the API
layer maps :class:`StoreValueError` to 422, :class:`NotFoundError` to 404 and
:class:`ConflictError` to 409. Database failures (connection lost, disk full) are not
wrapped: they are the server's problem, not the caller's."""

from __future__ import annotations


class StoreError(Exception):
    """Base of the store's own errors."""


class StoreValueError(StoreError, ValueError):
    """A value refused at the store's boundary; nothing was written.

    ``field`` names the offending input (dotted for nested values, e.g. ``summary.duration``),
    ``reason`` says what is wrong with it."""

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}")


class NotFoundError(StoreError, LookupError):
    """No row with that key: ``kind`` is what was looked for (``session``, ``user``…)."""

    def __init__(self, kind: str, key: object) -> None:
        self.kind = kind
        self.key = key
        super().__init__(f"no {kind} {key!r}")


class ConflictError(StoreError):
    """The request contradicts the stored state: a login name already taken, a session
    finished twice, telemetry that goes back in time."""
