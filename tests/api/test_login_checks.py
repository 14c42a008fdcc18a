"""The login checks themselves, in-process: the failed-login limiter (per name, per address,
per device cookie, its window and its memory bound), bearer and Origin parsing, who a request
is, the role dependencies and the login's own errors. Real parts: starlette requests built from
ASGI scopes, a SQLite store, argon2 hashes. (test_auth.py drives the same through a server.)

These are the tests that kill the mutants ``make mutation`` found alive in the ``auth`` target
(docs/testing.md, "Mutation testing"): each asserts a promise of server/security.py,
server/api/deps.py or server/api/auth.py that no end-to-end test pinned down.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import sqlite3
import time
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from fastapi import FastAPI, HTTPException, Response
from starlette.requests import Request

from server import security
from server.api import deps
from server.api.auth import HASHING_QUEUE, _authenticate, _check_password, _issue
from server.api.schemas import LoginIn
from server.security import (
    COOKIE,
    DEVICE_COOKIE,
    DEVICE_COOKIE_DAYS,
    HASHING_AT_ONCE,
    LoginLimiter,
    bearer,
    client_keys,
    cookie_write_allowed,
    device_key,
    identify,
    identify_async,
    origin_allowed,
    own_origins,
    retry_after_header,
    unauthorized,
)
from server.settings import Settings
from sessions.store import AccountRecord, Store, open_store
from sessions.store.tokens import digest
from testing.store import FAST_HASHER

HOST = "127.0.0.1:8000"
OWN = f"http://{HOST}"
EVIL = "http://evil.example"
TRUSTED = "https://trusted.example"
PASSWORD = "correct horse battery staple"
KEY = b"k" * 32


def request(
    method: str = "GET",
    *,
    client: str | None = "10.0.0.1",
    headers: dict[str, str] | None = None,
    cookies: dict[str, str] | None = None,
    app: FastAPI | None = None,
) -> Request:
    """A real starlette request, as uvicorn hands it over (header names lower-case)."""
    raw = [(b"host", HOST.encode())]
    raw += [(k.lower().encode(), v.encode()) for k, v in (headers or {}).items()]
    if cookies:
        raw.append((b"cookie", "; ".join(f"{k}={v}" for k, v in cookies.items()).encode()))
    scope = {
        "type": "http",
        "method": method,
        "path": "/api/v1/users",
        "raw_path": b"/api/v1/users",
        "query_string": b"",
        "headers": raw,
        "client": (client, 50000) if client else None,
        "server": ("127.0.0.1", 8000),
        "scheme": "http",
        "app": app,
    }
    return Request(scope)


def run(coro):  # type: ignore[no-untyped-def]
    """Run a coroutine, bounded: a check that deadlocks fails here instead of hanging."""
    return asyncio.run(asyncio.wait_for(coro, 10.0))


def lower(headers: dict[str, str] | None) -> dict[str, str]:
    """Header names compared as HTTP does: case-insensitively."""
    return {k.lower(): v for k, v in (headers or {}).items()}


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Store]:
    path = tmp_path_factory.mktemp("checks") / "ergoseek.sqlite"
    with open_store(f"sqlite:///{path}", password_hasher=FAST_HASHER) as s:
        for role in ("viewer", "trainer", "admin"):
            s.accounts.create(role, f"{PASSWORD} {role}", role)
        yield s


def account(store: Store, login: str) -> AccountRecord:
    found = store.accounts.by_login(login)
    assert found is not None
    return found


# -- errors ---------------------------------------------------------------------------------
def test_a_401_says_why_and_names_the_bearer_scheme() -> None:
    e = unauthorized()
    assert e.status_code == 401 and e.detail == "not logged in"
    assert {k: v.lower() for k, v in lower(e.headers).items()} == {"www-authenticate": "bearer"}
    assert unauthorized("gone").detail == "gone"


@pytest.mark.parametrize(("seconds", "header"), [(0.0, "1"), (0.01, "1"), (1.2, "2"), (5.0, "5")])
def test_retry_after_is_whole_seconds_and_at_least_one(seconds: float, header: str) -> None:
    assert lower(retry_after_header(seconds)) == {"retry-after": header}


# -- the failed-login limiter -----------------------------------------------------------------
def test_failures_count_per_name_and_four_times_as_many_per_address() -> None:
    lim = LoginLimiter(2, 60.0, KEY)
    a = request(client="10.0.0.1")
    b = request(client="10.0.0.2")
    assert lim.keys(a, " Alice ") == ["addr:10.0.0.1", "addr+login:10.0.0.1:alice"]
    lim.failed(lim.keys(a, "alice"))
    assert lim.retry_after(lim.keys(a, "alice")) == 0.0  # one of two
    lim.failed(lim.keys(a, "ALICE"))  # the same name, however typed
    assert 59.0 < lim.retry_after(lim.keys(a, "alice")) <= 60.0
    assert lim.retry_after(lim.keys(a, "bob")) == 0.0  # another name from the same address
    assert lim.retry_after(lim.keys(b, "alice")) == 0.0  # the same name from another address
    # guessing across names: 2 x 4 = 8 failures lock the address for every name
    for name in ("bob", "bob", "carol", "carol", "dave"):
        lim.failed(lim.keys(a, name))
    assert lim.retry_after(lim.keys(a, "eve")) == 0.0  # 7 of 8
    lim.failed(lim.keys(a, "dave"))
    assert 59.0 < lim.retry_after(lim.keys(a, "eve")) <= 60.0
    assert lim.retry_after(lim.keys(b, "eve")) == 0.0


def test_a_client_without_an_address_is_counted_as_one() -> None:
    assert client_keys(request(client=None), "x") == ["addr:?", "addr+login:?:x"]
    assert client_keys(request(client="::1"), "X") == ["addr:::1", "addr+login:::1:x"]


def test_a_success_forgives_the_name_not_the_address() -> None:
    lim = LoginLimiter(2, 60.0, KEY)
    a = request()
    lim.failed(lim.keys(a, "alice"))
    lim.succeeded(lim.keys(a, "alice"))
    lim.failed(lim.keys(a, "alice"))
    assert lim.retry_after(lim.keys(a, "alice")) == 0.0  # the first failure was forgiven
    # ... but the address still counts both: 6 more make 8
    for name in ("bob", "bob", "carol", "carol", "dave", "dave"):
        lim.failed(lim.keys(a, name))
    assert lim.retry_after(lim.keys(a, "eve")) > 0.0


def test_the_wait_is_until_the_oldest_counted_failure_leaves_the_window() -> None:
    window = 10.0
    lim = LoginLimiter(2, window, KEY)
    keys = lim.keys(request(), "alice")
    stamps = []
    for _ in range(3):
        before = time.monotonic()
        lim.failed(keys)
        stamps.append((before, time.monotonic()))
        time.sleep(0.2)
    now0 = time.monotonic()
    wait = lim.retry_after(keys)
    now1 = time.monotonic()
    # the limit is reached by the last two failures: the second one sets the wait
    (lo, hi) = stamps[1]
    assert lo + window - now1 <= wait <= hi + window - now0


def test_failures_older_than_the_window_are_forgotten() -> None:
    window = 2.0  # long against a loaded machine's scheduling delays
    lim = LoginLimiter(1, window, KEY)
    keys = lim.keys(request(), "alice")
    before = time.monotonic()
    lim.failed(keys)
    assert 0.0 < lim.retry_after(keys) <= window
    while time.monotonic() <= before + window:  # until that failure is surely out of it
        time.sleep(0.05)
    assert lim.retry_after(keys) == 0.0
    lim.failed(keys)  # counted afresh
    assert lim.retry_after(keys) > 0.0


def test_tracked_failures_stay_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(security, "MAX_TRACKED", 6)
    lim = LoginLimiter(1, 60.0, KEY)
    for i in range(30):  # rotating addresses: 2 keys each
        lim.failed(lim.keys(request(client=f"10.0.1.{i}"), "x"))
        assert len(lim._failures) <= 6 + 2
    # the newest are kept (the oldest forgotten)
    assert lim.retry_after(lim.keys(request(client="10.0.1.29"), "x")) > 0.0
    assert lim.retry_after(lim.keys(request(client="10.0.1.0"), "x")) == 0.0


def test_stale_keys_are_swept_first(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(security, "MAX_TRACKED", 6)
    lim = LoginLimiter(1, 0.2, KEY)
    for i in range(4):
        lim.failed(lim.keys(request(client=f"10.0.2.{i}"), "x"))
    time.sleep(0.25)
    lim.failed(lim.keys(request(client="10.0.3.1"), "x"))
    assert sorted(lim._failures) == ["addr+login:10.0.3.1:x", "addr:10.0.3.1"]


def test_memory_pressure_forgets_the_oldest_key_first_and_keeps_recent_locks(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(security, "MAX_TRACKED", 4)
    lim = LoginLimiter(1, 60.0, KEY)
    a = request(client="10.0.4.1")
    lim.failed(lim.keys(request(client="10.0.4.2"), "x"))  # the oldest two keys
    lim.failed(lim.keys(request(client="10.0.4.3"), "y"))
    lim.failed(lim.keys(a, "alice"))  # alice is locked at A
    lim.failed(lim.keys(request(client="10.0.4.4"), "z"))  # over the bound: a sweep
    assert len(lim._failures) == 4 + 2  # down to the bound (not below), then z's two keys
    assert lim.retry_after(lim.keys(a, "alice")) > 0.0  # a recent lock is kept
    assert lim.retry_after(lim.keys(request(client="10.0.4.2"), "x")) == 0.0  # the oldest went


def test_a_lock_on_the_name_outlives_its_address_key(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(security, "MAX_TRACKED", 4)
    lim = LoginLimiter(1, 60.0, KEY)
    a, b = request(client="10.0.5.1"), request(client="10.0.5.2")
    lim.failed(lim.keys(a, "alice"))  # addr:A, then addr+login:A:alice
    lim.failed(lim.keys(b, "x"))
    lim.failed(lim.keys(b, "y"))  # 5 keys: the next failure sweeps one, addr:A
    lim.failed(lim.keys(request(client="10.0.5.3"), "z"))
    assert "addr:10.0.5.1" not in lim._failures
    assert lim.retry_after(lim.keys(a, "alice")) > 0.0  # still locked by its own key


# -- device cookies ---------------------------------------------------------------------------
def sign(login: str, nonce: str, key: bytes = KEY) -> str:
    """The device cookie's signature, computed independently (HMAC-SHA256, 128 bits)."""
    return hmac.new(key, f"{login}|{nonce}".encode(), hashlib.sha256).hexdigest()[:32]


