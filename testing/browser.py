"""Drive the real thing: ``ergoseek demo`` in its own process (simulated machine, a fresh data
directory, a free port) and headless Chromium pages on its dashboard. Used by the browser
test, the dashboard benchmark and the screenshot script; needs the ``playwright`` package and
Debian's ``/usr/bin/chromium`` (no Playwright browser download).
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import httpx
import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from testing.server import ServerProcess, free_port

if TYPE_CHECKING:
    from playwright.sync_api import Browser, BrowserContext, Locator, Page

CHROMIUM = os.environ.get("ERGOSEEK_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
]
VIEWPORT = {"width": 1500, "height": 950}
TRAINER = "demo"
SUBPROTOCOL = f"viser-v{viser.__version__}"
UI_TIMEOUT = 30_000  # ms, for anything the page must show
WORD_JOINER = "\u2060"  # invisible; the dashboard's escaping puts it into URLs and addresses
# Records every Content-Security-Policy violation of a page (add it with add_init_script).
CSP_RECORDER = """
window.__csp = [];
document.addEventListener('securitypolicyviolation', e => window.__csp.push(
  {directive: e.effectiveDirective, blocked: e.blockedURI, sample: e.sample}));
"""


class DemoServer(ServerProcess):
    """``ergoseek demo`` on 127.0.0.1; ``accounts`` (login, password, role) are created
    first. The trainer ``demo`` gets ``password``; :meth:`client` logs in with the cookie."""

    def __init__(
        self,
        data_dir: Path,
        password: str = "demo-password-1",
        accounts: list[tuple[str, str, str]] | None = None,
        args: list[str] | None = None,
        port: int | None = None,
    ) -> None:
        super().__init__(
            data_dir,
            command="demo",
            args=list(args or []),
            accounts=list(accounts or []),
            env={"ERGOSEEK_DEMO_PASSWORD": password},
            port=port or free_port(),
        )
        self.password = password

    def passwords(self) -> dict[str, str]:
        return {**super().passwords(), TRAINER: self.password}

    @contextlib.contextmanager
    def client(  # type: ignore[override]
        self, login: str = TRAINER, password: str | None = None
    ) -> Iterator[httpx.Client]:
        """An httpx client logged in with the login cookie (and our own Origin)."""
        with self.browser_client(login, password or self.passwords()[login]) as c:
            yield c


@contextlib.contextmanager
def chromium(nice: int = 0) -> Iterator[Browser]:
    """A headless Debian Chromium driven by Playwright; ``nice`` > 0 runs it (and every
    process it starts) at that niceness, through a wrapper script."""
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as p:
        exe = CHROMIUM
        if nice:
            wrapper = Path(tmp) / "chromium"
            wrapper.write_text(f'#!/bin/sh\nexec nice -n {int(nice)} {CHROMIUM} "$@"\n')
            wrapper.chmod(0o755)
            exe = str(wrapper)
        browser = p.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def login(
    page: Page,
    base: str,
    name: str,
    password: str,
    timeout: float = 60.0,
    ready: tuple[str, str] = ("tab", "Live"),
) -> None:
    """Sign in on ``/`` and wait for the dashboard to be connected: the element of ``ready``
    (its ARIA role and name; the Live tab, which a phone's layout keeps folded away) is
    there. A login that does not go on says what the page said (an AssertionError)."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    page.goto(base + "/")
    page.get_by_label("Login").fill(name)
    page.get_by_label("Password").fill(password)
    page.get_by_role("button", name="Sign in").click()
    try:  # the login answered and the browser went on (the dashboard's load is the next wait)
        page.wait_for_url(base + "/dashboard/", wait_until="commit", timeout=timeout * 1e3)
    except PlaywrightTimeout:
        said = page.locator("#error").text_content(timeout=5e3)
        raise AssertionError(
            f"signing in as {name!r} did not reach the dashboard in {timeout:g} s: "
            f"still at {page.url}, the page says {said!r}"
        ) from None
    role, label = ready
    found = page.get_by_role(role, name=label, exact=True)  # type: ignore[arg-type]
    found.wait_for(timeout=timeout * 1e3)


def open_tab(page: Page, name: str, timeout_ms: int = 2 * UI_TIMEOUT) -> None:
    """Click the dashboard's tab ``name``, waiting as long as :func:`login` does: just after
    the login the page may still be building its panels from the first messages, and in the
    parallel rooms of a clean clone's CI a click there waited past 30 s."""
    page.get_by_role("tab", name=name, exact=True).click(timeout=timeout_ms)


def text_field(page: Page, label: str) -> Locator:
    """A viser text input by its label. (viser 1.1.1 labels text inputs with ``for`` = the
    handle's uuid but gives the input Mantine's own id, so ``get_by_label`` misses them;
    number inputs are fine.)"""
    row = page.locator(".mantine-Flex-root").filter(has=page.get_by_text(label, exact=True))
    return row.locator("input, textarea").first


READOUT = re.compile(
    r"t = (?P<t>[-\d.]+) s .*?u = (?P<u>[-+\d.—]+) N·m", re.DOTALL
)  # the live readout above the charts


def readout(page: Page) -> dict[str, float | None] | None:
    """The live readout's t and u (motor torque written), or None before any data."""
    texts = page.locator("p", has_text="t = ").all_inner_texts()
    for text in texts:
        m = READOUT.search(text)
        if m:
            u = m.group("u")
            return {"t": float(m.group("t")), "u": None if u == "—" else float(u)}
    return None


# -- what a user does on the page, and what the tests wait for ------------------------------
def cookie_of(context: BrowserContext) -> str:
    """The login cookie a browser context holds."""
    return next(c["value"] for c in context.cookies() if c["name"] == "ergoseek_session")


def ws_status(url: str, headers: dict[str, str]) -> int:
    """101 if the dashboard WebSocket was accepted (and sent viser's first frame), else the
    HTTP status the handshake was refused with."""
    try:
        with connect(
            url,
            subprotocols=[SUBPROTOCOL],
            additional_headers=headers,
            max_size=2**26,
            open_timeout=10,
        ) as ws:
            assert ws.subprotocol == SUBPROTOCOL
            first = ws.recv(timeout=10)
            assert isinstance(first, bytes) and first
            return 101
    except InvalidStatus as exc:
        return exc.response.status_code


# viser's client sends GUI updates through one throttled sender per panel
# (client/src/WebsocketUtils.ts, makeThrottledMessageSender(50)): the first update goes at
# once, and of the updates in the next 50 ms only the latest is sent, to whatever input it
# belongs. A script that edits three inputs within 50 ms loses the middle one (the CI saw a
# countdown typed as 2 s run at its default 3 s); a person's hand is slower. So every edit
# here waits out the window after it, and the next edit or click is sent on its own.
VISER_SEND_INTERVAL_MS = 50


def _sent(page: Page) -> None:
    page.wait_for_timeout(VISER_SEND_INTERVAL_MS + 20)


def pick(page: Page, combobox: str, option: str) -> None:
    # A field left with Tab may hand the focus to a select whose list then opens over what
    # follows it; Escape closes any list that is open before this one is clicked.
    page.keyboard.press("Escape")
    page.get_by_role("combobox", name=combobox, exact=True).click()
    page.get_by_role("option", name=option, exact=True).click()
    _sent(page)


def set_number(page: Page, label: str, value: float) -> None:
    box = page.get_by_label(label, exact=True)
    box.fill(f"{value:g}")
    box.press("Tab")
    _sent(page)


def set_text(page: Page, label: str, value: str) -> None:
    text_field(page, label).fill(value)
    _sent(page)


def paragraphs(page: Page) -> list[str]:
    """The text of every paragraph, as a reader sees it (no invisible word joiners)."""
    return [t.replace(WORD_JOINER, "") for t in page.locator("p").all_inner_texts()]


def wait_text(page: Page, pattern: str, timeout_ms: int = UI_TIMEOUT) -> re.Match[str]:
    """Wait until a paragraph matches ``pattern``; returns the match."""
    rx = re.compile(pattern)
    deadline = time.monotonic() + timeout_ms / 1e3
    while True:
        for text in paragraphs(page):
            m = rx.search(text)
            if m:
                return m
        if time.monotonic() > deadline:
            shown = "\n".join(paragraphs(page))
            raise AssertionError(f"no paragraph matched {pattern!r} in:\n{shown}")
        time.sleep(0.2)


def element_shot(locator: Locator, timeout_s: float = 30.0) -> bytes:
    """A screenshot of the element ``locator`` finds, taken again if the element was replaced
    while it was taken (viser's client rebuilds a chart whose scales change)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return locator.screenshot()
        except Exception as exc:  # playwright's Error: "Element is not attached to the DOM"
            if "not attached" not in str(exc) or time.monotonic() > deadline:
                raise


def csp_violations(page: Page) -> list[dict[str, str]]:
    """The CSP violations the page reported (:data:`CSP_RECORDER` must be installed)."""
    return list(page.evaluate("window.__csp || []"))


Readout = dict[str, float | None]


def wait_readout(page: Page, until: Callable[[Readout], bool], timeout_s: float = 30.0) -> Readout:
    """Wait until the live readout satisfies ``until``; returns it."""
    deadline = time.monotonic() + timeout_s
    while True:
        r = readout(page)
        if r is not None and until(r):
            return r
        if time.monotonic() > deadline:
            raise AssertionError(f"the live readout never satisfied the condition (last {r})")
        time.sleep(0.2)
