"""``ergoseek run`` and ``ergoseek emulate-odrive``, as a user runs them (subprocesses)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest

from testing.cli import COMMAND, ROOT, ergoseek

CLI = COMMAND

QUICK = """
duration = {duration}
seed = 3
[user]
kind = "hill"
[seeker]
kind = "brent"
filter = {{ pole = 6.0 }}
window = 0.3
max_window = 2.0
start_delay = 0.5
"""


@pytest.fixture
def quick(tmp_path):
    made = []

    def make(duration: float = 1.0, extra: str = "") -> str:
        made.append(duration)
        p = tmp_path / f"s{len(made)}.toml"
        p.write_text(QUICK.format(duration=duration) + extra)
        return str(p)

    return make


def test_run_sim_json(quick):
    r = ergoseek("run", quick(1.0), "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["status"] == "completed" and out["reason"] == "duration reached"
    # the duration, then the wind-down to rest (a few seconds from ~3 rad/s)
    assert 1.0 < out["summary"]["duration"] < 1.0 + 8.0
    assert out["timing"]["cycles"] >= 1000 and out["timing"]["rate_hz"] == 1000.0


def test_run_bad_input_is_one_line_and_status_2(quick, tmp_path):
    cases = [
        (("run", str(tmp_path / "none.toml")), "no such file"),
        (("run", quick(), "--machine", "odrive"), "needs --device"),
        (("run", quick(), "--machine", "odrive", "--device", str(tmp_path / "x")), "no such"),
        (
            ("run", quick(extra='[controller]\nkind = "measured"\n'), "--machine", "odrive",
             "--device", "/dev/null", "--torque-constant", "0.35"),
            "torque sensor",
        ),
        (("run", quick(), "--gear-ratio", "-2"), "gear_ratio"),
        (("run", quick(), "--machine", "odrive", "--device", "/dev/null"), "torque constant"),
        (("run", quick(), "--machine", "odrive", "--device", "/dev/null",
          "--torque-constant", "0.35", "--vel-limit-tolerance", "0"), "vel_limit_tolerance"),
    ]  # fmt: skip
    for args, message in cases:
        r = ergoseek(*args)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], r.stderr
        assert lines[0].startswith("ergoseek run: error:")


@pytest.mark.realtime  # a session over the emulated drive's pty: alone, after the parallel rooms
def test_emulate_odrive_then_run_against_it(quick):
    emu = subprocess.Popen(
        [*CLI, "emulate-odrive", "--scenario", quick(),
         "--gear-ratio", "3", "--direction", "-1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )  # fmt: skip
    try:
        path = emu.stdout.readline().strip()  # type: ignore[union-attr]
        assert path.startswith("/dev/pts/") and os.path.exists(path)
        r = ergoseek(
            "run", quick(2.0), "--machine", "odrive", "--device", path,
            "--gear-ratio", "3", "--direction", "-1", "--torque-constant", "0.35",
            # generous for a loaded shared VM: the defaults (20 ms, 50 ms) are for hardware
            "--reply-timeout", "0.2", "--watchdog-timeout", "0.5",
        )  # fmt: skip
        assert r.returncode == 0, r.stdout + r.stderr
        assert "session completed: duration reached" in r.stdout
        assert "odrive machine" in r.stdout
    finally:
        emu.send_signal(signal.SIGTERM)
        _, err = emu.communicate(timeout=10)
    assert emu.returncode == 0
    assert "closed loop" in err and "idle" in err  # the device's own log of the session


def test_ctrl_c_stops_with_zero_torque(quick):
    proc = subprocess.Popen(
        [*CLI, "run", quick(30.0)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        start_new_session=True,
    )  # fmt: skip
    try:
        first = proc.stdout.readline()  # type: ignore[union-attr]
        assert first.startswith("worker pid")
        worker_pid = int(first.split()[2].rstrip(":"))
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGINT)  # as a terminal does: the whole process group
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "session stopped: stopped at once by the operator" in out
    assert not os.path.exists(f"/proc/{worker_pid}")


@pytest.mark.realtime  # a time bound on a process's start: alone, after the parallel rooms
@pytest.mark.parametrize(
    ("drive", "words"),
    [
        (("--axis", "1"), "axis0 cannot enter closed-loop control"),
        (("--uncalibrated",), "the motor is not calibrated"),
        (("--firmware", "0.5.2"), "update to 0.5.4 or later"),
        (("--factory-defaults",), "motor.config.torque_constant is 0.04"),
    ],
    ids=["wrong-axis", "uncalibrated", "firmware-0.5.2", "factory-torque-constant"],
)
def test_run_exits_at_once_with_one_line_when_the_machine_refuses_to_arm(quick, drive, words):
    emu = subprocess.Popen(
        [*CLI, "emulate-odrive", "--quiet", *drive],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )  # fmt: skip
    try:
        path = emu.stdout.readline().strip()  # type: ignore[union-attr]
        t0 = time.monotonic()
        r = ergoseek(
            "run", quick(5.0), "--machine", "odrive", "--device", path,
            "--torque-constant", "0.35", "--reply-timeout", "0.2", "--watchdog-timeout", "0.5",
            timeout=30,
        )  # fmt: skip
        took = time.monotonic() - t0
    finally:
        emu.send_signal(signal.SIGTERM)
        emu.communicate(timeout=10)
    assert r.returncode == 1, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], r.stderr
    assert lines[0].startswith("ergoseek run: ")
    assert took < 10.0  # worker start and arm: seconds, never a hang