def with_device(value: str) -> Request:
    return request(cookies={DEVICE_COOKIE: value})


def test_a_device_cookie_is_signed_for_one_login() -> None:
    lim = LoginLimiter(2, 60.0, KEY)
    value = lim.device_cookie(" Alice ")
    nonce, _, sig = value.partition(".")
    assert nonce and sig == sign("alice", nonce)
    assert lim.device(with_device(value), "ALICE") == nonce
    assert lim.keys(with_device(value), "alice") == [f"device:{nonce}"]
    assert lim.device(with_device(value), "bob") is None
    assert lim.keys(with_device(value), "bob") == client_keys(with_device(value), "bob")
    assert LoginLimiter(2, 60.0, b"o" * 32).device(with_device(value), "alice") is None
    assert lim.device(with_device(f"{nonce}.{'0' * 32}"), "alice") is None
    assert lim.device(with_device(f".{sign('alice', '')}"), "alice") is None  # no nonce
    assert lim.device(request(), "alice") is None
    assert lim.device_cookie("alice") != value  # a new nonce each time


def test_a_device_cookie_is_at_most_128_characters() -> None:
    lim = LoginLimiter(2, 60.0, KEY)
    longest = "n" * (128 - 33)
    assert lim.device(with_device(f"{longest}.{sign('a', longest)}"), "a") == longest
    longer = longest + "n"
    assert lim.device(with_device(f"{longer}.{sign('a', longer)}"), "a") is None


