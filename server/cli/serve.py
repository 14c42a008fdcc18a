"""``ergoseek serve``: the web server with the machine's worker, the store and the dashboard."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

if TYPE_CHECKING:
    from server.gate import GateLink
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
    import functools
    import logging
    import signal

    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server, with the e-stop gate in front (it owns the listening socket and
        hands over every connection but an e-stop), and a shutdown that first brings the
        machine to zero torque and lets every live client see that (the last record, the
        session's end) before the connections are closed; the session's reason names the
        signal."""

        def __init__(self, config: uvicorn.Config, app: Any, gate: GateLink | None) -> None:
            super().__init__(config)
            self.app = app
            self.gate = gate
            self.signal_name: str | None = None
            self._ring_task: asyncio.Task[None] | None = None

        def handle_exit(self, sig: int, frame: Any) -> None:
            with contextlib.suppress(ValueError):
                self.signal_name = self.signal_name or signal.Signals(sig).name
            super().handle_exit(sig, frame)

        async def startup(self, sockets: Any = None) -> None:
            gate = self.gate
            await super().startup(sockets=[] if gate is not None else sockets)
            if gate is None or not self.started:
                return
            config = self.config
            protocol = functools.partial(
                config.http_protocol_class,
                config=config,
                server_state=self.server_state,
                app_state=self.lifespan.state,
            )
            gate.serve(asyncio.get_running_loop(), protocol)
            runtime = getattr(self.app.state, "runtime", None)
            if runtime is not None:  # the gate's copy of the logins follows every change
                runtime.accounts.subscribe(lambda change: gate.logins_changed(change.account_id))
            self._ring_task = asyncio.create_task(self._follow_ring(gate))
            host, port = gate.listener.getsockname()[:2]
            logging.getLogger("uvicorn.error").info(
                "Uvicorn running on http://%s:%d (e-stops through the gate)", host, port
            )

        async def _follow_ring(self, gate: GateLink) -> None:
            """Tell the gate the worker's ring whenever the worker changes."""
            while True:
                runtime = getattr(self.app.state, "runtime", None)
                name = None
                worker = runtime.machine.worker if runtime is not None else None
                if worker is not None:
                    with contextlib.suppress(Exception):
                        name = worker.ring_info.name
                gate.ring(name)
                await asyncio.sleep(RING_FOLLOW_S)

        async def shutdown(self, sockets: Any = None) -> None:
            runtime = getattr(self.app.state, "runtime", None)
            if runtime is not None:
                why = f" ({self.signal_name})" if self.signal_name else ""
                try:
                    await runtime.machine.halt(f"server shut down{why}")
                    await runtime.hub.flush(LIVE_FLUSH_S)
                except Exception:  # the rest of the shutdown must still happen
                    logging.getLogger("ergoseek.server").exception("halting the machine")
            if self._ring_task is not None:
                self._ring_task.cancel()
            if self.gate is not None:
                await asyncio.to_thread(self.gate.close)
            await super().shutdown(sockets)

    return Server


LIVE_FLUSH_S = 1.0  # s the live clients get to receive the end of a session at shutdown
RING_FOLLOW_S = 0.05  # s between looks at which ring the worker writes


def _gate(settings: Settings) -> GateLink | None:
    """The e-stop gate on a socket bound now (None: configured off)."""
    import socket

    from server.gate import GateConfig, GateLink
    from sessions.store.database import database_url

    if not settings.estop_gate:
        return None
    family = socket.AF_INET6 if ":" in settings.host else socket.AF_INET
    listener = socket.create_server((settings.host, settings.port), family=family, backlog=2048)
    cfg = GateConfig(
        database_url=database_url(settings.store_url()),
        host_names=tuple(settings.host_names()),
        allowed_origins=tuple(settings.allowed_origins),
        nice=settings.estop_gate_nice,
    )
    return GateLink(listener, cfg)


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
    try:
        gate = _gate(settings)
    except OSError as exc:
        logging.getLogger("ergoseek.server").error(
            "cannot listen on %s:%s: %s", settings.host, settings.port, exc
        )
        return 1
    server = _server_class()(config, app, gate)
    try:
        server.run()
    finally:
        if gate is not None and gate.proc.is_alive():
            gate.close()
    return 0 if server.started else 1


def run(args: argparse.Namespace) -> int:
    return serve(settings_from(args))
