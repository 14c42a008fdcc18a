"""``ergoseek run`` and ``ergoseek emulate-odrive``, as a user runs them (subprocesses)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from testing.cli import COMMAND, ROOT, ergoseek
from testing.processes import exited

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


# SIGINT set (default or ignored) before the CLI starts, and kept across the exec: the Ctrl-C
# test must not depend on how the suite was launched. A suite started as a background job of a
# shell without job control (``cmd &``) inherits SIGINT ignored, and so would the CLI (as it
# rightly should: such a job's Ctrl-C is not its own).
WITH_SIGINT = (
    "import os, signal, sys; signal.signal(signal.SIGINT, getattr(signal, sys.argv[1])); "
    "os.execv(sys.argv[2], sys.argv[2:])"
)


def _interrupted(quick, sig: signal.Signals, *, group: bool = True, ignore_sigint: bool = False):
    """``ergoseek run`` of a 30 s session sent ``sig`` 1 s into it (its whole process group,
    as a terminal or systemd sends it, or the CLI alone, as ``kill PID``): (its process,
    stdout, stderr, the worker's pid)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", WITH_SIGINT, "SIG_IGN" if ignore_sigint else "SIG_DFL",
         *CLI, "run", quick(30.0)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        start_new_session=True,
    )  # fmt: skip
    try:
        first = proc.stdout.readline()  # type: ignore[union-attr]
        assert first.startswith("worker pid"), first + proc.stderr.read()  # type: ignore[union-attr]
        worker_pid = int(first.split()[2].rstrip(":"))
        time.sleep(1.0)
        if group:
            os.killpg(proc.pid, sig)
        else:
            os.kill(proc.pid, sig)
        if ignore_sigint:
            time.sleep(1.5)
            assert proc.poll() is None  # still running: Ctrl-C was not its to take
            os.killpg(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc, out, err, worker_pid


def test_ctrl_c_stops_with_zero_torque(quick):
    proc, out, err, worker_pid = _interrupted(quick, signal.SIGINT)
    assert proc.returncode == 130, err
    assert "session stopped: stopped at once by the operator" in out
    assert not os.path.exists(f"/proc/{worker_pid}")


@pytest.mark.parametrize("group", [True, False], ids=["process-group", "cli-alone"])
def test_sigterm_stops_with_zero_torque_and_reports(quick, group):
    # what `kill`, systemd or a container runtime sends: the session ends at once, the summary
    # printed, 128 + 15 (before: the CLI died at once with nothing said, -15). To the group,
    # the worker takes it too and ends the session aborted; to the CLI alone, it stops it.
    proc, out, err, worker_pid = _interrupted(quick, signal.SIGTERM, group=group)
    assert proc.returncode == 143, err
    ends = ("stopped", "aborted") if group else ("stopped",)  # (whichever takes it first)
    assert any(f"session {e}: terminated (SIGTERM)" in out for e in ends), out
    assert "mean power" in out and "lateness" in out  # the summary and the timing
    assert not os.path.exists(f"/proc/{worker_pid}")


def test_a_background_job_keeps_ctrl_c_ignored_and_stops_on_sigterm(quick):
    proc, out, err, worker_pid = _interrupted(quick, signal.SIGINT, ignore_sigint=True)
    assert proc.returncode == 143, err
    assert "terminated (SIGTERM)" in out
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


class _WorkerTakesItFirst:
    """A SIGTERM sent to the whole group, as systemd sends it, where the worker is faster:
    the first time the CLI looks for a signal once the session runs, the worker has already
    taken its own SIGTERM, ended the session and exited; the CLI's is noted then."""

    def __init__(self, worker) -> None:
        self.worker, self._received = worker, None

    @property
    def received(self):
        if self._received is None and self.worker.state == "running":
            pid = self.worker.pid
            os.kill(pid, signal.SIGTERM)
            deadline = time.monotonic() + 10.0
            while not exited(pid) and time.monotonic() < deadline:
                time.sleep(0.01)
            assert exited(pid), "the worker did not exit on SIGTERM"
            self._received = signal.SIGTERM
        return self._received


def test_a_sigterm_the_worker_took_first_still_ends_with_its_report(quick):
    # before: the CLI's stop went to a worker already gone: a traceback, exit 1, no summary
    # (`test_sigterm_stops_with_zero_torque_and_reports[process-group]` when the worker won)
    from server.cli.run import _follow
    from sessions.config import load_scenario
    from sessions.worker import Worker, WorkerOptions

    cfg = load_scenario(quick(30.0))
    # (as `run` starts it; liveness is not what this tests: a loaded parallel run stalled a
    # worker's heartbeat past the default 0.1 s before the signal)
    with Worker(options=WorkerOptions(heartbeat_timeout=2.0)) as worker:
        assert worker.start().fault is None
        signals = _WorkerTakesItFirst(worker)
        t0 = time.monotonic()
        end, refused = _follow(worker, cfg, lambda *a: None, signals)
    assert refused is None and end is not None
    assert (end.status, end.reason) == ("aborted", "terminated (SIGTERM)")
    assert time.monotonic() - t0 < 15.0
