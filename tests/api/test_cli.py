"""`ergoseek account`, `ergoseek serve` and `ergoseek demo` from the command line."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from sessions.store import open_store
from testing.cli import ROOT, ergoseek
from testing.server import free_port


def test_account_create_reads_the_password_from_stdin(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    ok = ergoseek(
        "account",
        "create",
        "Coach",
        "--role",
        "trainer",
        "--database-url",
        url,
        stdin="s3cret pass for the coach\n",
    )
    assert ok.returncode == 0, ok.stderr
    assert "created trainer account 'coach'" in ok.stdout
    with open_store(url) as store:
        assert store.accounts.authenticate("coach", "s3cret pass for the coach").role == "trainer"
    again = ergoseek(
        "account",
        "create",
        "coach",
        "--role",
        "viewer",
        "--database-url",
        url,
        stdin="another pass for the coach\n",
    )
    assert again.returncode == 2 and "taken" in again.stderr and "Traceback" not in again.stderr
    short = ergoseek(
        "account", "create", "x", "--role", "viewer", "--database-url", url, stdin="short\n"
    )
    assert short.returncode == 2 and "password" in short.stderr
    role = ergoseek(
        "account", "create", "y", "--role", "boss", "--database-url", url, stdin="long-enough\n"
    )
    assert role.returncode == 2 and "invalid choice" in role.stderr
    listed = ergoseek("account", "list", "--database-url", url)
    assert "coach" in listed.stdout and "trainer" in listed.stdout


def test_serve_refuses_bad_settings_in_one_line(tmp_path: Path) -> None:
    bad = [
        (["serve", "--port", "70000"], "port"),
        (["serve", "--machine", "odrive"], "--device"),
        (["serve", "--config", str(tmp_path / "missing.toml")], "no such file"),
    ]
    for args, word in bad:
        proc = ergoseek(*args, "--data-dir", str(tmp_path))
        assert proc.returncode == 2, (args, proc.stderr)
        assert word in proc.stderr and "Traceback" not in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1
    conf = tmp_path / "bad.toml"
    conf.write_text("rate = -5\n")
    proc = ergoseek("serve", "--config", str(conf), "--data-dir", str(tmp_path))
    assert proc.returncode == 2 and "rate" in proc.stderr


def test_settings_come_from_flags_env_and_file(tmp_path: Path) -> None:
    from server.settings import Settings

    conf = tmp_path / "s.toml"
    conf.write_text('port = 9001\nmax_torque = 12.0\nhost = "0.0.0.0"\n')
    env = {"ERGOSEEK_CONFIG": str(conf), "ERGOSEEK_PORT": "9002"}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        s = Settings(host="127.0.0.2")
        assert (s.host, s.port, s.max_torque) == ("127.0.0.2", 9002, 12.0)  # flag > env > file
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def test_demo_prints_its_password_seeds_users_and_serves(tmp_path: Path) -> None:
    port = free_port()
    env = {**os.environ, "ERGOSEEK_DATA_DIR": str(tmp_path), "PYTHONUNBUFFERED": "1"}
    env.pop("ERGOSEEK_DEMO_PASSWORD", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "server", "demo", "--port", str(port), "--no-dashboard"],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        m = re.search(r"log in as 'demo' with password (\S+) \(generated\)", first)
        assert m, first
        password = m.group(1)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/healthz").status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        r = httpx.post(
            f"http://127.0.0.1:{port}/api/v1/auth/token",
            json={"login": "demo", "password": password},
        )
        assert r.status_code == 200
        users = httpx.get(
            f"http://127.0.0.1:{port}/api/v1/users",
            headers={"Authorization": f"Bearer {r.json()['access_token']}"},
        ).json()
        assert users["total"] >= 4
        assert all(u["sim_profile"] for u in users["items"])
        me = httpx.get(
            f"http://127.0.0.1:{port}/api/v1/auth/me",
            headers={"Authorization": f"Bearer {r.json()['access_token']}"},
        ).json()
        assert me["account"]["role"] == "trainer"
    finally:
        proc.terminate()
        proc.wait(20)


def test_the_passivity_bound_may_be_lowered_not_raised() -> None:
    from pydantic import ValidationError

    from server.settings import Settings

    assert Settings(passivity_c2=1e-3).machine_config().passivity_c2 == 1e-3
    assert Settings().machine_config().passivity_c2 == 50.0  # the engine's c²
    with pytest.raises(ValidationError, match="passivity_c2"):
        Settings(passivity_c2=50.5)
