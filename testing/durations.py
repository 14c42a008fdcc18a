"""The suite's modules by how long they take, for the parallel part's scheduling.

``make test`` runs the parallel part with ``--dist loadfile``: each module goes whole to one
worker, handed out in collection order as workers free up. xdist's default order is by the
number of tests in a module, not their time, so the few-but-slow modules (a browser and a
server each) came last and one worker ran them alone at the end. Longest first (LPT) keeps
the tail short: :data:`FILE` holds each module's measured seconds, ``tests/conftest.py``
orders by it (modules it does not list run after, in their usual order).

Refresh after a run with ``--junitxml``::

    python -m testing.durations /tmp/junit.xml   # rewrites tests/durations.json
"""

from __future__ import annotations

import argparse
import json
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

FILE = Path(__file__).resolve().parent.parent / "tests" / "durations.json"


def load() -> dict[str, float]:
    """Module path (``tests/api/test_crash.py``) → seconds; empty if the file is missing."""
    try:
        return {str(k): float(v) for k, v in json.loads(FILE.read_text()).items()}
    except FileNotFoundError:
        return {}


def from_junit(path: Path) -> dict[str, float]:
    """Each module's total time in a JUnit XML report (its tests' calls, setups, teardowns)."""
    per: dict[str, float] = defaultdict(float)
    for case in ET.parse(path).getroot().iter("testcase"):
        module = case.get("classname", "").split(".")
        # classname: tests.api.test_crash[.Class]: the module is the first test_* part
        parts = []
        for part in module:
            parts.append(part)
            if part.startswith("test_"):
                break
        per["/".join(parts) + ".py"] += float(case.get("time", 0.0))
    return dict(per)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m testing.durations", description=__doc__)
    p.add_argument("junit", type=Path, help="a JUnit XML report of a run of the suite")
    args = p.parse_args(argv)
    if not args.junit.is_file():
        print(f"testing.durations: {args.junit}: no such file", file=sys.stderr)
        return 2
    table = dict(sorted(from_junit(args.junit).items(), key=lambda kv: -kv[1]))
    FILE.write_text(json.dumps({k: round(v, 1) for k, v in table.items()}, indent=1) + "\n")
    print(f"{len(table)} modules, {sum(table.values()):.0f} s in all → {FILE}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
