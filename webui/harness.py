"""Drive the real thing: ``ergoseek demo`` in its own process (simulated machine, a fresh data
directory, a free port) and headless Chromium pages on its dashboard. Used by the browser
test, the dashboard benchmark and the screenshot script; needs the ``playwright`` package and
Debian's ``/usr/bin/chromium`` (no Playwright browser download).
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def ergoseek_command() -> list[str]:
    exe = shutil.which("ergoseek", path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, "-m", "server.cli"]


@dataclass
class DemoServer:
    """``ergoseek demo`` on 127.0.0.1; ``accounts`` (login, password, role) are created
    first. The trainer ``demo`` gets ``password``."""

    data_dir: Path
    password: str = "demo-password-1"
    accounts: list[tuple[str, str, str]] = field(default_factory=list)
    args: list[str] = field(default_factory=list)  # more flags for ``ergoseek demo``
    port: int = field(default_factory=free_port)
    proc: subprocess.Popen[bytes] | None = None
    log_path: Path | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        env.update(
            ERGOSEEK_DATA_DIR=str(self.data_dir),
            ERGOSEEK_DEMO_PASSWORD=self.password,
            PYTHONUNBUFFERED="1",
        )
        env.pop("ERGOSEEK_DATABASE_URL", None)
        env.pop("ERGOSEEK_CONFIG", None)
        return env

    def start(self, timeout: float = 60.0) -> DemoServer:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        for login, password, role in self.accounts:
            subprocess.run(
                [*ergoseek_command(), "account", "create", login, "--role", role],
                input=(password + "\n").encode(),
                env=self.env(),
                check=True,
                capture_output=True,
                timeout=60,
            )
        self.log_path = self.data_dir / "server.log"
        log = self.log_path.open("wb")
        self.proc = subprocess.Popen(
            [*ergoseek_command(), "demo", "--port", str(self.port), *self.args],
            env=self.env(),
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"ergoseek demo exited:\n{self.log()}")
            with contextlib.suppress(httpx.HTTPError):
                r = httpx.get(self.url + "/healthz", timeout=2.0)
                if r.status_code == 200 and r.json().get("status") == "ok":
                    return self
            time.sleep(0.2)
        self.stop()
        raise TimeoutError(f"ergoseek demo did not come up:\n{self.log()}")

    def log(self) -> str:
        if self.log_path is None or not self.log_path.exists():
            return ""
        return self.log_path.read_text(errors="replace")[-6000:]

    def stop(self, timeout: float = 20.0) -> int | None:
        """SIGINT (uvicorn's graceful shutdown), then SIGKILL if it hangs."""
        proc = self.proc
        if proc is None or proc.poll() is not None:
            return proc.returncode if proc is not None else None
        proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            return proc.wait(10)

    def __enter__(self) -> DemoServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- REST helpers (a logged-in httpx client) ---------------------------------------------------
    @contextlib.contextmanager
    def client(self, login: str = TRAINER, password: str | None = None) -> Iterator[httpx.Client]:
        """An httpx client logged in with the login cookie (and our own Origin)."""
        with httpx.Client(base_url=self.url, timeout=20.0, headers={"Origin": self.url}) as c:
            r = c.post(
                "/api/v1/auth/login", json={"login": login, "password": password or self.password}
            )
            r.raise_for_status()
            yield c


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of one process (all its threads, not its children), s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks


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
