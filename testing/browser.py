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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

from testing.server import ServerProcess, free_port

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
def chromium(nice: int = 0) -> Iterator[Any]:
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


def login(page: Any, base: str, name: str, password: str, timeout: float = 60.0) -> None:
    """Sign in on ``/`` and wait for the dashboard to be connected (its tabs are there)."""
    page.goto(base + "/")
    page.get_by_label("Login").fill(name)
    page.get_by_label("Password").fill(password)
    page.get_by_role("button", name="Sign in").click()
    page.wait_for_url(base + "/dashboard/", timeout=timeout * 1e3)
    page.get_by_role("tab", name="Live", exact=True).wait_for(timeout=timeout * 1e3)


def text_field(page: Any, label: str) -> Any:
    """A viser text input by its label. (viser 1.1.1 labels text inputs with ``for`` = the
    handle's uuid but gives the input Mantine's own id, so ``get_by_label`` misses them;
    number inputs are fine.)"""
    row = page.locator(".mantine-Flex-root").filter(has=page.get_by_text(label, exact=True))
    return row.locator("input, textarea").first


READOUT = re.compile(
    r"t = (?P<t>[-\d.]+) s .*?u = (?P<u>[-+\d.—]+) N·m", re.DOTALL
)  # the live readout above the charts


def readout(page: Any) -> dict[str, float | None] | None:
    """The live readout's t and u (motor torque written), or None before any data."""
    texts = page.locator("p", has_text="t = ").all_inner_texts()
    for text in texts:
        m = READOUT.search(text)
        if m:
            u = m.group("u")
            return {"t": float(m.group("t")), "u": None if u == "—" else float(u)}
    return None