def test_a_device_is_locked_on_its_own() -> None:
    lim = LoginLimiter(2, 60.0, KEY)
    cookie = with_device(lim.device_cookie("alice"))
    for _ in range(8):  # someone at the same address guesses alice's password
        lim.failed(lim.keys(request(), "alice"))
    assert lim.retry_after(lim.keys(request(), "alice")) > 0.0
    assert lim.retry_after(lim.keys(cookie, "alice")) == 0.0  # her browser still may
    lim.failed(lim.keys(cookie, "alice"))
    assert lim.retry_after(lim.keys(cookie, "alice")) == 0.0
    lim.failed(lim.keys(cookie, "alice"))  # the device's limit is `attempts`, not 4x
    assert lim.retry_after(lim.keys(cookie, "alice")) > 0.0
    lim.succeeded(lim.keys(cookie, "alice"))
    assert lim.retry_after(lim.keys(cookie, "alice")) == 0.0


def test_the_device_key_is_kept_beside_the_database(tmp_path: Path) -> None:
    key = device_key(tmp_path)
    path = tmp_path / security.DEVICE_KEY_FILE
    assert len(key) == 32 and path.read_bytes() == key
    assert path.stat().st_mode & 0o777 == 0o600
    assert device_key(tmp_path) == key  # the same after a restart
    fresh = device_key(None)
    assert len(fresh) == 32 and fresh != device_key(None)
    path.write_bytes(b"short")
    assert len(device_key(tmp_path)) == 32 and device_key(tmp_path) != b"short"


