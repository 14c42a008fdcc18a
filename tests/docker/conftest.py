"""The Docker test's parts: a dockerd of the suite's own (root), a Debian base image made with
debootstrap from the machine's apt mirror, the project's image built on it
(:mod:`testing.docker`), and a container of it running the demo. Everything is removed after
the module, failed or not; the engine's data root is kept as the cache."""

from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterator
from typing import Any

import pytest

from testing import docker as ds
from testing.processes import free_port


@pytest.fixture(scope="module")
def engine() -> Iterator[ds.Engine]:
    """Our own dockerd for this module; stopped and cleaned up after it, failed or not."""
    try:
        ds.ensure_prerequisites()
    except ds.DockerSetupError as exc:
        pytest.fail(str(exc), pytrace=False)
    root = ds.cache_dir()
    with ds.engine_lock(root):
        try:
            eng = ds.start_engine(root)
        except ds.DockerSetupError as exc:
            pytest.fail(str(exc), pytrace=False)
        try:
            yield eng
        finally:
            cleaned = ds.stop_engine(eng)
            print(f"docker timings: {json.dumps(eng.timings)}; cleaned: {cleaned}")


@pytest.fixture(scope="module")
def image(engine: ds.Engine) -> str:
    try:
        base = ds.ensure_base_image(engine)
        return ds.build_project_image(engine, base)
    except ds.DockerSetupError as exc:
        pytest.fail(str(exc), pytrace=False)


class Demo:
    def __init__(self, engine: ds.Engine, image: str, name: str, port: int, password: str) -> None:
        self.engine = engine
        self.image = image
        self.name = name
        self.volume = f"{name}-data"
        self.port = port
        self.url = f"http://127.0.0.1:{port}"
        self.ws_url = f"ws://127.0.0.1:{port}"
        self.password = password

    def run(self) -> None:
        """``docker run`` as the README says: the demo with its data on a named volume."""
        self.engine.docker(
            "run", "--detach", "--init", "--name", self.name, "--label", f"{ds.SMOKE_LABEL}=1",
            "--publish", f"127.0.0.1:{self.port}:8000",
            "--env", f"ERGOSEEK_DEMO_PASSWORD={self.password}",
            "--volume", f"{self.volume}:/data",
            self.image,
            timeout=120,
        )  # fmt: skip

    def remove(self) -> None:
        """The container gone (its named volume stays)."""
        self.engine.docker("rm", "--force", self.name, check=False, timeout=60)

    def exec(self, *argv: str) -> str:
        return self.engine.docker("exec", self.name, *argv, timeout=30).stdout.strip()

    def state(self) -> dict[str, Any]:
        out = self.engine.docker("inspect", "--format", "{{json .State}}", self.name, timeout=30)
        return json.loads(out.stdout)

    def logs(self, tail: int = 80) -> str:
        out = self.engine.docker("logs", "--tail", str(tail), self.name, check=False, timeout=30)
        return out.stdout + out.stderr


@pytest.fixture
def demo(engine: ds.Engine, image: str) -> Iterator[Demo]:
    """The image run as the README's `docker run` (a named /data volume); the container and
    its volume removed afterwards, failed or not."""
    name = f"ergoseek-smoke-{os.getpid()}"
    d = Demo(engine, image, name, free_port(), secrets.token_urlsafe(18))
    d.remove()
    engine.docker("volume", "rm", "--force", d.volume, check=False, timeout=60)
    d.run()
    try:
        yield d
    finally:
        print(f"---- container logs (last lines)\n{d.logs()}")
        d.remove()
        engine.docker("volume", "rm", "--force", d.volume, check=False, timeout=60)
