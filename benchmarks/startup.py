"""CPU seconds a process of ours spends importing before it does anything.

    python benchmarks/startup.py [--repeat 5] [--json]

Every server start (``ergoseek serve``, each test server), every CLI call that refuses bad
input, and every spawned 1 kHz worker pays its imports first; the suite starts hundreds of
them. Each entry point is imported ``--repeat`` times in a fresh interpreter, its children's
user + system CPU measured with ``getrusage``; the median counts. ``heavy`` lists which of the
libraries that should load only where used (matplotlib for the PDF report, scipy's fitting and
statistics for the profile fit) the import pulled in.
Prints one JSON object with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

ENTRY_POINTS = {
    "server_app": "server.app",  # ergoseek serve, before it listens
    "worker": "sessions.worker.process",  # the spawned 1 kHz worker
    "cli": "server.cli",  # every ergoseek command, before its first check
    "dashboard": "webui.dashboard",  # the viser dashboard of a serve with one
}
HEAVY = ("matplotlib", "scipy.optimize", "scipy.stats")


def measure(module: str) -> tuple[float, float, list[str]]:
    """(CPU s, wall s, heavy libraries loaded) of one fresh interpreter importing ``module``."""
    code = f"import sys, {module}; print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall, out.stdout.split()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    load0 = os.getloadavg()
    result: dict[str, object] = {}
    for name, module in ENTRY_POINTS.items():
        runs = [measure(module) for _ in range(args.repeat)]
        result[name] = {
            "module": module,
            "cpu_s_median": round(statistics.median(r[0] for r in runs), 3),
            "wall_s_median": round(statistics.median(r[1] for r in runs), 3),
            "heavy": sorted({m for r in runs for m in r[2]}),
        }
    result["repeat"] = args.repeat
    result["loadavg_start"] = [round(x, 2) for x in load0]
    result["loadavg_end"] = [round(x, 2) for x in os.getloadavg()]
    if args.json:
        print(json.dumps(result))
    else:
        for name, r in result.items():
            print(f"{name}: {r}")


if __name__ == "__main__":
    main()