# -- who is asking ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("header", "token"),
    [
        ("Bearer abc", "abc"),
        ("bearer abc", "abc"),
        ("BEARER abc ", "abc"),
        ("Bearer  abc", "abc"),
        ("Basic abc", None),
        ("Bearer", None),
        ("Bearer   ", None),
        ("abc", None),
    ],
)
def test_a_bearer_token_is_read_from_the_authorization_header(
    header: str, token: str | None
) -> None:
    assert bearer(request(headers={"Authorization": header})) == token


def test_no_authorization_header_is_no_bearer_token() -> None:
    assert bearer(request()) is None


def test_origins() -> None:
    assert own_origins(request(), [TRUSTED]) == {OWN, f"https://{HOST}", TRUSTED}
    assert origin_allowed(request(), [])  # not a browser
    assert origin_allowed(request(headers={"Origin": OWN}), [])
    assert origin_allowed(request(headers={"Origin": f"https://{HOST}"}), [])
    assert origin_allowed(request(headers={"Origin": TRUSTED}), [TRUSTED])
    assert not origin_allowed(request(headers={"Origin": EVIL}), [TRUSTED])
    assert not cookie_write_allowed(request(), [TRUSTED])  # a write needs an Origin
    assert cookie_write_allowed(request(headers={"Origin": OWN}), [])
    assert cookie_write_allowed(request(headers={"Origin": TRUSTED}), [TRUSTED])
    assert not cookie_write_allowed(request(headers={"Origin": EVIL}), [TRUSTED])


def auth(value: str) -> dict[str, str]:
    return {"Authorization": value}


def test_identify_prefers_the_bearer_token(store: Store) -> None:
    viewer, trainer = account(store, "viewer"), account(store, "trainer")
    tok, _ = store.tokens.issue(viewer.id, "bearer", timedelta(hours=1))
    ck, _ = store.tokens.issue(trainer.id, "cookie", timedelta(hours=1))
    cases = [
        (request(headers={"Authorization": f"Bearer {tok}"}), viewer.id, "bearer"),
        (request(cookies={COOKIE: ck}), trainer.id, "cookie"),
        (request(headers=auth(f"Bearer {tok}"), cookies={COOKIE: ck}), viewer.id, "bearer"),
        # a non-bearer Authorization (a proxy's Basic) leaves the cookie in charge
        (request(headers=auth(f"Basic {tok}"), cookies={COOKIE: ck}), trainer.id, "cookie"),
        (request(headers={"Authorization": "Bearer forged"}), None, "bearer"),
        (request(cookies={COOKIE: "forged"}), None, "cookie"),
        (request(), None, "none"),
    ]
    for req, want, how in cases:
        for found, via in (identify(req, store), run(identify_async(req, store))):
            assert (found.id if found else None, via) == (want, how)


