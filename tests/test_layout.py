"""The layout's rules, read from the source (docs/architecture.md): the shipped packages never
import the test tooling; the machine service knows no HTTP and no viser; the dashboard reaches
the server through typed objects; each code is defined in one module; each room of the tests
has its conftest."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ("sessions", "server", "webui")


def modules(*packages: str) -> Iterator[tuple[Path, ast.Module]]:
    for package in packages:
        for path in sorted((ROOT / package).rglob("*.py")):
            yield path, ast.parse(path.read_text(encoding="utf-8"))


def imported(tree: ast.Module) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
    return names


def top(name: str) -> str:
    return name.split(".", maxsplit=1)[0]


def test_the_shipped_packages_import_no_test_tooling() -> None:
    bad = [
        f"{path.relative_to(ROOT)}: {name}"
        for path, tree in modules(*SHIPPED)
        for name in imported(tree)
        if top(name) in ("tests", "testing")
    ]
    assert not bad, bad


def test_the_service_knows_no_http_and_no_viser() -> None:
    bad = [
        f"{path.relative_to(ROOT)}: {name}"
        for path, tree in modules("server/service", "sessions")
        for name in imported(tree)
        if top(name) in ("fastapi", "starlette", "uvicorn", "viser", "webui")
        or name.startswith("server.api")
    ]
    assert not bad, bad


SERVER_PARTS = {"runtime", "store", "machine", "control", "hub", "settings", "service", "bridge"}


def test_the_dashboard_reaches_the_server_through_typed_objects() -> None:
    loose = []
    for path, tree in modules("webui"):
        for node in ast.walk(tree):
            if isinstance(node, ast.arg) and node.arg in SERVER_PARTS:
                ann = node.annotation
                if ann is None or (isinstance(ann, ast.Name) and ann.id in ("Any", "object")):
                    loose.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.arg}")
    assert not loose, loose


ONE_DEFINITION = {
    "DELAY", "SETTLING", "MEASURING", "DONE", "PHASES", "STOPPING",
    "TORQUE_LIMIT", "VELOCITY_LIMIT", "FLAG_STOPPING", "FLAG_ESTOP", "FLAG_FAULT",
    "FLAG_PASSIVITY", "STATES", "STATUSES", "SessionStatus", "EndStatus", "WorkerStateName",
    "RANK", "ROLES", "Role", "STATE_IDLE", "STATE_RUNNING", "STATE_FAULTED",
}  # fmt: skip


def test_each_code_is_defined_in_one_module() -> None:
    where: dict[str, list[str]] = {}
    for path, tree in modules(*SHIPPED):
        for node in tree.body:
            targets: list[ast.expr] = []
            if isinstance(node, ast.Assign):
                targets = node.targets
            elif isinstance(node, ast.AnnAssign):
                targets = [node.target]
            for target in targets:
                for name in ast.walk(target):
                    if isinstance(name, ast.Name) and name.id in ONE_DEFINITION:
                        where.setdefault(name.id, []).append(str(path.relative_to(ROOT)))
    twice = {name: paths for name, paths in where.items() if paths != ["sessions/codes.py"]}
    assert not twice, twice


def test_each_room_of_the_tests_has_its_conftest() -> None:
    rooms = [p for p in (ROOT / "tests").iterdir() if p.is_dir() and (p / "__init__.py").exists()]
    assert {p.name for p in rooms} >= {
        "engine", "machine", "worker", "store", "api", "dashboard", "docker"
    }  # fmt: skip
    assert all((p / "conftest.py").exists() for p in rooms), [p.name for p in rooms]


def test_a_server_start_and_a_worker_load_no_plotting_or_fitting_library() -> None:
    """The server, its CLI and every spawned worker start often (each test server, each worker
    replaced): matplotlib (the PDF report) and scipy's fitting and statistics (the profile fit)
    load where they are used, not at import (measured: 4.0 → 2.2 CPU-s for ``server.app``,
    1.9 → 0.5 for the worker)."""
    from testing.processes import loaded_after

    heavy = ("matplotlib", "scipy.optimize", "scipy.stats")
    for module in ("server.app", "sessions.worker.process", "server.cli"):
        assert loaded_after(f"import {module}", heavy) == [], f"importing {module}"


def test_the_mutation_targets_name_tests_that_exist() -> None:
    """A renamed test must not leave ``make mutation`` selecting nothing (mutmut then stops
    in its first pass, after minutes)."""
    from testing.mutation import MODULES

    for target in MODULES:
        for node in target.tests:
            path, _, name = node.partition("::")
            assert (ROOT / path).exists(), f"{target.name}: no {path}"
            if name:
                assert f"def {name}(" in (ROOT / path).read_text(), f"{target.name}: no {node}"
