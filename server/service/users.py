"""What a trainer enters about a user, validated the same way for the REST API and the
dashboard, and the two things done with it: add a user, edit one."""

from __future__ import annotations

from pydantic import Field

from sessions.config import UserConfig
from sessions.requests import HEADROOM, Finite, Request, RequestError, Rig
from sessions.store import Store, UserRecord


class UserIn(Request):
    name: str = Field(..., min_length=1, max_length=200, examples=["Ada Lovelace"])
    notes: str = Field("", max_length=10_000)
    body_mass_kg: Finite | None = Field(None, gt=0, le=500, examples=[68.0])
    limb: str | None = Field(None, max_length=64, examples=["right arm"])
    sim_profile: UserConfig | None = Field(
        None, description="the simulated person standing in for this user on a simulated machine"
    )


class UserPatch(Request):
    name: str | None = Field(None, min_length=1, max_length=200)
    notes: str | None = Field(None, max_length=10_000)
    body_mass_kg: Finite | None = Field(None, gt=0, le=500)
    limb: str | None = Field(None, max_length=64)
    sim_profile: UserConfig | None = None


def create_user(store: Store, body: UserIn) -> UserRecord:
    """Add a user (store I/O: call it from a thread)."""
    return store.users.create(
        body.name,
        notes=body.notes,
        body_mass_kg=body.body_mass_kg,
        limb=body.limb,
        sim_profile=body.sim_profile,
    )


def update_user(store: Store, user_id: int, patch: UserPatch) -> UserRecord:
    """Change what the patch sets, nothing else (store I/O: call it from a thread)."""
    return store.users.update(user_id, **patch.model_dump(exclude_unset=True))


def check_setpoint(velocity: float, rig: Rig) -> float:
    """A setpoint set by hand, if the machine can hold it with the headroom every setpoint
    the policy picks keeps (:data:`sessions.requests.HEADROOM` of the velocity limit)."""
    vmax = rig.machine.max_velocity
    top = HEADROOM * vmax
    if velocity > top:
        raise RequestError(
            "velocity",
            f"{velocity:g} rad/s is above {top:g} rad/s ({HEADROOM:.0%} of the machine's "
            f"velocity limit, {vmax:g} rad/s)",
        )
    return velocity