def test_login_checks_never_wait_behind_the_default_thread_pool(store: Store) -> None:
    """identify_async runs on the checks' own threads: with the event loop's default pool
    taken by blocked work (password hashing, exports), a token is still checked at once."""
    from concurrent.futures import ThreadPoolExecutor
    from threading import Event

    viewer = account(store, "viewer")
    tok, _ = store.tokens.issue(viewer.id, "bearer", timedelta(hours=1))
    req = request(headers={"Authorization": f"Bearer {tok}"})
    release = Event()

    async def check() -> tuple[AccountRecord | None, str]:
        loop = asyncio.get_running_loop()
        busy = ThreadPoolExecutor(max_workers=1)
        loop.set_default_executor(busy)
        blocked = loop.run_in_executor(None, release.wait, 30.0)
        try:
            return await asyncio.wait_for(identify_async(req, store), 3.0)
        finally:
            release.set()
            await blocked

    found, via = run(check())
    assert found is not None and (found.id, via) == (viewer.id, "bearer")


def test_the_runtime_is_the_apps() -> None:
    app = FastAPI()
    app.state.runtime = object()
    assert run(deps.get_runtime(request(app=app))) is app.state.runtime


# -- the role dependencies --------------------------------------------------------------------
def current(req: Request, store: Store, origins: list[str] | None = None) -> AccountRecord:
    settings = Settings(allowed_origins=origins or [])
    return run(deps.current_account(req, store, settings))


def refused(req: Request, store: Store, origins: list[str] | None = None) -> HTTPException:
    with pytest.raises(HTTPException) as e:
        current(req, store, origins)
    return e.value


def test_the_current_account_and_why_there_is_none(store: Store) -> None:
    trainer = account(store, "trainer")
    ck, _ = store.tokens.issue(trainer.id, "cookie", timedelta(hours=1))
    tok, _ = store.tokens.issue(trainer.id, "bearer", timedelta(hours=1))
    e = refused(request(), store)
    assert (e.status_code, e.detail) == (401, "not logged in")
    assert lower(e.headers)["www-authenticate"].lower() == "bearer"
    for req in (request(cookies={COOKIE: "stale"}), request(headers={"Authorization": "Bearer x"})):
        e = refused(req, store)
        assert (e.status_code, e.detail) == (401, "login expired or revoked")
    store.tokens.revoke(tok)
    e = refused(request(headers={"Authorization": f"Bearer {tok}"}), store)
    assert (e.status_code, e.detail) == (401, "login expired or revoked")
    assert current(request(cookies={COOKIE: ck}), store).id == trainer.id


def test_a_change_by_cookie_needs_one_of_our_origins(store: Store) -> None:
    trainer = account(store, "trainer")
    ck, _ = store.tokens.issue(trainer.id, "cookie", timedelta(hours=1))
    tok, _ = store.tokens.issue(trainer.id, "bearer", timedelta(hours=1))
    for method in ("POST", "PATCH", "DELETE"):
        for origin in ({}, {"Origin": EVIL}):
            e = refused(request(method, cookies={COOKIE: ck}, headers=origin), store, [TRUSTED])
            assert (e.status_code, e.detail) == (403, "cross-site request refused")
        for good in (OWN, TRUSTED):
            req = request(method, cookies={COOKIE: ck}, headers={"Origin": good})
            assert current(req, store, [TRUSTED]).id == trainer.id
        # a bearer token is not sent cross-site by a browser: no Origin needed
        req = request(method, headers={"Authorization": f"Bearer {tok}", "Origin": EVIL})
        assert current(req, store).id == trainer.id
    for method in ("GET", "HEAD", "OPTIONS"):  # reads need no Origin
        assert current(request(method, cookies={COOKIE: ck}), store).id == trainer.id


