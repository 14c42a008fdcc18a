"""Where one browser's panels go, per viewport class (issue 16): every layout decision of the
dashboard is here — the classes, each panel's slot in each class, the order of what sits at
the top of the main panel, and the touch-size stylesheet.

The panels of a browser's dashboard:
- the **main panel** (``"main"``) — at its top, always in reach, the trainer's E-STOP, the
  large live numbers (velocity, power) and Start / Stop / Reset; below them the shared live
  charts. It is the one panel any scope may place, so each browser places it for itself
  (``client.gui.main_panel``);
- the **controls** panel (``"controls"``) — that browser's own tabs (Live, History, Users);
- the **seeker** panel (``"seeker"``) — that browser's own seeker progress.

A new panel (issue 15's protocol editor, phase progress, rpm…) gets a name, an ``order`` in
:data:`PANEL_ORDER` (its place among the sections of the phone sheet) and a :class:`Slot` in
every layout of :data:`LAYOUTS`; :func:`place` then docks it with the others. Docked panels
never overlap (viser shares a column between panels docked below one another and shrinks
docked widths that do not fit, keeping their ratio); a floating one is used only where the
canvas it floats over is wide enough (desktop).

:func:`viewport_class` chooses from the browser's canvas as its first camera message reported
it (the whole window: nothing is docked before :func:`place` runs) by its aspect ratio,
which, unlike its size in device pixels, does not depend on the pixel ratio. Below 36 em
(576 CSS px) of width viser's client shows no docks at all but one sheet at the bottom right:
the main panel's content first (so the E-STOP and the numbers are on screen without
scrolling), then each panel as a section in :data:`PANEL_ORDER`; the docks sent stay stored
and apply when the window widens. The layout is chosen when the page connects; a tablet
turned later keeps it (docked widths re-fit; a reload chooses again).
"""

from __future__ import annotations

from dataclasses import dataclass

import viser

# Order of the elements at the top of the main panel (viser sorts a container's children by
# ``order``, across the shared GUI and a browser's own): a browser's E-STOP first, the shared
# large numbers, that browser's Start / Stop / Reset and their message, then the stylesheet
# and the shared tabs (live charts), which keep viser's default (positive) orders.
ORDER_ESTOP = -50.0
ORDER_NUMBERS = -40.0
ORDER_ACTIONS = -30.0  # Start, Stop, Reset, message: ORDER_ACTIONS + 0, 1, 2, 3
ORDER_STYLE = -10.0
PANEL_ORDER = {"controls": 10.0, "seeker": 20.0}  # sections of the phone sheet, top down

DESKTOP, TABLET_LANDSCAPE, TABLET_PORTRAIT, PHONE = (
    "desktop",
    "tablet-landscape",
    "tablet-portrait",
    "phone",
)
WIDE, SQUARE, NARROW = 1.45, 1.0, 0.65  # aspect ratios (width / height) between the classes


@dataclass(frozen=True)
class Slot:
    """Where a panel goes: docked to an ``edge`` ("left" / "right", ``width`` CSS px), in the
    column of the panel named ``below`` (under it), or floating at (``x``, ``y``) with
    ``width`` × ``height`` (CSS px; negative x / y: from the right / bottom of the canvas)."""

    edge: str | None = None
    below: str | None = None
    x: float | None = None
    y: float | None = None
    width: float | None = None
    height: float | None = None


