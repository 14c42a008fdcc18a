"""Reasons as people read them: one clean line, whatever raised them. A reason from deep
inside (a worker's exception, a pydantic ValidationError's multi-line text) is shown to
viewers in ``/machine`` and to trainers in 409s: it must not be a dump."""

from __future__ import annotations

import re

MAX_CHARS = 300
_HEADER = re.compile(r"^\d+ validation errors? for \S+$")
_TRAILER = re.compile(r"\s*\[type=.*\]\s*$")


def one_line(reason: str | None) -> str | None:
    """``reason`` on one line: a pydantic error's ``loc: msg`` pairs, anything else joined
    with ``; ``; at most :data:`MAX_CHARS` characters."""
    if reason is None:
        return None
    parts: list[str] = []
    lead = ""  # what came before a pydantic error's header, if anything
    loc: str | None = None
    for raw in str(reason).splitlines():
        line = raw.strip()
        if not line or line.startswith("For further information visit"):
            continue
        tail = _HEADER.search(line.rsplit(": ", 1)[-1])
        if tail is not None:  # "internal error: ValidationError: 1 validation error for X"
            lead = line[: len(line) - len(tail.group(0))].rstrip(": ")
            continue
        if raw[:1].isspace() and loc is not None:  # a pydantic message under its location
            msg = _TRAILER.sub("", line).removeprefix("Value error, ")
            parts.append(f"{loc}: {msg}")
            loc = None
            continue
        if loc is not None:
            parts.append(loc)
        loc = line
    if loc is not None:
        parts.append(loc)
    text = "; ".join(parts)
    text = f"{lead}: {text}" if lead and text else lead or text
    return text if len(text) <= MAX_CHARS else text[: MAX_CHARS - 1] + "…"
