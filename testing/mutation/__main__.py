"""``python -m testing.mutation [--module NAME]... [--workers N]``: mutmut over MODULES.

Copies the working tree's tracked files to build/mutation/ (mutmut's config is generated there,
its ``mutants/`` tree and results stay out of the repository), runs ``mutmut run`` once for
all chosen modules (per-module test selection by :mod:`testing.mutation.plugin`), then prints
one line per module and writes every mutant that was not killed, with its diff, to
build/mutation/survivors.md. Exit 1 if a module scores below THRESHOLD.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

from testing.mutation import EQUIVALENT, MODULES, THRESHOLD, Target

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_WORK = ROOT / "build" / "mutation"
PACKAGES = ("server", "sessions", "webui")  # copied into mutants/ (imported by the tests)
COPY = (*PACKAGES, "tests", "testing", "pyproject.toml")
DETECTED = {"killed", "timeout", "caught by type check", "segfault", "aborted"}  # segfault: -9/-11
# mutmut calls any other exit "suspicious"; a test process that died of SIGABRT ran a mutant
# that aborts where the code must not (the simulator's injected abort: only its child-process
# test expects it)
ABORTED = -signal.SIGABRT
PENDING = "not checked"  # mutmut's status of a mutant not run yet
# the tests timed where it happens (marker realtime) fail for the load of a mutation run itself
PYTEST_ARGS = [
    "-p", "testing.mutation.plugin", "-p", "no:cacheprovider", "-m", "not docker and not realtime",
]  # fmt: skip


def sync(work: Path) -> None:
    """A fresh copy of the tracked (and new, not ignored) files that the tests need."""
    shutil.rmtree(work, ignore_errors=True)
    listed = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", *COPY],
        cwd=ROOT, check=True, capture_output=True, text=True,
    ).stdout.split()  # fmt: skip
    for name in listed:
        src = ROOT / name
        if src.is_file():
            (work / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, work / name)


def write_config(work: Path, targets: list[Target], per_test_timeout: int) -> None:
    tests = list(dict.fromkeys(t for target in targets for t in target.tests))
    # excluded tests never run at all (mutmut's own passes run the whole selection too)
    excluded = sorted({x for target in targets for x in target.exclude})
    deselect = ["-k", " and ".join(f"not {x}" for x in excluded)] if excluded else []
    cfg = {
        "source_paths": list(PACKAGES),
        "also_copy": ["testing"],
        "only_mutate": [g for target in targets for g in target.sources],
        "pytest_add_cli_args_test_selection": tests,
        "pytest_add_cli_args": [*PYTEST_ARGS, *deselect, "--timeout", str(per_test_timeout)],
        # a mutant's wall limit: (its tests' call time + constant) * multiplier, in seconds
        "timeout_constant": 20.0,
        "timeout_multiplier": 3.0,
        # each mutant forks from a server that has only collected the tests, not run them:
        # a fork of the process that ran them inherits its state (pools, caches, servers)
        "process_isolation": "forkserver",
    }
    toml = "\n[tool.mutmut]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in cfg.items())
    with (work / "pyproject.toml").open("a") as f:
        f.write(toml)


def results(work: Path, target: Target) -> dict[str, str]:
    """Mutant name -> status, for the mutants of ``target``'s sources."""
    from mutmut.stats import status_by_exit_code

    out: dict[str, str] = {}
    for meta in sorted((work / "mutants").glob("**/*.py.meta")):
        src = str(meta.relative_to(work / "mutants").with_suffix(""))
        if any(fnmatch.fnmatch(src, g) for g in target.sources):
            for name, code in json.loads(meta.read_text())["exit_code_by_key"].items():
                out[name] = "aborted" if code == ABORTED else status_by_exit_code[code]
    return out


