"""Which machine the worker drives and how: plain validated data, pickled to the worker process.

``sim`` needs nothing: the plant and the simulated user come from each session's config (a
:class:`SimFault` may be injected for fire drills and tests of the fault paths). ``odrive``
needs the serial device, the rig's mechanics (gear ratio, direction), the motor's torque
constant (checked against the drive's at arm) and the safety settings of the drive (watchdog,
reply timeout, velocity margin, overspeed tolerance). Every setting of the drive is defined
here once; the server's settings and the command line take them from here.

Which controller a machine can run is decided here too (:func:`check_controller`).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

Direction = Literal[1, -1]  # +1 if the motor's positive direction is the handle's
FirmwarePolicy = Literal["supported", "probe"]
SimFaultKind = Literal[
    "nan-angle", "nan-velocity", "nan-torque", "huge-torque", "worker-abort", "worker-exit"
]
UART_BAUDRATE = 115_200  # an ODrive v3.x UART's factory rate (USB CDC ignores the rate)


class SimFault(BaseModel):
    """A fault the simulator injects into every session from session time ``at`` on: what a
    broken sensor, an absurd person or a crashing worker does, through the real data path.

    - ``nan-angle`` / ``nan-velocity`` / ``nan-torque``: the measurement reads NaN;
    - ``huge-torque``: the torque sensor reads 1e308 N·m (finite, but every product the loop
      forms with it overflows: power, work);
    - ``worker-abort``: the worker process dies on the spot (SIGABRT, no goodbye);
    - ``worker-exit``: the worker process exits as an unhandled bug would (its last words sent).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    kind: SimFaultKind
    at: float = Field(1.0, ge=0, le=86_400, description="session time the fault starts, s")


class MachineSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    kind: Literal["sim", "odrive"] = "sim"
    device: str | None = Field(None, description="odrive: serial device path, e.g. /dev/ttyACM0")
    baudrate: int = Field(
        UART_BAUDRATE,
        gt=0,
        description="odrive: UART baud rate (the UART's default 115200; USB CDC ignores it)",
    )
    axis: int = Field(0, ge=0, le=1, description="odrive: axis the handle is on")
    gear_ratio: float = Field(1.0, gt=0, le=1000, description="odrive: motor turns per handle turn")
    direction: Direction = Field(
        1, description="odrive: +1 if the motor's positive direction is the handle's, else -1"
    )
    torque_constant: float | None = Field(
        None,
        gt=0,
        le=10.0,
        validate_default=True,
        description="odrive: the motor's torque constant, N·m/A (8.27/Kv); the drive's "
        "motor.config.torque_constant must match it at arm",
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
    vel_limit_tolerance: float = Field(
        1.2,
        ge=1.0,
        le=1.5,
        description="odrive: the device's overspeed error trips at tolerance × vel_limit",
    )
    firmware_policy: FirmwarePolicy = Field(
        "supported",
        description="odrive: 'supported' accepts firmware 0.5.1 and 0.5.4-0.5.6; 'probe' also "
        "a 0.5.2/0.5.3 build whose enum writes work (the released binaries' do not)",
    )
    health_period: float = Field(
        0.02, gt=0, le=1.0, description="odrive: how often axis0.error is read while active, s"
    )
    closed_loop_timeout: float = Field(
        2.0, gt=0, le=30.0, description="odrive: longest wait for closed-loop control, s"
    )
    sim_fault: SimFault | None = Field(
        None, description="sim: a fault injected into every session (fire drills, tests)"
    )

    @field_validator("torque_constant")
    @classmethod
    def _torque_constant(cls, v: float | None, info: ValidationInfo) -> float | None:
        if v is None and info.data.get("kind") == "odrive" and info.data.get("device"):
            raise ValueError(
                "the odrive machine needs its motor's torque constant, N·m/A (8.27/Kv of the "
                "motor), checked against the drive's at arm"
            )
        return v

    @model_validator(mode="after")
    def _device(self) -> MachineSpec:
        if self.kind == "odrive" and not self.device:
            raise ValueError("the odrive machine needs a device path")
        if self.watchdog_timeout <= self.reply_timeout:
            raise ValueError("watchdog_timeout must exceed the reply timeout")
        if self.sim_fault is not None and self.kind != "sim":
            raise ValueError("sim_fault is the simulator's: the odrive machine takes none")
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
