"""Server settings: ``ERGOSEEK_*`` environment variables, an optional TOML file, CLI flags.

Precedence, highest first: command-line flags (passed as init arguments), environment
variables, the config file named by ``--config`` or ``ERGOSEEK_CONFIG``, the defaults.
There are no default passwords anywhere: accounts are created with ``ergoseek account create``
(or by ``ergoseek demo``, which prints or takes ``ERGOSEEK_DEMO_PASSWORD``).

One Settings, one definition per setting: the machine's keys (``inertia``, ``max_torque``,
``max_velocity``, ``rate``) are the engine's fields (:class:`sessions.config.MachineConfig`,
:class:`sessions.config.SessionConfig`), the drive's (``gear_ratio``, ``direction``,
``torque_constant``, ``reply_timeout``, ``watchdog_timeout``, ``baudrate``,
``vel_limit_tolerance``, ``firmware_policy``) and the simulator's ``sim_fault`` are
:class:`sessions.machine.MachineSpec`'s, taken with
their defaults, bounds and descriptions (the server adds only its own caps). The worker's
options are nested as they are (``worker.cpu``, ``ERGOSEEK_WORKER__CPU``). What the service
runs on is built from them: :meth:`Settings.rig`, :meth:`Settings.machine_spec`.
"""

from __future__ import annotations

import copy
import os
import socket
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, Field, field_validator, model_validator
from pydantic.fields import FieldInfo
from pydantic_settings import BaseSettings, PydanticBaseSettingsSource, SettingsConfigDict

from sessions.config import MachineConfig, SessionConfig
from sessions.machine.odrive.emulator.device import EmulatorConfig
from sessions.machine.spec import Direction, FirmwarePolicy, MachineSpec, SimFault
from sessions.requests import Rig
from sessions.store.database import SQLITE_FILENAME
from sessions.store.hashing import HashCost
from sessions.worker.options import LIVE_RATE_MAX, WorkerOptions

MachineKind = Literal["sim", "odrive", "odrive-emulator"]
SERVER_MAX_TORQUE = 200.0  # N·m: the most any machine this server drives may be set to
SERVER_MAX_VELOCITY = 100.0  # rad/s
# c² of (5): the engine's default is the most energy a server lets its machine put into a
# person before it stops; an operator may only lower it (stricter)
SERVER_MAX_PASSIVITY_C2 = MachineConfig.model_fields["passivity_c2"].default


def owned(model: type[BaseModel], name: str, **caps: float) -> Any:
    """The field ``name`` as ``model`` defines it (default, bounds, description), with the
    server's extra ``caps``: a setting defined once, where it belongs."""
    info = model.model_fields[name]
    return FieldInfo.merge_field_infos(info, Field(**caps)) if caps else copy.copy(info)


class TomlFileSource(PydanticBaseSettingsSource):
    """Values from the TOML file named by ``ERGOSEEK_CONFIG`` (or the ``config`` init value)."""

    def __init__(self, settings_cls: type[BaseSettings], path: str | None) -> None:
        super().__init__(settings_cls)
        self.data: dict[str, Any] = {}
        if path:
            p = Path(path)
            try:
                self.data = tomllib.loads(p.read_text(encoding="utf-8"))
            except FileNotFoundError:
                raise ValueError(f"config file {p}: no such file") from None
            except tomllib.TOMLDecodeError as exc:
                raise ValueError(f"config file {p}: not valid TOML ({exc})") from None

    def get_field_value(self, field: Any, field_name: str) -> tuple[Any, str, bool]:
        return self.data.get(field_name), field_name, False

    def __call__(self) -> dict[str, Any]:
        return dict(self.data)


