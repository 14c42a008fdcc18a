"""The machine in 3D: a base and column, the shaft, a crank with its handle turning with the
measured angle q, and two torque bars (motor torque written, user torque) whose height follows
the torque and whose colour says its sign."""

from __future__ import annotations

import math

import numpy as np
import viser

SHAFT_Z = 0.62  # m, height of the shaft axis
CRANK = 0.22  # m, crank radius
BAR_HEIGHT = 0.5  # m, a torque bar at full scale
FULL_SCALE = 5.0  # N·m shown as a full bar (or the machine's limit if lower); larger: clipped
MOTOR_POS, MOTOR_NEG = (230, 120, 30), (40, 110, 220)
USER_COLOR = (40, 160, 80)


def about_y(angle: float) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of a rotation by ``angle`` about +y (the shaft)."""
    return (math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)


class MachineScene:
    def __init__(self, scene: viser.SceneApi, max_torque: float) -> None:
        self.full_scale = min(max_torque, FULL_SCALE)
        scene.add_grid("/floor", width=2.0, height=2.0, cell_size=0.1, plane="xy")
        scene.add_box(
            "/machine/base",
            color=(90, 90, 100),
            dimensions=(0.6, 0.4, 0.06),
            position=(0.0, 0.0, 0.03),
        )
        scene.add_box(
            "/machine/column",
            color=(120, 120, 130),
            dimensions=(0.1, 0.1, SHAFT_Z),
            position=(0.0, 0.05, SHAFT_Z / 2),
        )
        scene.add_box(
            "/machine/motor",
            color=(60, 60, 70),
            dimensions=(0.16, 0.12, 0.16),
            position=(0.0, 0.13, SHAFT_Z),
        )
        # The shaft (a cylinder is built along z: turn it onto y).
        turn_to_y = (math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0)
        scene.add_cylinder(
            "/machine/shaft",
            radius=0.02,
            height=0.3,
            color=(180, 180, 190),
            wxyz=turn_to_y,
            position=(0.0, -0.05, SHAFT_Z),
        )
        self.rotor = scene.add_frame(
            "/machine/rotor", show_axes=False, position=(0.0, -0.2, SHAFT_Z)
        )
        scene.add_box(
            "/machine/rotor/crank",
            color=(200, 200, 210),
            dimensions=(CRANK + 0.04, 0.03, 0.04),
            position=(CRANK / 2, 0.0, 0.0),
        )
        scene.add_cylinder(
            "/machine/rotor/handle",
            radius=0.025,
            height=0.14,
            color=(220, 60, 50),
            wxyz=turn_to_y,
            position=(CRANK, -0.08, 0.0),
        )
        self.motor_bar = scene.add_box(
            "/indicators/motor",
            color=MOTOR_POS,
            dimensions=(0.05, 0.05, 1.0),
            position=(0.45, 0.0, 0.0),
            scale=(1.0, 1.0, 1e-3),
        )
        self.user_bar = scene.add_box(
            "/indicators/user",
            color=USER_COLOR,
            dimensions=(0.05, 0.05, 1.0),
            position=(0.53, 0.0, 0.0),
            scale=(1.0, 1.0, 1e-3),
        )
        scene.add_label("/indicators/motor_label", "motor u", position=(0.45, 0.0, -0.03))
        scene.add_label("/indicators/user_label", "user τ", position=(0.53, 0.0, -0.03))
        self._last: tuple[float, float, float] | None = None

    def show(self, q: float, u: float, tau: float) -> None:
        """Turn the handle to q, size the torque bars; a NaN leaves a part as it was."""
        last = self._last or (0.0, 0.0, 0.0)
        q = q if math.isfinite(q) else last[0]
        u = u if math.isfinite(u) else last[1]
        tau = tau if math.isfinite(tau) else last[2]
        if self._last == (q, u, tau):
            return
        self._last = (q, u, tau)
        self.rotor.wxyz = np.array(about_y(q))
        self._bar(self.motor_bar, u, MOTOR_POS if u >= 0 else MOTOR_NEG)
        self._bar(self.user_bar, tau, USER_COLOR)

    def _bar(self, bar: viser.BoxHandle, torque: float, color: tuple[int, int, int]) -> None:
        h = max(min(abs(torque) / self.full_scale, 1.0), 0.0) * BAR_HEIGHT
        bar.scale = (1.0, 1.0, max(h, 1e-3))
        bar.position = (bar.position[0], 0.0, h / 2)
        if tuple(bar.color) != color:
            bar.color = color