# In each layout, the panels in the order they are placed (an anchor before what goes below
# it; several docks on one edge go from the edge inward in this order).
LAYOUTS: dict[str, dict[str, Slot]] = {
    # 1500 × 950 and wider: charts left, tabs right, the seeker floating over the 3D view.
    DESKTOP: {
        "main": Slot(edge="left", width=540),
        "controls": Slot(edge="right", width=440),
        "seeker": Slot(x=12, y=-12, width=470, height=390),
    },
    # 1024 × 768: narrower columns so the 3D view keeps a third; the seeker under the tabs.
    TABLET_LANDSCAPE: {
        "main": Slot(edge="left", width=400),
        "controls": Slot(edge="right", width=360),
        "seeker": Slot(below="controls"),
    },
    # 768 × 1024: two equal columns (the 3D view is what is left), the seeker under the tabs.
    TABLET_PORTRAIT: {
        "main": Slot(edge="left", width=380),
        "controls": Slot(edge="right", width=380),
        "seeker": Slot(below="controls"),
    },
    # 390 × 844: viser's sheet (see the module's text); these docks apply if it widens.
    PHONE: {
        "main": Slot(edge="left", width=380),
        "controls": Slot(edge="right", width=380),
        "seeker": Slot(below="controls"),
    },
}

# Finger-sized targets (WCAG 2.5.5: 44 × 44 CSS px), a large E-STOP, and the large numbers.
# A literal stylesheet — no data in it — allowed by the page's ``style-src 'unsafe-inline'``.
# (A template for webui.escape.html: braces doubled.)
ESTOP_HEIGHT, TOUCH_HEIGHT = 64, 44  # CSS px
TOUCH_CSS = (
    "<style>"
    ".mantine-Button-root{{min-height:" + str(TOUCH_HEIGHT) + "px}}"
    ".mantine-Button-root:has(.icon-tabler-hand-stop){{min-height:" + str(ESTOP_HEIGHT) + "px;"
    "font-size:1.35em;font-weight:700;letter-spacing:0.06em}}"
    ".mantine-Tabs-tab{{min-height:" + str(TOUCH_HEIGHT) + "px}}"
    ".ergoseek-numbers{{display:flex;gap:0.75em;padding:2px 0.75em}}"
    ".ergoseek-numbers>div{{flex:1 1 0;min-width:0}}"
    ".ergoseek-numbers .v{{font-size:2.1em;font-weight:700;line-height:1.1;"
    "font-variant-numeric:tabular-nums;white-space:nowrap}}"
    ".ergoseek-numbers .k{{font-size:0.8em;opacity:0.7}}"
    "</style>"
)


@dataclass(frozen=True)
class Canvas:
    """A browser's canvas at connect time, device pixels."""

    width: int
    height: int

    @property
    def aspect(self) -> float:
        return self.width / max(self.height, 1)


def canvas_of(client: viser.ClientHandle) -> Canvas:
    camera = client.camera
    return Canvas(int(camera.image_width), int(camera.image_height))


def viewport_class(canvas: Canvas) -> str:
    """desktop (≥ 1.45: 1500 × 950, 1920 × 1080, 1440 × 900), tablet landscape (≥ 1: 1024 ×
    768, 1366 × 1024), tablet portrait (≥ 0.65: 768 × 1024, 834 × 1194), else phone."""
    if canvas.width <= 0 or canvas.height <= 0:
        return DESKTOP  # no size reported (a raw client): the layout everyone had
    a = canvas.aspect
    return (
        DESKTOP
        if a >= WIDE
        else TABLET_LANDSCAPE
        if a >= SQUARE
        else (TABLET_PORTRAIT if a >= NARROW else PHONE)
    )


def place(client: viser.ClientHandle, panels: dict[str, viser.PanelHandle], canvas: Canvas) -> str:
    """Dock and float this browser's panels for its viewport class; returns the class."""
    kind = viewport_class(canvas)
    handles: dict[str, viser.PanelHandle | viser.MainPanelHandle] = {
        "main": client.gui.main_panel,
        **panels,
    }
    for name, slot in LAYOUTS[kind].items():
        if name not in handles:
            continue
        panel = handles[name]
        if slot.edge == "left":
            panel.dock_left()
        elif slot.edge == "right":
            panel.dock_right()
        elif slot.below is not None:
            panel.dock_below(handles[slot.below])  # type: ignore[arg-type]
        else:
            panel.float(x=slot.x, y=slot.y, width=slot.width, height=slot.height)
            continue
        if slot.width is not None:
            panel.set_width(slot.width)
    return kind
