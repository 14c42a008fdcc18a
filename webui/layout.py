"""Where one browser's panels go: placed per browser, so each can be laid out for its screen.

The panels of a browser's dashboard:
- the **main panel** — the shared live readout and charts (``server.gui``'s root). It is the
  one panel any scope may place, so each browser places it for itself
  (``client.gui.main_panel``);
- the **controls** panel — that browser's own tabs (Live, History, Users);
- the **seeker** panel — that browser's own seeker progress.

:func:`place` gets the browser's canvas as its first camera message reported it (device
pixels: CSS pixels × the device pixel ratio; the whole window, since nothing is docked before
this runs). Today it lays out every canvas as a desktop does; a layout per viewport class
(tablet, phone: issue 16) chooses here from the canvas's aspect ratio, which, unlike its
size, does not depend on the pixel ratio.
"""

from __future__ import annotations

from dataclasses import dataclass

import viser

MAIN_WIDTH, CONTROLS_WIDTH = 540, 440  # px: the docked panels (charts left, tabs right)
SEEKER_WIDTH, SEEKER_HEIGHT = 470, 390  # px: the seeker's window, floating bottom-left


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


def place(
    client: viser.ClientHandle,
    controls: viser.PanelHandle,
    seeker: viser.PanelHandle,
    canvas: Canvas,
) -> None:
    """Dock and float this browser's panels (the same for every canvas, for now)."""
    main = client.gui.main_panel
    main.dock_left()
    main.set_width(MAIN_WIDTH)
    controls.dock_right()
    controls.set_width(CONTROLS_WIDTH)
    seeker.float(x=12, y=-12, width=SEEKER_WIDTH, height=SEEKER_HEIGHT)
