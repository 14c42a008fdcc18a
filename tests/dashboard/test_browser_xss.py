"""Stored text on the dashboard, in the real browser (issue 12.1): users named with script
payloads of several shapes, added over REST by a trainer, then an admin opens the dashboard.

Every name is shown as its literal text wherever the dashboard shows a name (the Live tab's
picker and stored-optimum line, the status line of a running session, History's picker,
summary and table, the Users tab's form and message) and no script runs: the payloads set a
page-side flag (``window.pwned``), try to create an admin account, or become links; none of
that happens. The page's Content-Security-Policy is tested on its own: an inline script or
handler injected into the page does not run, and loading the dashboard reports no violation
but the one viser's bundle always causes.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from typing import Any

import pytest

from testing.browser import (
    CSP_RECORDER,
    TRAINER,
    VIEWPORT,
    DemoServer,
    csp_violations,
    login,
    open_tab,
    pick,
    text_field,
    wait_text,
)

ADMIN, ADMIN_PASSWORD = "chief", "chief-admin-Rt5b-Lm29-xQ"
EVIL = "evil"  # the login the first payload tries to create, as an admin
PAYLOADS = (
    # (the attack: an admin opening the dashboard creates an admin account)
    "<iframe srcdoc=\"<script>top.pwned=1;fetch('/api/v1/accounts',{method:'POST',"
    "headers:{'Content-Type':'x/json'},body:JSON.stringify({login:'evil',"
    "password:'Evil-pw-9876x',role:'admin'})})</script>\">",
    '<img src=x onerror="window.pwned=2">',
    '<svg onload="window.pwned=3"></svg>',
    "<script>window.pwned=4</script>",
    '<details open ontoggle="window.pwned=5">d</details>',
    "[click me](javascript:window.pwned=6)",
    '<a href="javascript:window.pwned=7">tap</a>',
    "**bold** _it_ | cell | `code` # head",
    "www.evil.example http://evil.example mail@evil.example",
    "&lt;b&gt; &amp; &#60;i&#62;",
)
# viser's bundle instantiates its Gaussian-splat sorter at start-up, whose emscripten glue
# calls Function(): blocked (no 'unsafe-eval'), harmless (no splats here), always reported.
KNOWN_VIOLATIONS = {("script-src", "eval")}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DemoServer]:
    demo = DemoServer(tmp_path_factory.mktemp("xss"), accounts=[(ADMIN, ADMIN_PASSWORD, "admin")])
    with demo:
        yield demo
    print(demo.log()[-3000:])


@pytest.fixture(scope="module")
def users(server: DemoServer) -> dict[str, str]:
    """payload → the label the pickers show for that user, added over REST by a trainer."""
    labels = {}
    with server.client(TRAINER) as api:
        for name in PAYLOADS:
            r = api.post("/api/v1/users", json={"name": name, "notes": name, "limb": name[:64]})
            assert r.status_code == 201, r.text
            assert r.json()["name"] == name  # stored as given: the dashboard must escape it
            labels[name] = f"{name} (#{r.json()['id']})"
    return labels


@pytest.fixture(scope="module")
def page(server: DemoServer, browser: Any, users: dict[str, str]) -> Iterator[Any]:
    context = browser.new_context(viewport=VIEWPORT)
    context.add_init_script(CSP_RECORDER)
    page = context.new_page()
    login(page, server.url, ADMIN, ADMIN_PASSWORD)
    yield page
    context.close()


def pwned(page: Any) -> Any:
    return page.evaluate("window.pwned ?? null")


def literal(page: Any, prefix: str, name: str, suffix: str = "") -> None:
    """A paragraph reads ``prefix + name + suffix``, the name as its literal text."""
    try:
        wait_text(page, re.escape(prefix + name + suffix), 10_000)
    except AssertionError as exc:
        raise AssertionError(f"{name!r} not shown as text; window.pwned = {pwned(page)}") from exc


def assert_nothing_ran(server: DemoServer, page: Any) -> None:
    assert pwned(page) is None
    found = page.evaluate(
        """() => ({
        iframes: document.querySelectorAll('iframe').length,
        images: [...document.images].filter(i => i.getAttribute('src') === 'x').length,
        handlers: document.querySelectorAll('[onload],[onerror],[ontoggle]').length,
        details: document.querySelectorAll('details').length,
        scripts: [...document.scripts].filter(s => s.textContent.includes('pwned')).length,
        links: [...document.querySelectorAll('a[href]')].map(a => a.getAttribute('href'))
            .filter(h => !h.startsWith('/')),
        })"""
    )
    assert found == {
        "iframes": 0, "images": 0, "handlers": 0, "details": 0, "scripts": 0, "links": []
    }, found  # fmt: skip
    with server.client(ADMIN, ADMIN_PASSWORD) as api:
        logins = {a["login"] for a in api.get("/api/v1/accounts").json()}
    assert EVIL not in logins


def test_names_show_as_text_in_the_live_tab(server: DemoServer, page: Any, users: dict) -> None:
    assert_nothing_ran(server, page)  # before anything is picked: the picker's default
    for name, label in users.items():
        pick(page, "User", label)  # the picker shows the label as text (exact match)
        literal(page, "Stored optimum for ", name, ": none yet")
    assert_nothing_ran(server, page)


def test_a_running_sessions_status_line_shows_the_name_as_text(
    server: DemoServer, page: Any, users: dict[str, str]
) -> None:
    name = PAYLOADS[0]
    user_id = int(users[name].rsplit("#", 1)[1].rstrip(")"))
    with server.client(TRAINER) as api:
        r = api.post("/api/v1/sessions", json={"user_id": user_id, "duration": 60})
        assert r.status_code == 201, r.text
        session = r.json()["id"]
        try:
            literal(page, f"Session #{session} (", name, ") running")
            assert_nothing_ran(server, page)
        finally:
            api.post(f"/api/v1/sessions/{session}/stop")
    server.wait_status(session, {"stopped", "completed", "aborted"}, 30.0, login=ADMIN)
    wait_text(page, rf"Last session #{session}: stopped")


def test_names_show_as_text_in_history(server: DemoServer, page: Any, users: dict) -> None:
    open_tab(page, "History")
    for name, label in users.items():
        pick(page, "History of", label)
        sessions = "1 session" if name == PAYLOADS[0] else "0 sessions"
        literal(page, "", name, f" · {sessions}")
    assert_nothing_ran(server, page)


def test_names_show_as_text_in_the_users_tab(server: DemoServer, page: Any, users: dict) -> None:
    open_tab(page, "Users")
    for name, label in users.items():
        pick(page, "Profile", label)
        field = text_field(page, "Name")
        deadline = time.monotonic() + 10
        while field.input_value() != name and time.monotonic() < deadline:
            time.sleep(0.1)
        assert field.input_value() == name
        page.get_by_role("button", name="Save user").click()
        literal(page, "Saved user ", name, f" ({label.rsplit(' (', 1)[1]}")
    assert_nothing_ran(server, page)
    open_tab(page, "Live")


def test_the_page_runs_no_inline_script_it_did_not_ship(page: Any) -> None:
    """The CSP on its own (escaping aside): an inline script or handler put into the page
    does not run; loading the dashboard caused no violation but the known one."""
    loaded = {(v["directive"], v["blocked"]) for v in csp_violations(page)}
    assert loaded <= KNOWN_VIOLATIONS, csp_violations(page)
    page.evaluate(
        """() => {
        const s = document.createElement('script');
        s.textContent = 'window.cspProbe = 1';
        document.body.appendChild(s);
        const i = document.createElement('img');
        i.setAttribute('onerror', 'window.cspProbe = 2');
        i.src = 'data:,not-an-image';
        document.body.appendChild(i);
        const f = document.createElement('iframe');
        f.id = 'csp-probe';
        f.srcdoc = '<script>parent.cspProbe = 3</script><p>loaded</p>';
        document.body.appendChild(f);
        }"""
    )
    page.wait_for_function(
        """() => {
        const d = document.getElementById('csp-probe').contentDocument;
        return d && d.readyState === 'complete' && d.body && d.body.textContent === 'loaded';
        }""",
        timeout=10_000,
    )
    page.wait_for_function(  # (the srcdoc frame reports its own violation to itself)
        """() => window.cspProbe != null
            || window.__csp.filter(v => v.directive.startsWith('script-src')).length >= 2""",
        timeout=10_000,
    )
    assert page.evaluate("window.cspProbe ?? null") is None
    directives = {v["directive"] for v in csp_violations(page)}
    assert {"script-src-elem", "script-src-attr"} <= directives, csp_violations(page)
    page.evaluate("document.getElementById('csp-probe').remove()")
