"""Mutation testing of the safety- and security-critical modules (``make mutation``).

MODULES is the one definition of what is mutated and which tests may kill it: a name, the
source files (globs relative to the repository root) and the pytest selection that runs for
every mutant of those files. ``python -m testing.mutation`` runs mutmut over them (see
docs/testing.md); :mod:`testing.mutation.plugin` feeds this table to mutmut.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Target:
    name: str
    sources: tuple[str, ...]  # fnmatch globs, relative to the repository root
    tests: tuple[str, ...]  # pytest node ids (folders, files, file::test): whole names
    exclude: tuple[str, ...] = ()  # tests whose names hold one of these never run (-k)


MODULES: tuple[Target, ...] = (
    # who is asking and with which role: logins, limits, Origins; the role dependencies
    Target(
        "auth",
        ("server/security.py", "server/api/deps.py", "server/api/auth.py"),
        ("tests/api/test_login_checks.py",),
    ),
    # the worker's supervision: e-stop, limits, passivity, the controlled stop. In-process:
    # the supervisor on the real loop and simulated machine, period by period. The worker's
    # process tests (test_safety, test_session, test_liveness, test_nonfinite) check the same
    # decisions through the ring, but a survivor costs them ~2 min on this machine
    Target(
        "supervisor",
        ("sessions/worker/supervisor.py",),
        (
            "tests/worker/test_supervisor.py",
            "tests/worker/test_stop_ramp.py",
            "tests/worker/test_nonfinite.py::test_a_summary_with_a_non_finite_figure_keeps_what_is_finite",
            "tests/worker/test_nonfinite.py::test_the_fallback_summary_keeps_each_finite_figure_and_zeroes_the_others",
        ),
    ),
    # the machine backends' fault handling: the lifecycle and its latched FAULT, the
    # simulator's faults, the ODrive's pre-arm checks and fault registers. In-process: the
    # lifecycle on the simulator, the checks on an emulated drive in a thread over a real pty.
    # The backend's process tests (test_odrive_arm, test_odrive_firmware: an emulator process
    # each, ~1 s a spawn) check the same through OdriveMachine, but cost a survivor minutes
    Target(
        "machine",
        (
            "sessions/machine/base.py",
            "sessions/machine/sim.py",
            "sessions/machine/odrive/checks.py",
        ),
        (
            "tests/machine/test_lifecycle.py",
            "tests/machine/test_sim.py",
            "tests/machine/test_odrive_checks.py",
            "tests/machine/test_odrive_firmware.py::test_the_firmware_policy",
        ),
    ),
    # nothing recorded is lost: the store's recorder (SQLite; PostgreSQL adds cost, not kills;
    # test_crash.py's SIGKILL of a writer process flakes at the load of a mutation run)
    Target(
        "recorder",
        ("sessions/store/recorder.py",),
        (
            "tests/store/test_recorder.py",
            "tests/store/test_telemetry.py::test_chunks_hold_at_most_one_second_and_read_back_exactly",
            "tests/store/test_telemetry.py::test_open_chunk_is_rewritten_until_full",
            "tests/store/test_telemetry.py::test_live_summary_follows_the_stored_data",
            "tests/store/test_telemetry.py::test_background_thread_commits_while_feeding",
            "tests/store/test_telemetry.py::test_recorder_resumes_after_stored_data",
            "tests/store/test_telemetry.py::test_recorder_stops_when_the_session_ended_elsewhere",
            "tests/store/test_telemetry.py::test_bad_rows_are_refused_and_nothing_is_stored",
            "tests/store/test_telemetry.py::test_non_finite_channels_are_kept",
        ),
        exclude=("postgresql",),
    ),
)
THRESHOLD = 85.0  # % of the non-equivalent mutants killed (or timed out), per module

# Survivors that no test can kill, with the reason (equivalent.toml beside this file):
# (mutmut's function name, the mutated line(s)) -> why.
EQUIVALENT: dict[tuple[str, str], str] = {
    (e["function"], e["mutant"]): e["reason"]
    for e in tomllib.loads((Path(__file__).parent / "equivalent.toml").read_text())["equivalent"]
}
