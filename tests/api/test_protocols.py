"""Protocol templates over HTTP against a real server: who may read, create, edit and delete
them, bad input refused with a 422 naming the field (nothing stored), the preview."""

from __future__ import annotations

import httpx
import pytest

from testing.server import ServerProcess

PROTOCOL = {
    "phases": [
        {"kind": "warmup", "duration": 60},
        {"kind": "seek", "duration": 120},
        {"kind": "train", "intervals": 6, "work": 20, "rest": 40},
        {"kind": "cooldown", "duration": 60},
    ]
}


def listed(c: httpx.Client) -> list[str]:
    r = c.get("/api/v1/protocols")
    assert r.status_code == 200
    return [t["name"] for t in r.json()]


def test_templates_by_role(server: ServerProcess) -> None:
    with server.client("trainer") as t, server.client("viewer") as v, server.client("admin") as a:
        own = t.post("/api/v1/protocols", json={"name": "mine", "protocol": PROTOCOL})
        assert own.status_code == 201, own.text
        shared = t.post("/api/v1/protocols",
                        json={"name": "team", "protocol": PROTOCOL, "shared": True})  # fmt: skip
        assert shared.status_code == 201
        own_id, team_id = own.json()["id"], shared.json()["id"]
        assert listed(t) == ["team", "mine"]
        assert listed(v) == ["team"]  # viewers read the shared ones
        assert v.get(f"/api/v1/protocols/{own_id}").status_code == 404  # not disclosed
        assert v.get(f"/api/v1/protocols/{team_id}").json()["protocol"]["phases"][2]["work"] == 20
        # viewers never write
        assert (
            v.post("/api/v1/protocols", json={"name": "x", "protocol": PROTOCOL}).status_code == 403
        )
        assert v.patch(f"/api/v1/protocols/{team_id}", json={"name": "y"}).status_code == 403
        assert v.delete(f"/api/v1/protocols/{team_id}").status_code == 403
        # another trainer (the admin's account here is another person) edits the shared one
        r = a.patch(f"/api/v1/protocols/{team_id}", json={"description": "by the admin"})
        assert r.status_code == 200 and r.json()["description"] == "by the admin"
        assert "mine" in listed(a)
        r = t.patch(
            f"/api/v1/protocols/{own_id}", json={"protocol": {"phases": [{"kind": "seek"}]}}
        )
        assert r.status_code == 200 and [p["kind"] for p in r.json()["protocol"]["phases"]] == [
            "seek"
        ]
        dup = t.post("/api/v1/protocols", json={"name": "MINE", "protocol": PROTOCOL})
        assert dup.status_code == 409
        assert t.delete(f"/api/v1/protocols/{own_id}").status_code == 204
        assert t.get(f"/api/v1/protocols/{own_id}").status_code == 404
        assert listed(t) == ["team"]
    with server.client(None) as anon:
        assert anon.get("/api/v1/protocols").status_code == 401


@pytest.mark.parametrize(
    ("body", "loc"),
    [
        ({"name": "b", "protocol": {"phases": [{"kind": "train", "work": -1}]}},
         ["body", "protocol", "phases", 0, "train", "work"]),
        ({"name": "b", "protocol": {"phases": [{"kind": "hiit"}]}},
         ["body", "protocol", "phases", 0]),
        ({"name": "b", "protocol": {"phases": [{"kind": "cooldown"}, {"kind": "seek"}]}},
         ["body", "protocol"]),
        ({"name": "", "protocol": PROTOCOL}, ["body", "name"]),
        ({"name": "b", "protocol": PROTOCOL, "owner": 3}, ["body", "owner"]),
        ({"name": "b", "protocol": {"phases": [{"kind": "seek", "duration": "NaN"}]}},
         ["body", "protocol", "phases", 0, "seek", "duration"]),
    ],
)  # fmt: skip
def test_a_bad_template_is_422_naming_the_field_and_nothing_is_stored(
    server: ServerProcess, body: dict, loc: list
) -> None:
    with server.client("trainer") as c:
        before = listed(c)
        r = c.post("/api/v1/protocols", json=body)
        assert r.status_code == 422, r.text
        detail = r.json()["detail"][0]
        assert detail["loc"][: len(loc)] == loc and detail["msg"]
        assert listed(c) == before


def test_the_preview_says_how_long_a_protocol_takes_for_a_user(server: ServerProcess) -> None:
    with server.client("trainer") as c:
        user = c.post("/api/v1/users", json={"name": "Preview"}).json()
        r = c.post("/api/v1/protocols/preview", json={"protocol": PROTOCOL, "user_id": user["id"]})
        assert r.status_code == 200, r.text
        out = r.json()
        assert [p["kind"] for p in out["phases"]] == ["warmup", "seek", "train", "cooldown"]
        assert out["phases"][2]["longest"] == 3 + 6 * 60
        assert out["duration"] >= sum(p["longest"] for p in out["phases"])
        assert out["summary"].startswith("warmup 60 s → seek ≤ 120 s → train 6 × 20/40 s")
        fast = {"phases": [{"kind": "warmup", "velocity": 9.0}]}  # above the bracket's γ3
        r = c.post("/api/v1/protocols/preview", json={"protocol": fast, "user_id": user["id"]})
        assert r.status_code == 422 and "upper bound" in r.text
