"""``ergoseek serve``: the web server with the machine's worker, the store and the dashboard."""

from __future__ import annotations

import argparse
import contextlib
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

if TYPE_CHECKING:
    from server.settings import Settings


def add_server_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="TOML file of settings (see docs/server.md)")
    p.add_argument("--host", help="bind address (default 127.0.0.1)")
    p.add_argument("--port", type=int, help="port (default 8000)")
    p.add_argument("--database-url", dest="database_url", help="SQLAlchemy URL (default SQLite)")
    p.add_argument("--data-dir", dest="data_dir", help="folder of the default SQLite file")
    p.add_argument("--no-dashboard", dest="dashboard", action="store_const", const=False)


def register(sub: Any) -> None:
    p = sub.add_parser(
        "serve",
        help="run the web server (REST API, live WebSocket, dashboard) and the machine",
        description="Serve ergoseek: settings from flags, ERGOSEEK_* variables, --config.",
    )
    add_server_flags(p)
    p.add_argument("--machine", choices=("sim", "odrive", "odrive-emulator"))
    p.add_argument("--device", help="serial device of the ODrive (--machine odrive)")
    p.set_defaults(run=run)


def settings_from(args: argparse.Namespace, **extra: Any) -> Settings:
    from server.cli import UsageError
    from server.settings import Settings

    given = {k: v for k, v in vars(args).items() if k in Settings.model_fields and v is not None}
    try:
        settings = Settings(**given, **extra)
    except ValidationError as exc:
        from sessions.config import describe_validation_error

        raise UsageError(describe_validation_error(exc)) from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if settings.machine == "odrive" and not settings.device:
        raise UsageError("--machine odrive needs --device PATH")
    return settings


def _server_class() -> type:
    import logging
    import signal

    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server, whose shutdown first brings the machine to zero torque and lets
        every live client see that (the last record, the session's end) before the
        connections are closed; the session's reason names the signal."""

        def __init__(self, config: uvicorn.Config, app: Any) -> None:
            super().__init__(config)
            self.app = app
            self.signal_name: str | None = None

        def handle_exit(self, sig: int, frame: Any) -> None:
            with contextlib.suppress(ValueError):
                self.signal_name = self.signal_name or signal.Signals(sig).name
            super().handle_exit(sig, frame)

        async def shutdown(self, sockets: Any = None) -> None:
            runtime = getattr(self.app.state, "runtime", None)
            if runtime is not None:
                why = f" ({self.signal_name})" if self.signal_name else ""
                try:
                    await runtime.machine.halt(f"server shut down{why}")
                    await runtime.hub.flush(LIVE_FLUSH_S)
                except Exception:  # the rest of the shutdown must still happen
                    logging.getLogger("ergoseek.server").exception("halting the machine")
            await super().shutdown(sockets)

    return Server


LIVE_FLUSH_S = 1.0  # s the live clients get to receive the end of a session at shutdown


def serve(settings: Settings) -> int:
    import logging

    import uvicorn

    from server.app import create_app

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    app = create_app(settings)
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        ws_per_message_deflate=False,
        lifespan="on",
        log_level="info",
        timeout_graceful_shutdown=5,
        # the client's address is the socket's unless a proxy is configured and trusted
        proxy_headers=settings.proxy_headers,
        forwarded_allow_ips=list(settings.forwarded_allow_ips),
        server_header=False,
    )
    server = _server_class()(config, app)
    server.run()
    return 0 if server.started else 1


def run(args: argparse.Namespace) -> int:
    return serve(settings_from(args))
