"""``ergoseek simulate SCENARIO.toml [--json] [--csv OUT]``: one session in simulation, scored."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser(
        "simulate",
        help="run one scenario in simulation and score it against the simulated user",
        description="Run a TOML scenario (plant, user, controller, seeker) and score the result.",
    )
    p.add_argument("scenario", help="TOML scenario file (see scenarios/)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--csv", metavar="OUT", help="write full-rate telemetry as CSV")
    p.set_defaults(run=run)


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, list):
        return [_clean(v) for v in value]
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    return value


def phases(result: Any) -> list[dict[str, Any]]:
    """Each protocol phase's span, totals and optimum (and a profile's fitted parameters)."""
    from sessions.protocol.analysis import phase_spans, summarize_phase

    cols = {n: result.column(n) for n in ("t", "q", "w", "tau", "W")}
    end = float(cols["t"][-1]) + result.cfg.dt if len(cols["t"]) else 0.0
    out = []
    for span in phase_spans(result.stages, end, result.progress.target, result.progress.at_bound):
        r = summarize_phase(cols, span)
        row = {k: getattr(r, k) for k in ("kind", "name", "start", "end", "mean_power",
                                          "peak_power", "work", "optimum_w",
                                          "at_bound")}  # fmt: skip
        if r.profile is not None:
            fit = r.profile.to_dict()
            row["profile"] = {k: fit[k] for k in ("model", "tau0", "wmax", "pmax", "w_opt")}
        out.append(row)
    return out


def run(args: argparse.Namespace) -> int:
    from server.cli import UsageError
    from sessions.config import load_scenario
    from sessions.simulation import run_simulation, score

    cfg = load_scenario(args.scenario)
    result = run_simulation(cfg)
    if args.csv:
        try:
            result.write_csv(args.csv)
        except OSError as exc:
            raise UsageError(f"cannot write {args.csv}: {exc.strerror}") from None
    figures = score(result)
    if cfg.protocol is not None:
        figures["phases"] = phases(result)
    figures = _clean(figures)
    if args.json:
        print(json.dumps(figures))
        return 0
    print(f"user       w* = {figures['w_star']:.3f} rad/s   p* = {figures['p_star']:.3f} W")
    print(
        f"{cfg.seeker.kind:10s} wd = {figures['wd_final']:.3f} rad/s   "
        f"p(wd)/p* = {figures['power_ratio']:.4f}   ({figures['stop_reason'] or 'running'})"
    )
    t99, t1 = figures["t_99"], figures["t_1pct"]
    print(
        "           t_99 = "
        + (f"{t99:.1f} s" if t99 is not None else "never")
        + "   t_1pct = "
        + (f"{t1:.1f} s" if t1 is not None else "never")
        + f"   evaluations = {len(figures['evaluations'])}"
    )
    regret, lo, hi = figures["regret"], figures["target_min"], figures["target_max"]
    print(
        "           regret = "
        + (f"{100 * regret:.2f} %" if regret is not None else "-")
        + (f"   targets {lo:.3f}..{hi:.3f} rad/s" if lo is not None else "   no seeker targets")
        + (f"   AT THE {figures['at_bound'].upper()} BOUND" if figures["at_bound"] else "")
    )
    print(
        f"           W_min = {figures['passivity_min']:.3f} J   "
        f"e_rms = {figures['e_rms']:.4f} rad/s   max|u| = {figures['max_abs_u']:.2f} N·m"
    )
    print(f"           {figures['sim_seconds']:.0f} s simulated in {figures['wall_seconds']:.2f} s")
    for ph in figures.get("phases", []):
        print(
            f"phase      {ph['name']:12s} {ph['start']:7.1f} – {ph['end']:7.1f} s   "
            f"mean {ph['mean_power']:.2f} W  peak {ph['peak_power']:.2f} W  {ph['work']:.0f} J"
        )
    return 0
