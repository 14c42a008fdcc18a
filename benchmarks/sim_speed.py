"""Simulated seconds per wall second for one 1 kHz session, per controller × seeker.

    python benchmarks/sim_speed.py [--seconds 60] [--repeat 3] [--json]

Each combination runs the default scenario (Hill user with 3 % noise, 10 % ripple, fatigue)
``--repeat`` times on one core, the combinations taking turns; the best run counts (the least
disturbed by the machine).
Prints one JSON object with ``--json``; ``realtime_factor_min`` is the slowest combination.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from typing import get_args

from sessions.config import SeekerConfig, parse_session_config
from sessions.simulation import run_simulation

CONTROLLERS = ("rise", "measured")
SEEKERS: tuple[str, ...] = get_args(SeekerConfig.model_fields["kind"].annotation)  # every kind


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per session")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    load0 = os.getloadavg()[0]
    configs = {
        f"{ctrl}/{kind}": parse_session_config(
            {
                "duration": args.seconds,
                "rate": 1000.0,
                "user": {"noise": 0.03, "ripple": 0.1, "fatigue_tau": 600.0},
                "controller": {"kind": ctrl},
                "seeker": {"kind": kind},
            }
        )
        for ctrl in CONTROLLERS
        for kind in SEEKERS
    }
    # Round robin: a slow spell of the machine spreads over all combinations instead of
    # landing on every repeat of one of them.
    best: dict[str, float] = dict.fromkeys(configs, float("inf"))
    for _ in range(args.repeat):
        for name, cfg in configs.items():
            best[name] = min(best[name], run_simulation(cfg).wall_seconds)
    factors = {name: args.seconds / wall for name, wall in best.items()}
    out = {
        "rate_hz": 1000.0,
        "sim_seconds": args.seconds,
        "realtime_factor": {k: round(v, 1) for k, v in factors.items()},
        "realtime_factor_min": round(min(factors.values()), 1),
        "slowest": min(factors, key=factors.__getitem__),
        "us_per_step_max": round(1e6 / (1000.0 * min(factors.values())), 2),
        "max_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "loadavg_1min": [round(load0, 2), round(os.getloadavg()[0], 2)],
        "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out["realtime_factor"].items():
            print(f"{k:24s} {v:8.1f}× real time")
        print(f"slowest: {out['slowest']} at {out['realtime_factor_min']}×")


if __name__ == "__main__":
    main()
