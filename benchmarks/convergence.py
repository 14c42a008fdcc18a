"""How fast and how well each seeker converges, with the paper's settings and ergoseek's.

    python benchmarks/convergence.py [--seeds 5] [--jobs 2] [--json]

Scenarios: the paper's Exp. 1 (surrogate (31), linear user) and Exp. 2 (Hill user, τ̂·wd),
and three noisy users (3-5 % band-limited noise, 10-15 % stroke ripple, fatigue), each noisy one
over ``--seeds`` seeds. Settings: "paper" (the paper's RISE gains; Exp. 2's for the noisy users)
and "ergoseek" (the defaults). Seekers: parabolic (Appendix A, Step 7 corrected), brent,
perturbation. Per run: t_99, t_1pct, evaluations, power_ratio (true p(wd_final)/p*).
Prints one JSON object with ``--json``: every run, the medians per seeker, and the ratio of
brent's median t_99 to parabolic's.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from multiprocessing import Pool
from typing import Any

from sessions.config import parse_session_config
from sessions.experiments import PAPER_GAINS, experiment
from sessions.simulation import run_simulation, score

SEEKERS = ("parabolic", "brent", "perturbation")
TRAITS = {"noise": 0.03, "ripple": 0.1, "fatigue_tau": 1800.0}
NOISY: dict[str, tuple[dict[str, Any], list[float]]] = {
    "noisy-linear": (
        {"kind": "linear", "tau0": 2.0, "wmax": 6.0, **TRAITS},
        [1.0, 2.5, 4.0],
    ),
    "noisy-hill": (
        {"kind": "hill", "tau0": 3.0, "wmax": 10.0, **TRAITS},
        [1.0, 3.5, 6.0],
    ),
    "noisy-strong-hill": (
        {
            "kind": "hill", "tau0": 6.0, "wmax": 14.0, "curvature": 0.35, "noise": 0.05,
            "ripple": 0.15, "fatigue_model": "three-compartment", "fatigue_effort": 0.3,
            "fatigue_f": 0.002, "fatigue_r": 0.002,
        },
        [1.5, 3.5, 9.0],
    ),
}  # fmt: skip


def job(args: tuple[str, str, str, int]) -> dict[str, Any]:
    scenario, settings, seeker, seed = args
    paper = settings == "paper"
    if scenario in ("exp1", "exp2"):
        cfg = experiment(scenario, paper=paper, seeker=seeker, duration=90.0)  # type: ignore[arg-type]
    else:
        user, bracket = NOISY[scenario]
        data: dict[str, Any] = {
            "duration": 120.0,
            "seed": seed,
            "user": user,
            "seeker": {"kind": seeker, "bracket": bracket},
        }
        if paper:
            data["controller"] = {"kind": "rise", **PAPER_GAINS["exp2"]}
        cfg = parse_session_config(data)
    s = score(run_simulation(cfg))
    return {
        "scenario": scenario,
        "settings": settings,
        "seeker": seeker,
        "seed": seed,
        "t_99": s["t_99"],
        "t_1pct": s["t_1pct"],
        "evaluations": len(s["evaluations"]),
        "power_ratio": round(s["power_ratio"], 5),
        "wd_final": round(s["wd_final"], 4),
        "w_star": round(s["w_star"], 4),
        "converged": s["converged"],
    }


def median(xs: list[float | None]) -> float | None:
    """Median with 'never' (None) counted as +inf; None if the median itself is never."""
    vals = sorted(float("inf") if x is None else x for x in xs)
    m = statistics.median(vals) if vals else float("inf")
    return None if m == float("inf") else round(m, 3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds per noisy user")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    jobs = [
        (sc, st, sk, seed)
        for sc in ("exp1", "exp2", *NOISY)
        for st in ("paper", "ergoseek")
        for sk in SEEKERS
        for seed in (range(1, args.seeds + 1) if sc in NOISY else [1])
    ]
    t0 = time.perf_counter()
    with Pool(args.jobs) as pool:
        runs = pool.map(job, jobs)
    wall = time.perf_counter() - t0
    summary: dict[str, Any] = {}
    for sk in SEEKERS:
        mine = [r for r in runs if r["seeker"] == sk]
        summary[sk] = {
            "median_t_99": median([r["t_99"] for r in mine]),
            "median_evaluations": statistics.median(r["evaluations"] for r in mine),
            "min_power_ratio": min(r["power_ratio"] for r in mine),
            "share_at_99pct": round(sum(r["power_ratio"] >= 0.99 for r in mine) / len(mine), 3),
            "noisy_share_at_99pct": round(
                sum(r["power_ratio"] >= 0.99 for r in mine if r["scenario"] in NOISY)
                / max(1, sum(r["scenario"] in NOISY for r in mine)),
                3,
            ),
        }
    b, p = summary["brent"]["median_t_99"], summary["parabolic"]["median_t_99"]
    exp1 = {
        st: next(
            r["t_1pct"]
            for r in runs
            if (r["scenario"], r["settings"], r["seeker"]) == ("exp1", st, "parabolic")
        )
        for st in ("paper", "ergoseek")
    }
    out = {
        "runs": runs,
        "per_seeker": summary,
        "brent_over_parabolic_median_t99": round(b / p, 3) if b and p else None,
        "exp1_parabolic_t_1pct": exp1,
        "wall_seconds": round(wall, 1),
        "loadavg_1min": round(os.getloadavg()[0], 2),
    }
    if args.json:
        print(json.dumps(out))
        return
    print(f"{'scenario':18s} {'settings':9s} {'seeker':13s} seed   t_99  t_1pct  evals  p/p*")
    for r in runs:
        t99 = "never" if r["t_99"] is None else f"{r['t_99']:.1f}"
        t1 = "never" if r["t_1pct"] is None else f"{r['t_1pct']:.1f}"
        print(
            f"{r['scenario']:18s} {r['settings']:9s} {r['seeker']:13s} {r['seed']:4d} {t99:>6s} "
            f"{t1:>7s} {r['evaluations']:6d} {r['power_ratio']:.4f}"
        )
    print(json.dumps({k: v for k, v in out.items() if k != "runs"}, indent=2))


if __name__ == "__main__":
    main()