def test_the_body_guards_login_is_reused(store: Store) -> None:
    admin = account(store, "admin")
    req = request()
    req.scope["state"] = {"identity": (admin, "bearer")}
    assert current(req, store).id == admin.id  # no token on this request: the guard's
    req = request("POST")
    req.scope["state"] = {"identity": (admin, "cookie")}
    assert refused(req, store).status_code == 403  # still the cookie's Origin rule


@pytest.mark.parametrize("need", ["viewer", "trainer", "admin"])
def test_roles_nest(store: Store, need: str) -> None:
    rank = {"viewer": 0, "trainer": 1, "admin": 2}
    check = deps.require(need)  # type: ignore[arg-type]
    for role in ("viewer", "trainer", "admin"):
        who = account(store, role)
        if rank[role] >= rank[need]:
            assert run(check(who)) is who
        else:
            with pytest.raises(HTTPException) as e:
                run(check(who))
            assert e.value.status_code == 403
            assert e.value.detail == f"needs the {need} role (you are {role})"


# -- logging in -------------------------------------------------------------------------------
def login_app(secure: bool) -> FastAPI:
    app = FastAPI()
    app.state.settings = Settings(cookie_secure=secure)
    return app


def log_in(
    store: Store, lim: LoginLimiter, login: str, password: str, *, secure: bool = False
) -> tuple[AccountRecord, Response]:
    response = Response()
    req = request("POST", app=login_app(secure))
    body = LoginIn(login=login, password=password)
    return run(_authenticate(req, response, body, store, lim)), response


def test_a_login_sets_the_device_cookie(store: Store) -> None:
    lim = LoginLimiter(3, 60.0, KEY)
    for secure in (False, True):
        found, response = log_in(store, lim, "viewer", f"{PASSWORD} viewer", secure=secure)
        assert found.login == "viewer"
        cookie = response.headers["set-cookie"]
        name, _, rest = cookie.partition("=")
        value = rest.split(";")[0]
        attrs = {a.strip().lower() for a in cookie.split(";")[1:]}
        assert name == DEVICE_COOKIE and lim.device(with_device(value), "viewer")
        assert f"max-age={DEVICE_COOKIE_DAYS * 86400}" in attrs
        assert {"httponly", "samesite=strict"} <= attrs
        # a cookie's path matches case-sensitively (RFC 6265 5.1.4): only its name is not
        paths = [a.strip().partition("=")[2] for a in cookie.split(";")[1:]
                 if a.strip().lower().startswith("path=")]  # fmt: skip
        assert paths == ["/api/v1/auth"]
        assert ("secure" in attrs) is secure


def test_wrong_passwords_are_counted_then_refused_even_when_right(store: Store) -> None:
    lim = LoginLimiter(2, 60.0, KEY)
    for _ in range(2):
        with pytest.raises(HTTPException) as e:
            log_in(store, lim, "trainer", "not the password")
        assert (e.value.status_code, e.value.detail) == (401, "wrong login name or password")
    with pytest.raises(HTTPException) as e:
        log_in(store, lim, "trainer", f"{PASSWORD} trainer")
    assert e.value.status_code == 429
    assert e.value.detail == "too many failed logins: try again later"
    assert 59 <= int(lower(e.value.headers)["retry-after"]) <= 60
    # another login name from the same address is not locked by these two
    assert log_in(store, lim, "admin", f"{PASSWORD} admin")[0].login == "admin"


def test_a_lock_holds_to_its_last_fraction_of_a_second(store: Store) -> None:
    # a one-second window: the wait left is always under a second, and still a lock
    for _ in range(5):
        lim = LoginLimiter(1, 1.0, KEY)
        with pytest.raises(HTTPException):
            log_in(store, lim, "viewer", "not the password")
        failed = time.monotonic()
        try:
            log_in(store, lim, "viewer", f"{PASSWORD} viewer")
        except HTTPException as e:
            assert e.status_code == 429
            assert lower(e.headers)["retry-after"] == "1"
            return
        # let in: only right if the second was over before the check (a loaded machine)
        assert time.monotonic() - failed >= 1.0, "a login inside the locked second was let in"
    pytest.fail("five tries all took more than a second: inconclusive")


