"""Which machine the worker drives and how: plain validated data, pickled to the worker process.

``sim`` needs nothing: the plant and the simulated user come from each session's config.
``odrive`` needs the serial device and the rig's mechanics (gear ratio, direction) and the
safety settings of the drive (watchdog, reply timeout, velocity margin). Every setting of the
drive is defined here once; the server's settings and the command line take them from here.

Which controller a machine can run is decided here too (:func:`check_controller`).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Direction = Literal[1, -1]  # +1 if the motor's positive direction is the handle's


class MachineSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    kind: Literal["sim", "odrive"] = "sim"
    device: str | None = Field(None, description="odrive: serial device path, e.g. /dev/ttyACM0")
    baudrate: int = Field(921600, gt=0, description="odrive: UART baud rate (ignored by USB CDC)")
    axis: int = Field(0, ge=0, le=1, description="odrive: axis the handle is on")
    gear_ratio: float = Field(1.0, gt=0, le=1000, description="odrive: motor turns per handle turn")
    direction: Direction = Field(
        1, description="odrive: +1 if the motor's positive direction is the handle's, else -1"
    )
    watchdog_timeout: float = Field(
        0.05, gt=0, le=1.0, description="odrive: device watchdog, s (fed every cycle)"
    )
    reply_timeout: float = Field(
        0.02, gt=0, le=1.0, description="odrive: longest wait for a reply before a fault, s"
    )
    checksum: bool = Field(True, description="odrive: send and require line checksums")
    velocity_margin: float = Field(
        1.2, gt=1.0, le=3.0, description="odrive: device vel_limit = margin × machine.max_velocity"
    )
    health_period: float = Field(
        0.02, gt=0, le=1.0, description="odrive: how often axis0.error is read while active, s"
    )
    closed_loop_timeout: float = Field(
        2.0, gt=0, le=30.0, description="odrive: longest wait for closed-loop control, s"
    )

    @model_validator(mode="after")
    def _device(self) -> MachineSpec:
        if self.kind == "odrive" and not self.device:
            raise ValueError("the odrive machine needs a device path")
        if self.watchdog_timeout <= self.reply_timeout:
            raise ValueError("watchdog_timeout must exceed the reply timeout")
        return self

    @property
    def has_torque_sensor(self) -> bool:
        """Controller A (measured torque) needs one: the simulator has it, an ODrive has not."""
        return self.kind == "sim"


def check_controller(machine: str, has_torque_sensor: bool, controller: str) -> None:
    """Refuse a controller the machine cannot run: controller A (7) feeds back the measured
    user torque, so it needs a torque sensor. Raises ValueError (one wording everywhere)."""
    if controller == "measured" and not has_torque_sensor:
        raise ValueError(
            f"the {machine} machine has no torque sensor: controller 'measured' (eq. 7) needs "
            "one; use 'rise' (eq. 23)"
        )
