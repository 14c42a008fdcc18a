"""The dashboard on a desktop, a tablet (landscape and portrait) and a phone (issue 16), in
Debian's Chromium against ``ergoseek demo`` with a session running: one page load per size.

At each size: the E-STOP is inside the viewport without scrolling, finger-sized, and nothing
covers it (``elementFromPoint`` at its centre is the button); Start and Stop likewise; the
live velocity and power are shown as large numbers, on screen, and move; no two panels
overlap. With ``ERGOSEEK_UPDATE_SCREENSHOT=1`` the shots replace ``docs/img/dashboard-*.png``
(otherwise they stay in the test's tmp_path).
"""

from __future__ import annotations

import os
import re
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from testing.browser import TRAINER, UI_TIMEOUT, DemoServer, login
from testing.screenshot import DEFAULT_OUT, dismiss_notifications
from webui import layout

SIZES = {
    "desktop": (1500, 950),
    "tablet-landscape": (1024, 768),
    "tablet-portrait": (768, 1024),
    "phone": (390, 844),
}
ADA = 1  # the demo's first user
NUMBER = re.compile(r"^[-+]?\d+\.\d+$")

# Where an element is and what is on top of it at its centre.
REACH_JS = """(el) => {
  if (typeof el === 'string') el = el.startsWith('button=')
    ? [...document.querySelectorAll('button')].find(b => b.textContent.trim() === el.slice(7))
    : document.querySelector(el);
  const r = el.getBoundingClientRect();
  const x = r.x + r.width / 2, y = r.y + r.height / 2;
  const top = document.elementFromPoint(x, y);
  return {x: r.x, y: r.y, w: r.width, h: r.height, vw: innerWidth, vh: innerHeight,
          hit: top !== null && (el === top || el.contains(top)),
          top: top === null ? null : top.outerHTML.slice(0, 160)};
}"""

# The rectangle of each panel, found from one element inside it (its marker): the outermost
# ancestor that holds no other panel's marker, stopping at a positioned (docked or floating)
# window.
PANELS_JS = """(els) => {
  els = els.map(([n, e]) => [n, typeof e === 'string' ? document.querySelector(e) : e]);
  const out = {};
  for (const [name, el] of els) {
    if (el === null) { out[name] = null; continue; }
    const others = els.filter(([n, e]) => n !== name && e !== null).map(([, e]) => e);
    let cur = el;
    while (cur.parentElement && !others.some(o => cur.parentElement.contains(o))) {
      const cs = getComputedStyle(cur), r = cur.getBoundingClientRect();
      if ((cs.position === 'absolute' || cs.position === 'fixed') && r.width > 100
          && r.height > 100) break;
      cur = cur.parentElement;
    }
    const r = cur.getBoundingClientRect();
    out[name] = [r.x, r.y, r.width, r.height];
  }
  return out;
}"""


def markers(page: Any) -> list[tuple[str, Any]]:
    """One element inside each panel (on a phone, a sheet section's header)."""

    def section(name: str) -> Any:
        return page.get_by_role("button", name=re.compile(f"^Expand panel {name}"))

    found = [
        ("controls", page.get_by_role("tab", name="History").or_(section("Live"))),
        ("seeker", page.get_by_role("progressbar").or_(section("Seeker"))),
    ]
    # (the numbers are re-rendered ~6 times a second: found inside the page's script, at once)
    for name, loc in found:
        loc.first.evaluate(f"e => e.setAttribute('data-marker', '{name}')", timeout=UI_TIMEOUT)
    return [("main", ".ergoseek-w")] + [(name, f"[data-marker={name}]") for name, _ in found]


@pytest.fixture(scope="module")
def running(server: DemoServer) -> Iterator[int]:
    """A session for the demo user, running through every size's page."""
    with server.client() as api:
        r = api.post("/api/v1/sessions", json={"user_id": ADA, "duration": 600})
        r.raise_for_status()
        sid = int(r.json()["id"])
        yield sid
        api.post(f"/api/v1/sessions/{sid}/stop")


def open_dashboard(browser: Any, server: DemoServer, width: int, height: int) -> Any:
    page = browser.new_page(viewport={"width": width, "height": height})
    login(page, server.url, TRAINER, server.password, UI_TIMEOUT * 2e-3, ("button", "E-STOP"))
    return page


def live_number(page: Any, name: str) -> str:
    text = page.evaluate(f"() => document.querySelector('.ergoseek-{name}')?.textContent")
    return (text or "").strip()


def wait_moving(page: Any) -> tuple[str, str]:
    """Wait until the large velocity number shows a number, and the session time under the
    power changes (the numbers are live, not a picture)."""
    deadline = time.monotonic() + UI_TIMEOUT / 1e3
    first = None
    while time.monotonic() < deadline:
        w, clock = live_number(page, "w"), live_number(page, "numbers")
        if NUMBER.match(w):
            if first is None:
                first = clock
            elif clock != first:
                return w, live_number(page, "p")
        time.sleep(0.2)
    raise AssertionError(f"the live velocity never moved (first {first!r})")


def overlap(a: list[float], b: list[float]) -> float:
    dx = min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0])
    dy = min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])
    return max(dx, 0.0) * max(dy, 0.0)


def in_reach(page: Any, target: Any, what: str) -> dict[str, Any]:
    """``target``: a locator, or a CSS selector resolved in the page at once."""
    r = page.evaluate(REACH_JS, target) if isinstance(target, str) else target.evaluate(REACH_JS)
    inside = r["x"] >= 0 and r["y"] >= 0 and r["x"] + r["w"] <= r["vw"]
    assert inside and r["y"] + r["h"] <= r["vh"], f"{what} not inside the viewport: {r}"
    assert r["hit"], f"{what} is covered at its centre by {r['top']}"
    return r


@pytest.mark.parametrize("kind", list(SIZES))
def test_estop_start_and_numbers_in_reach_and_no_panel_overlaps(
    browser: Any, server: DemoServer, running: int, kind: str, tmp_path: Path
) -> None:
    width, height = SIZES[kind]
    page = open_dashboard(browser, server, width, height)
    try:
        assert layout.viewport_class(layout.Canvas(width, height)) == kind
        _, p = wait_moving(page)
        assert NUMBER.match(p), p
        r = in_reach(page, "button=E-STOP", "E-STOP")
        assert r["h"] >= layout.ESTOP_HEIGHT and r["w"] >= 3 * layout.ESTOP_HEIGHT, r
        for name in ("Start", "Stop"):
            r = in_reach(page, f"button={name}", name)
            assert r["h"] >= layout.TOUCH_HEIGHT, (name, r)
        for name in ("w", "p"):
            r = in_reach(page, f".ergoseek-{name}", f"live {name}")
            assert r["h"] >= 28, (name, r)  # large: about twice the body text
        panels = page.evaluate(PANELS_JS, markers(page))
        assert all(panels.values()), panels
        names = list(panels)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                assert overlap(panels[a], panels[b]) < 1.0, (kind, a, b, panels)
        dismiss_notifications(page)
        shot = tmp_path / f"dashboard-{kind}.png"
        page.screenshot(path=str(shot))
        if os.environ.get("ERGOSEEK_UPDATE_SCREENSHOT") and kind != "desktop":
            shutil.copy(shot, DEFAULT_OUT.with_name(shot.name))
    finally:
        page.close()
