"""How fast and how well each seeker finds a person's optimum, over a population of people.

    nice -n 5 python benchmarks/convergence.py [--users 72] [--jobs 2] [--seed 14]
        [--populations 1] [--json]

The population (drawn with a fixed seed, the same people for every seeker: paired):
- shapes: Hill users (curvature a 0.15-0.6) and measured-curve tables whose power is
  flat-topped, sharp or skewed (``kind = "table"``, PCHIP through 30 points);
- noise 0-6 %, ripple 0-20 %;
- a third steady, a third with torque fatigue (exponential or three-compartment), a third with
  velocity fatigue (w* drifts 10-30 % over the session; some tire in strength too);
- brackets around w* (γ1 0.35-0.75 w*, γ3 1.35-2.4 w*, the start guess γ2 anywhere inside),
  and one person in eight whose w* lies outside the bracket (above or below);
- 120 s each, the default controller (RISE), the default measurement, 1 kHz.
Per seeker: median and p95 of t_99 (over the people whose start guess lies outside their
99 % band) and the median of the search's own t_99 (the track phase's later dips left out),
median regret on steady people, min power_ratio over people with w* inside (steady and
torque-fatigued; drifting people separately), the share reporting ``at_bound`` when w* is
inside (must be 0) and when it is outside, the share of escapes (a target outside [γ1, γ3]
at any period: must be 0). Also the paper's Exp. 1 and Exp. 2 with ergoseek's
defaults. Prints one JSON object with ``--json``; wall time and load with it.

One population of 72 is a small sample: its median moves by a second or more from one seed to
the next. ``--populations N`` draws N populations (seeds seed … seed + N − 1), pools their
people into the per-seeker table and lists each population's own median ``t_99`` beside it,
so a change is judged on hundreds of people and on its spread over populations.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from multiprocessing import Pool
from typing import Any

import numpy as np

from sessions.config import SeekerConfig, SessionConfig, parse_session_config
from sessions.experiments import experiment
from sessions.people import SimulatedUser
from sessions.simulation import SimulationResult, held_from, run_simulation, score

SEEKERS = ("sweep", "brent", "parabolic", "perturbation")
DURATION = 120.0
MIN_USERS = 12  # people 0-11 hold each shape, each group and one w* outside the bracket


def _table(rng: np.random.Generator, family: str) -> tuple[list[list[float]], float]:
    """Points [w, τ] of a measured-looking curve; its power on a log axis x = ln(w/w*):
    p = p*·exp(-|x/s±|^β / β): β = 4 flat-topped (99 % band ±25-40 %), β = 2 with a narrow
    s sharp (±4-6 %), β = 2 with s+ ≠ s- skewed."""
    w_star = float(rng.uniform(2.0, 6.0))
    p_star = float(rng.uniform(3.0, 40.0))
    beta, s_lo, s_hi = {
        "flat": (4.0, float(rng.uniform(0.5, 0.8)), float(rng.uniform(0.5, 0.8))),
        "sharp": (2.0, float(rng.uniform(0.3, 0.45)), float(rng.uniform(0.3, 0.45))),
        "skewed": (2.0, *((0.7, 0.3) if rng.random() < 0.5 else (0.3, 0.7))),
    }[family]
    w = np.linspace(0.15, 3.2, 60) * w_star
    x = np.log(w / w_star)
    s = np.where(x < 0, s_lo, s_hi)
    p = p_star * np.exp(-(np.abs(x / s) ** beta) / beta)
    tau = p / w
    tau *= min(1.0, 12.0 / tau.max())  # within the machine's 20 N·m
    pts = [[0.0, float(tau[0])]] + [[float(a), float(b)] for a, b in zip(w, tau, strict=True)]
    return pts, w_star


def _shape(rng: np.random.Generator, shape: str) -> dict[str, Any]:
    if shape == "hill":
        return {
            "kind": "hill",
            "tau0": float(rng.uniform(2.0, 15.0)),
            "wmax": float(rng.uniform(6.0, 20.0)),
            "curvature": float(rng.uniform(0.15, 0.6)),
        }
    pts, _ = _table(rng, shape)
    return {"kind": "table", "points": pts}


def _fatigue(rng: np.random.Generator, group: str) -> dict[str, Any]:
    """Nothing (steady), torque fatigue, or velocity fatigue (w* drifts; some tire too)."""
    if group == "torque":
        if rng.random() < 0.5:
            return {"fatigue_tau": float(rng.uniform(300.0, 3000.0))}
        return {
            "fatigue_model": "three-compartment",
            "fatigue_effort": float(rng.uniform(0.2, 0.5)),
            "fatigue_f": 0.002,
            "fatigue_r": 0.002,
        }
    if group == "drift":
        out = {
            "velocity_fatigue_floor": float(rng.uniform(0.7, 0.9)),
            "velocity_fatigue_tau": float(rng.uniform(30.0, 150.0)),
        }
        if rng.random() < 0.5:
            out["fatigue_tau"] = float(rng.uniform(600.0, 3000.0))
        return out
    return {}


def _bracket(rng: np.random.Generator, user: dict[str, Any], inside: bool) -> list[float]:
    """γ1 < γ2 < γ3 around the person's optimum over the session (or beside it)."""
    probe = SimulatedUser(parse_session_config({"user": user}).user, 1e-3, 0)
    w0 = probe.w_star()
    w_end = probe.w_star(t=DURATION)
    lo = min(w0, w_end) * float(rng.uniform(0.35, 0.75))
    hi = max(w0, w_end) * float(rng.uniform(1.35, 2.4))
    if not inside:  # the optimum outside the trainer's bracket
        if rng.random() < 0.5:
            hi = min(w0, w_end) * float(rng.uniform(0.6, 0.85))
            lo = hi * float(rng.uniform(0.35, 0.6))
        else:
            lo = max(w0, w_end) * float(rng.uniform(1.2, 1.5))
            hi = lo * float(rng.uniform(1.5, 2.2))
    guess = lo + (hi - lo) * float(rng.uniform(0.05, 0.95))
    return [lo, guess, hi]


