"""A whole session in simulation: plant (1) + simulated user + the loop, recorded at full rate
and scored against the user's known truth. Used by ``ergoseek simulate``/``reproduce``, the
tests and the benchmarks; the real-time worker runs the same :class:`~sessions.loop.Loop`."""

from __future__ import annotations

import gc
import math
import time
from array import array
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sessions.config import SessionConfig
from sessions.loop import Loop
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.protocol.cues import CuedPerson
from sessions.protocol.stage import Stage
from sessions.seekers import Evaluation, SeekerProgress
from sessions.summary import SessionSummary, summarize
from sessions.telemetry import INDEX, WIDTH, csv_header


@dataclass
class SimulationResult:
    cfg: SessionConfig
    telemetry: np.ndarray  # (n, WIDTH), columns as sessions.telemetry.CHANNELS
    evaluations: list[Evaluation]
    progress: SeekerProgress
    user: SimulatedUser
    passivity_min: float  # from the loop's own τ or τ̂
    true_passivity_min: float  # from the user's true torque
    wall_seconds: float
    true_work: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    stages: tuple[Stage, ...] = ()  # the protocol runner's segments, as they began
    summary: SessionSummary | None = None
    min_user_torque: float = 0.0  # extremes of the user's true torque over every period
    max_user_torque: float = 0.0

    def column(self, name: str) -> np.ndarray:
        return self.telemetry[:, INDEX[name]]

    def write_csv(self, path: str) -> None:
        np.savetxt(
            path, self.telemetry, delimiter=",", header=csv_header(), comments="", fmt="%.9g"
        )


def run_simulation(cfg: SessionConfig, *, as_printed: bool = False) -> SimulationResult:
    """Run ``cfg`` from rest (q = w = 0) for its whole duration, or, with a protocol, until the
    protocol has ended at rest (the simulated person following its effort cues)."""
    dt = cfg.dt
    n = round(cfg.duration * cfg.rate)
    user = SimulatedUser(cfg.user, dt, cfg.seed)
    plant = Plant(cfg.machine.inertia)
    loop = Loop(cfg, as_printed=as_printed, truth=user)
    loop.begin(plant.q, plant.w)
    seeker, ref = loop.seeker, loop.reference
    person = user if cfg.protocol is None else CuedPerson(user, ref, dt)
    buf = array("d")
    extend = buf.extend
    true_work = array("d")
    torques = array("d")
    step, sample, advance, user_advance = (
        loop.step,
        plant.sample_torque,
        plant.advance,
        person.advance,
    )
    true_min = 0.0
    # The loop allocates only short-lived floats and tuples, freed by reference counting;
    # the cyclic collector would only interrupt it (as it would the real-time worker).
    gc_was_enabled = gc.isenabled()
    gc.disable()
    wall = time.perf_counter()
    try:
        for _ in range(n):
            tau = sample(person)
            u = step(plant.q, plant.w, tau)
            extend(loop.row)
            advance(u, dt, person)
            user_advance(dt)
            true_work.append(plant.user_work)
            torques.append(tau)
            if ref.finished:
                break
    finally:
        wall = time.perf_counter() - wall
        if gc_was_enabled:
            gc.enable()
    tw = np.frombuffer(true_work, dtype=float)
    taus = np.frombuffer(torques, dtype=float)
    if len(tw):
        true_min = min(0.0, float(tw.min()))
    return SimulationResult(
        cfg=cfg,
        telemetry=np.frombuffer(buf, dtype=float).reshape(-1, WIDTH),
        evaluations=list(seeker.evaluations),
        progress=seeker.progress(),
        user=user,
        passivity_min=loop.passivity.minimum,
        true_passivity_min=true_min,
        wall_seconds=wall,
        true_work=tw,
        stages=tuple(ref.log),
        summary=summarize(loop),
        min_user_torque=float(taus.min()) if len(taus) else 0.0,
        max_user_torque=float(taus.max()) if len(taus) else 0.0,
    )


def held_from(t: np.ndarray, ok: np.ndarray) -> float | None:
    """Earliest time after which ``ok`` holds to the end; None if it fails at the end."""
    if len(ok) == 0 or not ok[-1]:
        return None
    bad = np.flatnonzero(~ok)
    return float(t[0]) if len(bad) == 0 else float(t[bad[-1] + 1])


def score(result: SimulationResult) -> dict[str, Any]:
    """The figures ``ergoseek simulate --json`` prints, judged against the user's truth.

    ``w_star``, ``p_star`` and ``power_ratio`` = p(wd_final)/p* are at the end; ``t_99`` is the
    time after which p(wd(t), t)/p*(t) ≥ 0.99 holds to the end (the optimum may move: velocity
    fatigue); ``t_1pct`` the time after which |wd − w*(t)| ≤ 1 % of w*(t). ``regret``,
    ``at_bound``, ``target_min``/``target_max``, ``t_converged``/``wd_converged`` and the
    optimum at the end are the session summary's (:mod:`sessions.summary`)."""
    cfg, user = result.cfg, result.user
    rho = cfg.seeker.rho
    t = result.column("t")
    wd = result.column("wd")
    w = result.column("w")
    end = cfg.duration
    w_star, p_star = user.optimum(rho, end)
    wd_final = float(wd[-1]) if len(wd) else math.nan
    ratio = user.power_ratio(wd, t, rho)
    if user.speed.time_varying:
        w_stars = np.array([user.w_star(rho, float(x)) for x in t[::10]])
        w_star_t = np.repeat(w_stars, 10)[: len(t)]
    else:
        w_star_t = np.full(len(t), user.w_star(rho))
    e = w - wd
    after5 = t >= 5.0
    sm = result.summary
    summary = sm.model_dump() if sm is not None else {}
    return {
        "w_star": w_star,
        "p_star": p_star,
        "wd_final": wd_final,
        "power_ratio": user.true_power(wd_final, rho, end) / p_star,
        "t_1pct": held_from(t, np.abs(wd - w_star_t) <= 0.01 * w_star_t),
        "t_99": held_from(t, ratio >= 0.99),
        "regret": summary.get("regret"),
        "at_bound": summary.get("at_bound"),
        "target_min": summary.get("target_min"),
        "target_max": summary.get("target_max"),
        "t_converged": summary.get("t_converged"),
        "wd_converged": summary.get("wd_converged"),
        "p_converged": summary.get("p_converged"),
        "optimum_w": summary.get("optimum_w"),
        "optimum_p": summary.get("optimum_p"),
        "optimum_t": summary.get("optimum_t"),
        "evaluations": [[ev.t, ev.candidate, ev.power] for ev in result.evaluations],
        "converged": summary.get("converged", result.progress.done),
        "stop_reason": result.progress.reason,
        "passivity_min": result.passivity_min,
        "true_passivity_min": result.true_passivity_min,
        "e_rms": float(np.sqrt(np.mean(e[after5] ** 2))) if after5.any() else math.nan,
        "max_abs_u": float(np.abs(result.column("u")).max()) if len(t) else 0.0,
        "sim_seconds": end,
        "wall_seconds": result.wall_seconds,
    }
