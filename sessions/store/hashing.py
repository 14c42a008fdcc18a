"""How hard a stored password is to guess back: argon2id's cost, one setting of the server
(``password_hash`` in :class:`server.settings.Settings`, ``ERGOSEEK_PASSWORD_HASH__MEMORY_KIB``
and so on) and the hasher it makes.

The default is argon2-cffi's own, RFC 9106's second recommended option (64 MiB, 3 passes,
4 lanes; about 0.3 s of a core per hash or check on this project's 2-core VM). An operator
whose machine is small may lower it, never below OWASP's Password Storage Cheat Sheet
minimum for argon2id (19 MiB, 2 passes, 1 lane), which the bounds below hold. A password
stored at another cost is checked at its own and stored again at this one when it next
lets its owner in (:meth:`AccountRepository.authenticate`).
"""

from __future__ import annotations

from argon2 import PasswordHasher
from pydantic import BaseModel, ConfigDict, Field

DEFAULT = PasswordHasher()
OWASP_MIN_MEMORY_KIB = 19 * 1024
OWASP_MIN_TIME_COST = 2


class HashCost(BaseModel):
    """argon2id's cost for new password hashes."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    memory_kib: int = Field(
        DEFAULT.memory_cost, ge=OWASP_MIN_MEMORY_KIB, le=4 * 1024 * 1024,
        description="memory per hash, KiB (OWASP's minimum: 19 MiB)",
    )  # fmt: skip
    time_cost: int = Field(
        DEFAULT.time_cost, ge=OWASP_MIN_TIME_COST, le=32, description="passes over the memory"
    )
    parallelism: int = Field(DEFAULT.parallelism, ge=1, le=64, description="lanes (threads)")

    def hasher(self) -> PasswordHasher:
        return PasswordHasher(
            time_cost=self.time_cost, memory_cost=self.memory_kib, parallelism=self.parallelism
        )