class Settings(BaseSettings):
    model_config = SettingsConfigDict(
        env_prefix="ERGOSEEK_", env_nested_delimiter="__", extra="forbid", frozen=True
    )

    config: str | None = Field(None, description="TOML file with any of these settings")
    host: str = Field("127.0.0.1", description="address the web server binds")
    port: int = Field(8000, ge=0, le=65535, description="web port (0: any free port)")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; default: SQLite in the data directory"
    )
    data_dir: str | None = Field(None, description="where the default SQLite file lives")
    # the machine
    machine: MachineKind = Field("sim", description="the worker's machine backend")
    device: str | None = Field(None, description="serial device for --machine odrive")
    rate: float = owned(SessionConfig, "rate", le=LIVE_RATE_MAX)
    max_torque: float = owned(MachineConfig, "max_torque", le=SERVER_MAX_TORQUE)
    max_velocity: float = owned(MachineConfig, "max_velocity", le=SERVER_MAX_VELOCITY)
    inertia: float = owned(MachineConfig, "inertia")
    passivity_c2: float = owned(MachineConfig, "passivity_c2", le=SERVER_MAX_PASSIVITY_C2)
    gear_ratio: float = owned(MachineSpec, "gear_ratio")
    direction: Direction = owned(MachineSpec, "direction")
    reply_timeout: float = owned(MachineSpec, "reply_timeout")
    watchdog_timeout: float = owned(MachineSpec, "watchdog_timeout")
    torque_constant: float | None = owned(MachineSpec, "torque_constant")
    baudrate: int = owned(MachineSpec, "baudrate")
    vel_limit_tolerance: float = owned(MachineSpec, "vel_limit_tolerance")
    firmware_policy: FirmwarePolicy = owned(MachineSpec, "firmware_policy")
    sim_fault: SimFault | None = owned(MachineSpec, "sim_fault")
    worker: WorkerOptions = Field(default_factory=WorkerOptions, description="the worker")
    # logins
    session_hours: float = Field(12.0, gt=0, le=24 * 30, description="login lifetime, h")
    cookie_secure: bool = Field(False, description="mark the login cookie Secure (behind TLS)")
    allowed_origins: list[str] = Field(
        default_factory=list, description="extra Origins allowed besides the server's own"
    )
    password_hash: HashCost = Field(
        default_factory=HashCost, description="argon2id's cost for new password hashes"
    )
    login_attempts: int = Field(5, ge=1, description="failed logins allowed per window")
    login_window_s: float = Field(300.0, gt=0, description="failed-login window, s")
    # what a client may send, and whom the server believes
    allowed_hosts: list[str] = Field(
        default_factory=list,
        description="Host names the server answers to besides its loopback names and bind "
        "address ('*': any; '*.example.org': a domain's subdomains)",
    )
    max_body_bytes: int = Field(
        128 * 1024,
        ge=4096,
        le=64 * 1024 * 1024,
        description="largest request body accepted (413 above it, before it is read)",
    )
    proxy_headers: bool = Field(
        False, description="believe X-Forwarded-For/-Proto from forwarded_allow_ips"
    )
    forwarded_allow_ips: list[str] = Field(
        default_factory=list,
        description="addresses of the reverse proxies trusted with forwarded headers",
    )
    estop_gate: bool = Field(
        True,
        description="answer POST /api/v1/machine/estop in a process of its own that owns the "
        "listening socket, ahead of the web server (server/gate.py)",
    )
    estop_gate_nice: int = Field(
        -10, ge=-20, le=19, description="the e-stop gate's scheduling niceness (if allowed)"
    )
    live_max_per_account: int = Field(
        8, ge=1, le=1000, description="open /api/v1/live connections one account may hold"
    )
    live_max_total: int = Field(
        64, ge=1, le=10_000, description="open /api/v1/live connections in all"
    )
    # what is served
    dashboard: bool = Field(True, description="serve the login page and the viser dashboard")
    demo: bool = Field(False, description="demo mode: simulated users seeded")

    def host_names(self) -> list[str]:
        """Every Host the server answers to: its loopback names, its bind address (a
        wildcard bind adds this machine's name), and ``allowed_hosts``."""
        names = ["127.0.0.1", "localhost", "::1", "[::1]"]
        if self.host in ("0.0.0.0", "::", ""):
            names += [socket.gethostname(), socket.getfqdn()]
        else:
            names += [self.host, f"[{self.host}]" if ":" in self.host else self.host]
        return list(dict.fromkeys([*names, *self.allowed_hosts]))

    def store_url(self) -> str | None:
        """The database: ``database_url``, else SQLite in ``data_dir``, else the store's
        default (``$ERGOSEEK_DATABASE_URL`` or the XDG data directory)."""
        if self.database_url:
            return self.database_url
        if self.data_dir:
            return f"sqlite:///{Path(self.data_dir).expanduser().resolve() / SQLITE_FILENAME}"
        return None

    def machine_config(self) -> MachineConfig:
        """The machine every session gets (a request may lower its limits)."""
        return MachineConfig(
            inertia=self.inertia, max_torque=self.max_torque, max_velocity=self.max_velocity,
            passivity_c2=self.passivity_c2,
        )  # fmt: skip

    def machine_spec(self, device: str | None = None) -> MachineSpec:
        """What the worker drives: the simulator, or an ODrive at ``device`` (default: the
        configured one; the emulator's pty for ``odrive-emulator``)."""
        if self.machine == "sim":
            return MachineSpec(kind="sim", sim_fault=self.sim_fault)
        torque_constant = self.torque_constant
        if torque_constant is None and self.machine == "odrive-emulator":
            torque_constant = EmulatorConfig.torque_constant  # the emulated motor's
        return MachineSpec(
            kind="odrive",
            device=device or self.device,
            gear_ratio=self.gear_ratio,
            direction=self.direction,
            torque_constant=torque_constant,
            reply_timeout=self.reply_timeout,
            watchdog_timeout=self.watchdog_timeout,
            baudrate=self.baudrate,
            vel_limit_tolerance=self.vel_limit_tolerance,
            firmware_policy=self.firmware_policy,
        )

    def rig(self, spec: MachineSpec) -> Rig:
        """The machine ``spec`` drives, as the request policy sees it (:mod:`sessions.requests`)."""
        return Rig(self.machine, self.machine_config(), self.rate, spec.has_torque_sensor)

    @model_validator(mode="after")
    def _proxy(self) -> Settings:
        if self.proxy_headers and not self.forwarded_allow_ips:
            raise ValueError("proxy_headers needs forwarded_allow_ips (the proxies' addresses)")
        return self

    @model_validator(mode="after")
    def _drive(self) -> Settings:
        if self.machine == "odrive" and not self.device:
            return self  # the command line asks for --device first
        if self.machine != "sim":  # the drive's settings must make a spec (checked now, not later)
            self.machine_spec(self.device or "(the emulator's pty)")
        elif self.sim_fault is not None:
            self.machine_spec()
        return self

    @field_validator("device")
    @classmethod
    def _device_exists(cls, v: str | None) -> str | None:
        if v is not None and not v:
            raise ValueError("must not be empty")
        return v

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        path = init_settings().get("config") or os.environ.get("ERGOSEEK_CONFIG")
        return (init_settings, env_settings, TomlFileSource(settings_cls, path))