def population(n: int, seed: int) -> list[dict[str, Any]]:
    """``n`` people drawn with ``seed``; each knows its population's seed."""
    rng = np.random.default_rng(seed)
    people = []
    for i in range(n):
        shape = ("hill", "flat", "sharp", "skewed")[i % 4]
        user = _shape(rng, shape)
        user["noise"] = float(rng.uniform(0.0, 0.06))
        user["ripple"] = float(rng.uniform(0.0, 0.2))
        group = ("steady", "torque", "drift")[(i // 4) % 3]
        user |= _fatigue(rng, group)
        inside = i % 8 != 7
        bracket = _bracket(rng, user, inside)
        people.append(
            {
                "id": i,
                "population": seed,
                "shape": shape,
                "group": group,
                "inside": inside,
                "seed": int(rng.integers(1, 2**31)),
                "user": user,
                "bracket": bracket,
                "max_velocity": max(15.0, 1.3 * bracket[2]),
            }
        )
    return people


def t_99_search(result: SimulationResult, s: dict[str, Any]) -> float | None:
    """The search's own ``t_99``: the time from which p(wd, t)/p*(t) ≥ 0.99 holds until wd has
    arrived at the vertex the search converged on (within 2 %), what the track phase does
    after that left out; None if the search never converged or arrived outside the band.
    Beside ``t_99`` it tells the search's time from the tracker's later dips."""
    tc, wc = s["t_converged"], s["wd_converged"]
    if tc is None or wc is None:
        return None
    t, wd = result.column("t"), result.column("wd")
    there = np.flatnonzero((t >= tc) & (np.abs(wd - wc) <= 0.02 * wc))
    if len(there) == 0:
        return None
    end = int(there[0]) + 1
    ok = result.user.power_ratio(wd[:end], t[:end], result.cfg.seeker.rho) >= 0.99
    return held_from(t[:end], ok)


def session_config(person: dict[str, Any], seeker: str) -> SessionConfig:
    """One person's session with one seeker: every default, DURATION long."""
    return parse_session_config(
        {
            "duration": DURATION,
            "seed": person["seed"],
            "machine": {"max_velocity": person["max_velocity"]},
            "user": person["user"],
            "seeker": {"kind": seeker, "bracket": person["bracket"]},
        }
    )


def job(args: tuple[dict[str, Any], str]) -> dict[str, Any]:
    person, seeker = args
    result = run_simulation(session_config(person, seeker))
    s = score(result)
    lo, guess, hi = person["bracket"]
    user = result.user
    ratio0 = float(user.power_ratio(np.array([guess]), np.array([0.0]))[0])
    escaped = s["target_min"] < lo - 1e-9 or s["target_max"] > hi + 1e-9
    return {
        "id": person["id"],
        "population": person["population"],
        "seeker": seeker,
        "shape": person["shape"],
        "group": person["group"],
        "inside": person["inside"],
        "guess_outside_band": ratio0 < 0.99,
        "t_99": s["t_99"],
        "t_99_search": t_99_search(result, s),
        "regret": s["regret"],
        "power_ratio": round(s["power_ratio"], 5),
        "at_bound": s["at_bound"],
        "escaped": escaped,
        "t_converged": s["t_converged"],
        "w_star": round(s["w_star"], 4),
        "wd_final": round(s["wd_final"], 4),
        "wall_seconds": round(result.wall_seconds, 2),
    }


def quantile(xs: list[float | None], q: float) -> float | None:
    """Quantile with 'never' (None) counted as +inf; None if it is never."""
    vals = sorted(math.inf if x is None else x for x in xs)
    if not vals:
        return None
    v = float(np.quantile(np.array(vals), q, method="inverted_cdf"))
    return None if math.isinf(v) else round(v, 3)


def table(runs: list[dict[str, Any]], seekers: tuple[str, ...]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for sk in seekers:
        mine = [r for r in runs if r["seeker"] == sk]
        far = [r for r in mine if r["guess_outside_band"] and r["inside"]]
        steady = [r for r in mine if r["group"] == "steady" and r["inside"]]
        fixed_in = [r for r in mine if r["inside"] and r["group"] != "drift"]
        drift_in = [r for r in mine if r["inside"] and r["group"] == "drift"]
        inside = [r for r in mine if r["inside"]]
        outside = [r for r in mine if not r["inside"]]
        out[sk] = {
            "median_t_99": quantile([r["t_99"] for r in far], 0.5),
            "p95_t_99": quantile([r["t_99"] for r in far], 0.95),
            "median_t_99_search": quantile([r["t_99_search"] for r in far], 0.5),
            "users_for_t_99": len(far),
            "median_regret_steady": round(statistics.median(r["regret"] for r in steady), 4),
            "median_regret_all": round(statistics.median(r["regret"] for r in mine), 4),
            "min_power_ratio_inside": min(r["power_ratio"] for r in fixed_in),
            "min_power_ratio_drifting": min(r["power_ratio"] for r in drift_in),
            "share_ratio_99_inside": round(
                sum(r["power_ratio"] >= 0.99 for r in fixed_in) / len(fixed_in), 3
            ),
            "share_at_bound_inside": round(
                sum(r["at_bound"] is not None for r in inside) / len(inside), 3
            ),
            "share_at_bound_outside": round(
                sum(r["at_bound"] is not None for r in outside) / max(1, len(outside)), 3
            ),
            "share_escapes": round(sum(r["escaped"] for r in mine) / len(mine), 3),
            "median_wall_seconds": statistics.median(r["wall_seconds"] for r in mine),
        }
    return out


def experiments() -> dict[str, Any]:
    """The paper's experiments with ergoseek's default seeker and gains (filter (32))."""
    default = SeekerConfig().kind
    out = {}
    for name in ("exp1", "exp2"):
        s = score(run_simulation(experiment(name, paper=False, seeker=default, duration=60.0)))  # type: ignore[arg-type]
        out[name] = {
            "seeker": default,
            "t_1pct": s["t_1pct"],
            "t_99": s["t_99"],
            "wd_final": round(s["wd_final"], 4),
            "optimum_w": s["optimum_w"],
            "w_star": round(s["w_star"], 4),
            "velocity_error": round(abs(s["optimum_w"] - s["w_star"]) / s["w_star"], 4)
            if s["optimum_w"]
            else None,
            "power_ratio": round(s["power_ratio"], 5),
            "regret": s["regret"],
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--users", type=int, default=72)
    ap.add_argument("--seed", type=int, default=14)
    ap.add_argument(
        "--populations", type=int, default=1, help="populations drawn, seeds seed, seed + 1, …"
    )
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--seekers", default=",".join(SEEKERS))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    seekers = tuple(args.seekers.split(","))
    if args.users < MIN_USERS:  # every group, and a person with w* outside, in the table
        ap.error(f"--users must be at least {MIN_USERS}")
    if args.populations < 1:
        ap.error("--populations must be at least 1")
    unknown = sorted(set(seekers) - set(SEEKERS))
    if unknown:
        ap.error(f"--seekers: unknown {', '.join(unknown)} (known: {', '.join(SEEKERS)})")
    seeds = list(range(args.seed, args.seed + args.populations))
    people = [p for s in seeds for p in population(args.users, s)]
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    with Pool(max(1, min(args.jobs, 2))) as pool:
        runs = pool.map(job, [(p, sk) for p in people for sk in seekers], chunksize=1)
        exps = pool.apply(experiments)
    wall = time.perf_counter() - t0
    out = {
        "per_seeker": table(runs, seekers),
        "experiments": exps,
        "default_seeker": SeekerConfig().kind,
        "users": len(people),
        "seed": args.seed,
        "populations": {
            str(s): {
                sk: table([r for r in runs if r["population"] == s], (sk,))[sk]["median_t_99"]
                for sk in seekers
            }
            for s in seeds
        },
        "wall_seconds": round(wall, 1),
        "loadavg_start": [round(x, 2) for x in load0],
        "loadavg_end": [round(x, 2) for x in os.getloadavg()],
        "runs": runs,
    }
    if args.json:
        print(json.dumps(out))
        return
    head = f"{'pop':>4s} {'id':>3s} {'shape':7s} {'group':7s} in seeker        t_99   regret"
    print(f"{head}  p/p*    bound")
    for r in runs:
        t99 = "never" if r["t_99"] is None else f"{r['t_99']:.1f}"
        print(
            f"{r['population']:4d} {r['id']:3d} {r['shape']:7s} {r['group']:7s} "
            f"{'y' if r['inside'] else 'n'}  "
            f"{r['seeker']:12s} {t99:>6s} {r['regret']:7.4f} {r['power_ratio']:.4f}  "
            f"{r['at_bound'] or '-'}{' ESCAPED' if r['escaped'] else ''}"
        )
    print(json.dumps({k: v for k, v in out.items() if k != "runs"}, indent=2))


if __name__ == "__main__":
    main()