def test_a_success_resets_the_names_count(store: Store) -> None:
    lim = LoginLimiter(2, 60.0, KEY)
    with pytest.raises(HTTPException):
        log_in(store, lim, "trainer", "not the password")
    log_in(store, lim, "trainer", f"{PASSWORD} trainer")
    with pytest.raises(HTTPException) as e:
        log_in(store, lim, "trainer", "not the password")
    assert e.value.status_code == 401  # not 429: the first failure was forgiven
    assert log_in(store, lim, "trainer", f"{PASSWORD} trainer")[0].login == "trainer"


def test_too_many_waiting_logins_are_refused_at_once(store: Store) -> None:
    lim = LoginLimiter(2, 60.0, KEY)
    body = LoginIn(login="viewer", password=f"{PASSWORD} viewer")
    lim.hashing_waiting = HASHING_QUEUE
    with pytest.raises(HTTPException) as e:
        run(_check_password(store, lim, body))
    assert e.value.status_code == 503 and e.value.detail == "too many logins at once: try again"
    assert lower(e.value.headers) == {"retry-after": "1"}
    lim.hashing_waiting = HASHING_QUEUE - 1  # one place left: it waits, then hashes
    assert run(_check_password(store, lim, body)).login == "viewer"
    assert lim.hashing_waiting == HASHING_QUEUE - 1
    assert lim.hashing._value == HASHING_AT_ONCE  # the slot was given back
    wrong = LoginLimiter(2, 60.0, KEY)
    nobody = LoginIn(login="viewer", password="no")
    assert run(_check_password(store, wrong, nobody)) is None
    assert wrong.hashing_waiting == 0 and wrong.hashing._value == HASHING_AT_ONCE


def test_password_checks_run_a_few_at_a_time(tmp_path: Path) -> None:
    """With the server's own hasher (argon2, 64 MiB, ~0.1 s a check), six at once."""
    store = open_store(f"sqlite:///{tmp_path / 'slow.sqlite'}")
    store.accounts.create("viewer", f"{PASSWORD} viewer", "viewer")
    lim = LoginLimiter(50, 60.0, KEY)
    body = LoginIn(login="viewer", password=f"{PASSWORD} viewer")
    seen: list[int] = []

    async def burst() -> list[AccountRecord | None]:
        async def watch() -> None:
            while True:
                seen.append(HASHING_AT_ONCE - lim.hashing._value)
                await asyncio.sleep(0.005)

        watcher = asyncio.create_task(watch())
        found = await asyncio.gather(*(_check_password(store, lim, body) for _ in range(6)))
        watcher.cancel()
        return found

    try:
        found = run(burst())
    finally:
        store.close()
    assert all(f is not None and f.login == "viewer" for f in found)
    assert 1 <= max(seen) <= HASHING_AT_ONCE  # never more than that at once


def test_a_new_login_forgets_the_dead_ones(store: Store) -> None:
    viewer = account(store, "viewer")
    old, _ = store.tokens.issue(viewer.id, "cookie", timedelta(hours=1))
    store.tokens.revoke(old)
    before = datetime.now(UTC)
    secret, record = _issue(store, viewer.id, "bearer", timedelta(hours=2))
    assert (record.account_id, record.kind) == (viewer.id, "bearer")
    assert timedelta(hours=2) <= record.expires_at - before <= timedelta(hours=2, seconds=30)
    found = store.tokens.resolve(secret)
    assert found is not None and found.id == viewer.id
    with sqlite3.connect(store.url.removeprefix("sqlite:///")) as con:
        digests = {d for (d,) in con.execute("select digest from auth_tokens")}
    assert digest(old) not in digests and digest(secret) in digests  # the revoked one is gone
