"""A session start that names a protocol template: the template's protocol, as the account
may read it, put in the request (its name the protocol's when the protocol has none)."""

from __future__ import annotations

from sessions.protocol.config import Protocol
from sessions.requests import RequestError, SessionStart
from sessions.store import AccountRecord, NotFoundError, Store


def resolve_template(store: Store, req: SessionStart, account: AccountRecord) -> SessionStart:
    assert req.template_id is not None
    try:
        template = store.templates.get(req.template_id, account_id=account.id, role=account.role)
    except NotFoundError:
        raise RequestError("template_id", f"no protocol template {req.template_id}") from None
    protocol = Protocol.model_validate(template.protocol)
    if not protocol.name:
        protocol = protocol.model_copy(update={"name": template.name})
    return req.model_copy(update={"protocol": protocol, "template_id": None})
