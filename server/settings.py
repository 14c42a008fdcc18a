"""Server settings: ``ERGOSEEK_*`` environment variables, an optional TOML file, CLI flags.

Precedence, highest first: command-line flags (passed as init arguments), environment
variables, the config file named by ``--config`` or ``ERGOSEEK_CONFIG``, the defaults below.
There are no default passwords anywhere: accounts are created with ``ergoseek account create``
(or by ``ergoseek demo``, which prints or takes ``ERGOSEEK_DEMO_PASSWORD``).
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, PydanticBaseSettingsSource, SettingsConfigDict

from sessions.store.database import SQLITE_FILENAME

MachineKind = Literal["sim", "odrive", "odrive-emulator"]


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
    model_config = SettingsConfigDict(env_prefix="ERGOSEEK_", extra="forbid", frozen=True)

    config: str | None = Field(None, description="TOML file with any of these settings")
    host: str = Field("127.0.0.1", description="address the web server binds")
    port: int = Field(8000, ge=0, le=65535, description="web port (0: any free port)")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; default: SQLite in the data directory"
    )
    data_dir: str | None = Field(None, description="where the default SQLite file lives")
    machine: MachineKind = Field("sim", description="the worker's machine backend")
    device: str | None = Field(None, description="serial device for --machine odrive")
    rate: float = Field(1000.0, ge=50.0, le=5000.0, description="control loop rate, Hz")
    max_torque: float = Field(20.0, gt=0, le=200.0, description="machine torque limit, N·m")
    max_velocity: float = Field(15.0, gt=0, le=100.0, description="machine velocity limit, rad/s")
    inertia: float = Field(0.1, gt=0, description="machine inertia J, kg·m²")
    gear_ratio: float = Field(1.0, gt=0, description="ODrive: motor turns per handle turn")
    direction: Literal[1, -1] = Field(1, description="ODrive: +1 or -1")
    reply_timeout: float = Field(
        0.02, gt=0, le=1.0, description="ODrive: longest wait for a reply before a fault, s"
    )
    watchdog_timeout: float = Field(
        0.05, gt=0, le=1.0, description="ODrive: the device's own watchdog, s (fed every cycle)"
    )
    session_hours: float = Field(12.0, gt=0, le=24 * 30, description="login lifetime, h")
    cookie_secure: bool = Field(False, description="mark the login cookie Secure (behind TLS)")
    allowed_origins: list[str] = Field(
        default_factory=list, description="extra Origins allowed besides the server's own"
    )
    login_attempts: int = Field(5, ge=1, description="failed logins allowed per window")
    login_window_s: float = Field(300.0, gt=0, description="failed-login window, s")
    dashboard: bool = Field(True, description="serve the login page and the viser dashboard")
    demo: bool = Field(False, description="demo mode: simulated users seeded")

    def store_url(self) -> str | None:
        """The database: ``database_url``, else SQLite in ``data_dir``, else the store's
        default (``$ERGOSEEK_DATABASE_URL`` or the XDG data directory)."""
        if self.database_url:
            return self.database_url
        if self.data_dir:
            return f"sqlite:///{Path(self.data_dir).expanduser().resolve() / SQLITE_FILENAME}"
        return None

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
