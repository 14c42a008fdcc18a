"""schemathesis against the server's own OpenAPI schema: no input, however odd, is a 500.

Every operation gets bounded property-based examples (schemathesis' strategies, run by
hypothesis) sent to a real server as an admin, who may call everything."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from testing.server import ServerProcess, start_server

EXAMPLES = 15
STATUS: list[int] = []


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> ServerProcess:
    with start_server(tmp_path_factory.mktemp("schema")) as srv:
        with srv.client("admin") as c:  # something to find behind the ids
            uid = c.post("/api/v1/users", json={"name": "Schema"}).json()["id"]
            c.post("/api/v1/sessions", json={"user_id": uid, "duration": 1.0})
        yield srv


def test_no_server_errors(server: ServerProcess, tmp_path: Path) -> None:
    schema = schemathesis.openapi.from_url(f"{server.url}/openapi.json")
    # logging itself out would only test the 401s (test_server_auth does that)
    operations = [
        r.ok() for r in schema.get_all_operations() if r.ok().path != "/api/v1/auth/logout"
    ]
    assert len(operations) >= 20
    errors: list[str] = []
    headers = server.headers("admin")
    admin_id = httpx.get(f"{server.url}/api/v1/auth/me", headers=headers).json()["account"]["id"]
    calls = 0

    for op in operations:

        @given(case=op.as_strategy(), data=st.data())
        @settings(
            max_examples=EXAMPLES,
            deadline=None,
            derandomize=True,
            database=None,
            suppress_health_check=list(HealthCheck),
        )
        def run(case: schemathesis.Case, data: st.DataObject) -> None:
            nonlocal calls
            # the fuzzer must not log itself out or lock its own account: tested elsewhere
            assume((case.path_parameters or {}).get("account_id") != admin_id)
            calls += 1
            response = case.call(base_url=server.url, headers=headers, timeout=30)
            STATUS.append(response.status_code)
            if response.status_code >= 500:
                errors.append(
                    f"{case.method} {case.formatted_path} → {response.status_code}: "
                    f"{response.text[:200]}"
                )

        run()
    assert calls >= len(operations) * 3
    assert {200, 201, 404, 422} <= set(STATUS)  # it reached the handlers, not just the gate
    assert errors == []
    assert server.proc.poll() is None  # and the server is still up
