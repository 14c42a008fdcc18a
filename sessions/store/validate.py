"""Checks at the store's boundary. Each raises :class:`StoreValueError` naming the field and
the reason, before anything is written."""

from __future__ import annotations

import json
import math
import numbers
import re
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from pydantic import BaseModel, ValidationError

from sessions.config import SessionConfig
from sessions.store.errors import StoreValueError
from sessions.summary import SessionSummary

_IDENT = re.compile(r"[a-z][a-z0-9_.:-]*")


def text(field: str, value: Any, *, max_len: int, allow_empty: bool = False) -> str:
    """A string, stripped of surrounding white space, within ``max_len`` characters."""
    if not isinstance(value, str):
        raise StoreValueError(field, f"must be a string, got {type(value).__name__}")
    value = value.strip()
    if not value and not allow_empty:
        raise StoreValueError(field, "must not be empty")
    if len(value) > max_len:
        raise StoreValueError(field, f"longer than {max_len} characters")
    if "\x00" in value:
        raise StoreValueError(field, "must not contain NUL characters")
    return value


def optional_text(field: str, value: Any, *, max_len: int) -> str | None:
    if value is None:
        return None
    return text(field, value, max_len=max_len, allow_empty=True) or None


def identifier(field: str, value: Any, *, max_len: int = 32) -> str:
    """A short lowercase name such as a seeker kind, an event kind or a machine backend."""
    value = text(field, value, max_len=max_len)
    if not _IDENT.fullmatch(value):
        raise StoreValueError(
            field, f"{value!r} is not a lowercase name (a-z, then a-z 0-9 _ . : -)"
        )
    return value


def choice(field: str, value: Any, options: tuple[str, ...]) -> str:
    if value not in options:
        raise StoreValueError(field, f"unknown value {value!r} (one of {', '.join(options)})")
    return str(value)


def number(
    field: str,
    value: Any,
    *,
    gt: float | None = None,
    ge: float | None = None,
    le: float | None = None,
) -> float:
    """A finite float within the given bounds."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise StoreValueError(field, f"must be a number, got {type(value).__name__}")
    x = float(value)
    if not math.isfinite(x):
        raise StoreValueError(field, f"must be finite, got {x}")
    if gt is not None and not x > gt:
        raise StoreValueError(field, f"must be greater than {gt:g}, got {x:g}")
    if ge is not None and not x >= ge:
        raise StoreValueError(field, f"must be at least {ge:g}, got {x:g}")
    if le is not None and not x <= le:
        raise StoreValueError(field, f"must be at most {le:g}, got {x:g}")
    return x


def optional_number(field: str, value: Any, **bounds: float) -> float | None:
    return None if value is None else number(field, value, **bounds)


def integer(field: str, value: Any, *, ge: int | None = None, le: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise StoreValueError(field, f"must be an integer, got {type(value).__name__}")
    if ge is not None and value < ge:
        raise StoreValueError(field, f"must be at least {ge}, got {value}")
    if le is not None and value > le:
        raise StoreValueError(field, f"must be at most {le}, got {value}")
    return value


def flag(field: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise StoreValueError(field, f"must be true or false, got {value!r}")
    return value


def moment(field: str, value: Any) -> datetime:
    """An aware UTC datetime; a naive one is taken as UTC."""
    if not isinstance(value, datetime):
        raise StoreValueError(field, f"must be a datetime, got {type(value).__name__}")
    if value.tzinfo is None:
        return value.replace(tzinfo=UTC)
    return value.astimezone(UTC)


def json_object(field: str, value: Any) -> dict[str, Any]:
    """A JSON object (finite numbers only), as it will read back."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise StoreValueError(field, f"must be an object, got {type(value).__name__}")
    try:
        return json.loads(json.dumps(dict(value), allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise StoreValueError(field, f"not storable as JSON ({exc})") from None


def _model_error(field: str, exc: ValidationError) -> StoreValueError:
    err = exc.errors()[0]
    loc = ".".join(str(x) for x in err["loc"])
    msg = err["msg"].removeprefix("Value error, ")
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
    elif "input" in err and not isinstance(err["input"], dict):
        msg = f"{msg} (got {err['input']!r})"
    return StoreValueError(f"{field}.{loc}" if loc else field, msg)


def config(value: Any) -> dict[str, Any]:
    """A session configuration, validated, as the JSON the store keeps."""
    data = value.model_dump(mode="json") if isinstance(value, BaseModel) else value
    if not isinstance(data, Mapping):
        raise StoreValueError("config", f"must be an object, got {type(value).__name__}")
    try:
        return SessionConfig.model_validate(dict(data)).model_dump(mode="json")
    except ValidationError as exc:
        raise _model_error("config", exc) from None


def summary(value: Any) -> SessionSummary:
    """A session summary, validated again (a model may have been built unchecked)."""
    data = value.model_dump() if isinstance(value, BaseModel) else value
    if not isinstance(data, Mapping):
        raise StoreValueError("summary", f"must be an object, got {type(value).__name__}")
    try:
        return SessionSummary.model_validate(dict(data))
    except ValidationError as exc:
        raise _model_error("summary", exc) from None