def diffs(work: Path, names: list[str]) -> dict[str, str]:
    """``mutmut show`` for many mutants in one process (mutmut reads its config in ``work``)."""
    code = (
        "import json, sys\n"
        "from mutmut.mutation.diff_apply import get_diff_for_mutant\n"
        "print(json.dumps({n: get_diff_for_mutant(n) for n in json.load(sys.stdin)}))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=work, input=json.dumps(names),
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    return json.loads(done.stdout)


def key(name: str, text: str) -> tuple[str, str]:
    """The EQUIVALENT key of a mutant: its function and its "+" lines (a mutant that only
    removes lines: "- " and the lines removed)."""
    lines = text.splitlines()
    plus = [ln[1:].strip() for ln in lines if ln.startswith("+") and ln[:3] != "+++"]
    if not plus:
        minus = [ln[1:].strip() for ln in lines if ln.startswith("-") and ln[:3] != "---"]
        return name.partition("__mutmut_")[0], "- " + " / ".join(minus)
    return name.partition("__mutmut_")[0], " / ".join(plus)


def score(work: Path, target: Target, lines: list[str]) -> bool:
    """Print the module's line, append its survivors to ``lines``; True if it passes."""
    status = results(work, target)
    counts = Counter(status.values())
    unseen = ("skipped", PENDING)  # a run stopped early scores what it checked
    alive = [n for n, s in status.items() if s not in DETECTED and s not in unseen]
    survivors = diffs(work, alive)
    equivalent = {n: EQUIVALENT[key(n, d)] for n, d in survivors.items() if key(n, d) in EQUIVALENT}
    tested = len(status) - counts["skipped"] - counts[PENDING] - len(equivalent)
    detected = sum(counts[s] for s in DETECTED)
    pct = 100.0 * detected / tested if tested else 0.0
    rest = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()) if s not in DETECTED)
    print(
        f"{target.name:10s} {pct:5.1f} %  {detected}/{tested} killed"
        f" ({counts['timeout']} by timeout; {len(equivalent)} equivalent not counted)"
        f"  {len(survivors) - len(equivalent)} unexplained survivors  [{rest or '-'}]"
    )
    lines.append(f"\n## {target.name}: {pct:.1f} % ({detected}/{tested})\n")
    for n, d in survivors.items():
        why = equivalent.get(n, "UNEXPLAINED: kill it with a test or list it in EQUIVALENT")
        lines.append(f"\n### {n} ({status[n]})\n\n{why}\n\n```diff\n{d}\n```\n")
    return pct >= THRESHOLD


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m testing.mutation", description=__doc__)
    parser.add_argument("--module", action="append", choices=[t.name for t in MODULES])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--per-test-timeout", type=int, default=120)
    parser.add_argument("--report-only", action="store_true", help="score the last run again")
    parser.add_argument("--work", type=Path, default=DEFAULT_WORK, help="where mutmut runs")
    args = parser.parse_args(argv)
    work = args.work.resolve()
    targets = [t for t in MODULES if not args.module or t.name in args.module]

    started = time.monotonic()
    if not args.report_only:
        sync(work)
        write_config(work, targets, args.per_test_timeout)
        (work / "tmp").mkdir()
        # must exist before mutmut starts: Python caches "no finder" for a PYTHONPATH entry
        # that is missing at start-up, and imports fall through to the editable install
        (work / "mutants").mkdir()
        env = {
            **os.environ,
            # every child python (servers, spawned workers, ``-c`` helpers) imports the
            # mutated tree, whatever its cwd: the editable install maps to the original one
            "PYTHONPATH": str(work / "mutants"),
            "ERGOSEEK_MUTATION_TMP": str(work / "tmp"),
        }
        mutmut = Path(sys.executable).with_name("mutmut")
        with (work / "mutmut.log").open("w") as log:
            rc = subprocess.run(
                ["nice", "-n", "10", str(mutmut), "run", "--max-children", str(args.workers)],
                cwd=work, env=env, stdout=log, stderr=subprocess.STDOUT, check=False,
            ).returncode  # fmt: skip
        if rc != 0:
            print(f"mutmut failed (exit {rc}); see {work / 'mutmut.log'}", file=sys.stderr)
            return 2
        # a kill must be seen twice: each detected mutant runs once more in a fresh fork (a
        # wall-clock limit or a timing bound on a loaded machine can "kill" a survivor); what
        # survives the second run is a survivor
        seen = [n for t in targets for n, s in results(work, t).items() if s in DETECTED]
        if seen:
            with (work / "mutmut.log").open("a") as log:
                subprocess.run(
                    ["nice", "-n", "10", str(mutmut), "run", "--max-children",
                     str(args.workers), *seen],
                    cwd=work, env=env, stdout=log, stderr=subprocess.STDOUT, check=False,
                )  # fmt: skip

    lines = ["# Mutants not killed\n"]
    ok = [score(work, target, lines) for target in targets]
    (work / "survivors.md").write_text("".join(lines))
    print(f"survivors: {work / 'survivors.md'}; {time.monotonic() - started:.0f} s")
    return 0 if all(ok) else 1


if __name__ == "__main__":
    raise SystemExit(main())
