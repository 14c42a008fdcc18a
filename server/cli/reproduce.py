"""``ergoseek reproduce {exp1,exp2,exp1-as-printed,exp2-as-printed} [--out DIR]``.

Runs the paper's experiments (Section VI) in simulation and writes figures like its
Figs. 2-5 (desired vs actual velocity; motor torque), a search figure (candidates, bracket,
measured power), the JSON summary and the full-rate CSV. ``*-as-printed`` runs Appendix A with
Step 7 exactly as printed (docs/erratum.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

NAMES = ("exp1", "exp2", "exp1-as-printed", "exp2-as-printed")


def register(sub: Any) -> None:
    p = sub.add_parser(
        "reproduce",
        help="run the paper's experiments in simulation and write its figures",
        description=__doc__.split("\n\n")[1],
    )
    p.add_argument("experiment", choices=NAMES)
    p.add_argument("--out", default="out", help="output folder (default: out/)")
    p.add_argument(
        "--gains",
        choices=("paper", "ergoseek"),
        default="paper",
        help="the paper's controller gains (default) or ergoseek's defaults",
    )
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds (default 60)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from server.cli import UsageError
    from server.cli.simulate import _clean
    from sessions.experiments import experiment
    from sessions.simulation import run_simulation, score

    if not 5.0 <= args.duration <= 3600.0:
        raise UsageError("--duration must be between 5 and 3600 s")
    name: str = args.experiment
    base = name.removesuffix("-as-printed")
    as_printed = name.endswith("-as-printed")
    cfg = experiment(base, paper=args.gains == "paper", duration=args.duration)  # type: ignore[arg-type]
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot create {out}: {exc.strerror}") from None
    result = run_simulation(cfg, as_printed=as_printed)
    figures = _clean(score(result))
    figures["experiment"] = name
    figures["gains"] = args.gains
    figures["config"] = cfg.model_dump(mode="json")
    stem = out / name
    Path(f"{stem}.json").write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    result.write_csv(f"{stem}.csv")
    pngs = _plot(result, name, stem)
    print(
        f"{name}: wd → {figures['wd_final']:.3f} rad/s (w* = {figures['w_star']:.3f}), "
        f"p/p* = {figures['power_ratio']:.4f}, t_1pct = {figures['t_1pct']}, "
        f"{len(figures['evaluations'])} evaluations, {figures['stop_reason'] or 'not stopped'}"
    )
    for path in [f"{stem}.json", f"{stem}.csv", *pngs]:
        print(f"  wrote {path}")
    return 0


def _plot(result: Any, name: str, stem: Path) -> list[str]:
    import matplotlib.pyplot as plt

    t = result.column("t")
    paths = []
    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=110)
    ax.plot(t, result.column("wd"), "--", color="C0", label="desired velocity $\\dot q_d$")
    ax.plot(t, result.column("w"), "-", color="C1", lw=0.8, label="actual velocity $\\dot q$")
    w_star = result.user.w_star(result.cfg.seeker.rho)
    ax.axhline(w_star, color="grey", lw=0.6, ls=":", label=f"optimum {w_star:.2f} rad/s")
    ax.set(xlabel="time [s]", ylabel="velocity [rad/s]", title=f"{name}: velocity (cf. Figs. 2, 4)")
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
    paths.append(f"{stem}-velocity.png")
    fig.tight_layout()
    fig.savefig(paths[-1])
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 3.0), dpi=110)
    ax.plot(t, result.column("u"), color="C2", lw=0.8, label="motor torque u")
    ax.plot(t, result.column("tau"), color="C3", lw=0.8, alpha=0.7, label="user torque τ̂ (28)")
    ax.set(xlabel="time [s]", ylabel="torque [N·m]", title=f"{name}: torque (cf. Figs. 3, 5)")
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
    paths.append(f"{stem}-torque.png")
    fig.tight_layout()
    fig.savefig(paths[-1])
    plt.close(fig)

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=110)
    a1.plot(t, result.column("gamma"), color="C0", lw=1.0, label="candidate γ")
    for ev in result.evaluations:
        a1.plot(ev.t, ev.candidate, "o", color="C1", ms=4)
    a1.axhline(w_star, color="grey", lw=0.6, ls=":")
    a1.set(xlabel="time [s]", ylabel="γ [rad/s]", title="candidates (dots: measured)")
    a1.grid(alpha=0.3)
    w = sorted({ev.candidate for ev in result.evaluations} | {w_star})
    import numpy as np

    grid = np.linspace(min(w) * 0.8, max(w) * 1.1, 200)
    if result.cfg.seeker.objective == "surrogate":
        from sessions.objective import surrogate_power

        truth = [surrogate_power(x) for x in grid]
    else:
        truth = [result.user.true_power(x, result.cfg.seeker.rho, 0.0) for x in grid]
    a2.plot(grid, truth, color="grey", lw=1, label="true p(w) at t = 0")
    for i, ev in enumerate(result.evaluations):
        a2.plot(ev.candidate, ev.power, "o", color="C1", ms=4)
        a2.annotate(
            str(i + 1),
            (ev.candidate, ev.power),
            fontsize=7,
            xytext=(3, 3),
            textcoords="offset points",
        )
    a2.set(xlabel="velocity [rad/s]", ylabel="p [W]", title="measured power, in order")
    a2.grid(alpha=0.3)
    a2.legend(fontsize=8)
    paths.append(f"{stem}-search.png")
    fig.tight_layout()
    fig.savefig(paths[-1])
    plt.close(fig)
    return paths
