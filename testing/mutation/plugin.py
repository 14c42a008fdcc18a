"""pytest plugin for mutmut runs (loaded with ``-p testing.mutation.plugin``).

1. Test selection. mutmut maps a mutated function to the tests that called it *in the pytest
   process*; our tests reach most of the code in child processes (``ergoseek serve``, the
   spawned worker, ``python -m tests.store_writer``), where mutmut sees nothing, so it would
   mark those mutants "no tests". In mutmut's stats pass this plugin declares, after each test,
   that the test covers every function of each module whose selection includes it.
2. Timeouts. mutmut ends a mutant that runs too long with SIGXCPU to its pytest process; the
   servers a test started live in sessions of their own and would be orphaned. The handler
   kills the test process's whole tree, then exits with mutmut's "timeout" code.
3. A private pytest basetemp per mutant, removed afterwards (mutmut's forked runs end with
   os._exit, so pytest's own clean-up never runs).
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import shutil
import signal
import sys
from concurrent.futures import ThreadPoolExecutor
from functools import cache
from pathlib import Path

import pytest

from testing.mutation import MODULES

PHASES = {"", "stats", "fail", "list_all_tests", "mutant_generation"}
_basetemp: list[Path] = []  # this mutant's pytest basetemp
_stats_pass: list[bool] = []  # set while mutmut's stats pass runs in this process


def _mutant() -> str:
    return os.environ.get("MUTANT_UNDER_TEST", "")


@cache
def _functions() -> dict[str, frozenset[str]]:
    """Module name -> mutmut's names of its mutated functions (from mutmut's .meta files)."""
    from mutmut.utils.format_utils import mangled_name_from_mutant_name

    out: dict[str, set[str]] = {}
    for meta in Path().glob("**/*.py.meta"):
        src = str(meta.with_suffix("")).removeprefix("./")
        for target in MODULES:
            if any(fnmatch.fnmatch(src, g) for g in target.sources):
                keys = json.loads(meta.read_text())["exit_code_by_key"]
                out.setdefault(target.name, set()).update(
                    mangled_name_from_mutant_name(k) for k in keys
                )
    return {k: frozenset(v) for k, v in out.items()}


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_teardown(item: pytest.Item) -> None:
    if not _stats_pass:
        return
    from mutmut.state import state

    for target in MODULES:
        excluded = any(x in item.nodeid for x in target.exclude)
        if item.nodeid.startswith(target.tests) and not excluded:
            state()._stats.update(_functions().get(target.name, ()))


def _descendants(pid: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, ValueError, IndexError):
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
                children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _on_timeout(signum: int, frame: object) -> None:
    for pid in _descendants(os.getpid()):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    for path in _basetemp:
        shutil.rmtree(path, ignore_errors=True)
    os._exit(36)  # mutmut: "timeout"


def _fresh_pools() -> None:
    """mutmut forks each mutant's pytest from a process that already ran the tests: a
    module-level thread pool there (``server.security._AUTH_POOL``) believes its threads are
    alive in the fork, where they are not, and work submitted to it would wait forever.
    Give each such pool of our packages a new executor with the same settings."""
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] not in ("server", "sessions", "webui"):
            continue
        for attr, value in list(vars(module).items()):
            if isinstance(value, ThreadPoolExecutor):
                fresh = ThreadPoolExecutor(value._max_workers, value._thread_name_prefix)
                setattr(module, attr, fresh)


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config: pytest.Config) -> None:
    if _mutant() == "stats":
        # The table above says which tests cover what, so the trampolines need not record
        # calls: run the original code everywhere. (mutmut's recording, at every call of a
        # mutated function, also in the spawned 1 kHz worker, slows that loop down enough
        # to fail real-time tests on a loaded machine.)
        _stats_pass.append(True)
        os.environ["MUTANT_UNDER_TEST"] = ""
        return
    if _mutant() in PHASES:
        return
    _fresh_pools()
    signal.signal(signal.SIGXCPU, _on_timeout)
    base = Path(os.environ.get("ERGOSEEK_MUTATION_TMP", "/tmp")) / f"mutant-{os.getpid()}"
    config.option.basetemp = str(base)
    _basetemp.append(base)


def pytest_unconfigure(config: pytest.Config) -> None:
    if _stats_pass:
        _stats_pass.clear()
        os.environ["MUTANT_UNDER_TEST"] = "stats"
        return
    if _mutant() not in PHASES and config.option.basetemp:
        shutil.rmtree(config.option.basetemp, ignore_errors=True)
