"""The password policy of accounts: what a new password must be, wherever it is set (the REST
API, the CLI, the demo), checked by the store itself so no path can skip it.

- long enough: :data:`MIN_LENGTH` characters, :data:`ADMIN_MIN_LENGTH` for an admin (who can
  make accounts); at most :data:`MAX_LENGTH`;
- not the login name, nor a close variant of it (case, digits or punctuation around it,
  reversed, doubled);
- hard to guess: zxcvbn (Dropbox's estimator, maintained as the ``zxcvbn`` package) must
  score it at least :data:`MIN_SCORE` of 4, given the login name as a word an attacker
  knows. That refuses common passwords (``12345678``, ``password1``), repeats
  (``aaaaaaaa``, eight spaces), keyboard walks, dates and dictionary words with l33t.

A refusal is a :class:`StoreValueError` on ``password`` with the reason in words (a 422
naming the field over REST, one line and exit 2 on the CLI).
"""

from __future__ import annotations

import re
from typing import Any

from zxcvbn import zxcvbn

from sessions.store.errors import StoreValueError

MIN_LENGTH = 8
ADMIN_MIN_LENGTH = 12
MAX_LENGTH = 1024
MIN_SCORE = 3  # zxcvbn: "safely unguessable" (about 10^8 guesses and more)
ESTIMATE_CHARS = 100  # zxcvbn's cost grows with length; a longer password is past guessing

_NOT_ALNUM = re.compile(r"[\W_]+")


def _core(text: str) -> str:
    """Letters only, lowercased: what is left of a variant once digits and punctuation go."""
    return re.sub(r"\d+", "", _NOT_ALNUM.sub("", text.lower()))


def is_login_variant(password: str, login: str) -> bool:
    """The login name itself, or it dressed up: case, digits and punctuation around it,
    reversed, repeated (``Coach!``, ``coach2024``, ``hcaoc``, ``CoachCoach``)."""
    core, name = _core(password), _core(login)
    if not name:
        return False
    repeats = len(core) // len(name)
    return bool(core) and any(core == word * repeats for word in (name, name[::-1]))


def check_password(value: Any, login: str, role: str) -> str:
    """``value`` if it may be the password of ``login`` with ``role``; else StoreValueError."""
    if not isinstance(value, str):
        raise StoreValueError("password", "must be a string")
    least = ADMIN_MIN_LENGTH if role == "admin" else MIN_LENGTH
    if len(value) < least:
        who = "an admin's" if role == "admin" else "a password"
        raise StoreValueError("password", f"shorter than {least} characters ({who} minimum)")
    if len(value) > MAX_LENGTH:
        raise StoreValueError("password", f"longer than {MAX_LENGTH} characters")
    if is_login_variant(value, login):
        raise StoreValueError("password", "must not be the login name or a variant of it")
    verdict = zxcvbn(value[:ESTIMATE_CHARS], user_inputs=[login])
    if verdict["score"] < MIN_SCORE:
        feedback = verdict["feedback"]
        why = (feedback.get("warning") or "").rstrip(".")
        hint = " ".join(feedback.get("suggestions") or [])
        reason = "too easy to guess" + (f": {why}" if why else "") + (f" ({hint})" if hint else "")
        raise StoreValueError("password", reason)
    return value
