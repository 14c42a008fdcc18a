"""The one online interface every seeker offers the loop, and what a session can read of it.

Each loop period the loop reads the reference ``wd, ad, jd`` (attributes, for speed), computes
its control, then calls ``tell(t, q, p, e)`` with the power it measured (p = τ̂·w^ρ by default,
see ``SeekerConfig.measure``) and the tracking error e = w - wd, so the seeker knows the
measured velocity w = wd + e. That advances the seeker one period. ``tell`` returns an
:class:`Evaluation` when a power has just been measured. ``progress()`` gives plain data
(bracket, candidates with measured power, best so far, done) for events, the store and the
dashboard.

Guarantees every seeker keeps (tests/engine/test_bounds.py checks them with hypothesis):

- **The bracket is a hard bound.** ``target`` (the candidate fed to the filter) stays within
  [lo, hi] = [γ1, γ3] ∩ [0, 0.95·max_velocity] at every period, and so does wd once the
  filter has reached the bracket from the machine's starting velocity (the filters are
  cascades of positive lags: their output never leaves the hull of their input and start).
  ``expand = true`` moves lo or hi outward in steps of a quarter of the initial width, never
  past ``expand_limit`` nor the machine's headroom (:meth:`Seeker.expand`).
- **An edge is not an optimum.** When the best point is at lo or hi and the measurements say
  the power still rises outward, ``at_bound`` is "lower" or "upper": the search did not
  converge (``t_converged`` stays None) and the summary does not call it converged.
- **Non-finite input never reaches a target.** A NaN or infinite p or e is ignored: the
  reference advances with the target held (finite, inside the bracket) and ``nonfinite``
  counts it, so the loop (``Loop.fault``) and the worker can end the session on it.
- **What was found, and when.** ``optimum`` is the current best estimate of the optimal
  velocity (the setpoint to store), ``optimum_power`` the power measured there;
  ``t_converged``, ``w_converged``, ``p_converged`` record the first convergence.

:class:`FilteredSeeker` is the common machinery of the numerical seekers (Appendix A): a
candidate γ is fed through the trajectory filter (32)/(33); after the start delay the seeker
waits until |e| ≤ ē1 and |wd - γ| ≤ ē2 (Step 3), averages p (see :mod:`.averaging`), and
hands the measurement to its *plan*, a generator that yields candidates and receives
evaluations. A plan reads like the algorithm it implements. Once the plan has converged, a
:class:`~sessions.seekers.tracker.Tracker` follows the optimum if it moves (``track``).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Generator
from dataclasses import dataclass, field

import numpy as np

from sessions.codes import DELAY, DONE, MEASURING, PHASES, SETTLING
from sessions.config import SeekerConfig
from sessions.filters import TrajectoryFilter
from sessions.seekers.averaging import PowerAverager
from sessions.seekers.regression import Rows

HEADROOM = 0.95  # targets stay below this fraction of the machine's velocity limit
EXPAND_FRACTION = 0.25  # one expansion step, as a fraction of the initial bracket's width


@dataclass(frozen=True, slots=True)
class Evaluation:
    """One measured power: when the measurement ended, the velocity it was measured at (the
    mean of w over the window; of wd with ``measure = "desired"``), p and its standard error."""

    t: float
    candidate: float
    power: float
    stderr: float = 0.0


@dataclass(frozen=True, slots=True)
class SeekerProgress:
    kind: str
    phase: str
    target: float
    bracket: tuple[float, float]
    evaluations: tuple[Evaluation, ...] = ()
    best: Evaluation | None = None
    done: bool = False
    fraction: float = 0.0
    reason: str = ""
    extra: dict[str, float] = field(default_factory=dict)
    at_bound: str | None = None
    optimum: float | None = None
    tracking: bool = False
    bounds: tuple[float, float] = (0.0, 0.0)


Plan = Generator[float, Evaluation, tuple[float, str]]


def is_finite(x: float) -> bool:
    return x - x == 0.0  # False for nan and ±inf; cheaper than math.isfinite on the 1 kHz path


class Seeker:
    """Base: the bounds, the reference outputs and the record every seeker keeps."""

    kind = "seeker"
    seeking = True  # as a loop's reference, its target is always its own (the runner's may not be)
    __slots__ = (
        "cfg", "dt", "lo", "hi", "outer", "wd", "ad", "jd", "target", "phase", "done",
        "reason", "evaluations", "bracket", "bracket0", "optimum", "optimum_power",
        "at_bound", "t_converged", "w_converged", "p_converged", "nonfinite", "tracking",
        "velocity_abscissa", "ends_at",
    )  # fmt: skip

    def __init__(self, cfg: SeekerConfig, dt: float, max_velocity: float) -> None:
        self.cfg = cfg
        self.dt = dt
        top = HEADROOM * max_velocity
        self.hi = min(cfg.bracket[2], top)
        self.lo = min(cfg.bracket[0], self.hi)
        if cfg.expand and cfg.expand_limit is not None:
            self.outer = (
                min(cfg.expand_limit[0], self.lo),
                min(max(cfg.expand_limit[1], self.hi), top),
            )
        else:
            self.outer = (self.lo, self.hi)
        self.wd = self.ad = self.jd = 0.0
        self.target = self.clamp(cfg.bracket[1])
        self.phase = DELAY
        self.done = False
        self.reason = ""
        self.evaluations: list[Evaluation] = []
        self.bracket = (self.lo, self.hi)
        self.bracket0 = self.bracket
        self.optimum: float | None = None
        self.optimum_power: float | None = None
        self.at_bound: str | None = None
        self.t_converged: float | None = None
        self.w_converged: float | None = None
        self.p_converged: float | None = None
        self.nonfinite = 0
        self.tracking = False
        self.velocity_abscissa = cfg.measure == "velocity"
        # s: when the reference is taken from it and nothing follows that it learns for (its
        # seek's end, the session's duration: the runner's); the track phase ends on θ there
        self.ends_at = math.inf

    # -- bounds ----------------------------------------------------------------------------
    def clamp(self, v: float) -> float:
        """Into the hard bounds [lo, hi]; a non-finite value becomes the current target."""
        if not is_finite(v):
            v = self.target
        return min(max(v, self.lo), self.hi)

    def expand(self, side: str) -> bool:
        """Move one bound outward by a step (``expand = true``), never past ``expand_limit``
        nor the machine's headroom; False when it cannot move."""
        if not self.cfg.expand:
            return False
        step = EXPAND_FRACTION * (self.bracket0[1] - self.bracket0[0])
        if side == "upper":
            new = min(self.hi + step, self.outer[1])
            if new <= self.hi + 1e-9:
                return False
            self.hi = new
        else:
            new = max(self.lo - step, self.outer[0])
            if new >= self.lo - 1e-9:
                return False
            self.lo = new
        return True

    def edge(self, v: float) -> str | None:
        """Which bound ``v`` sits on (within the larger of min_step and 2 % of the bounds)."""
        tol = max(self.cfg.min_step, 0.02 * (self.hi - self.lo))
        if v >= self.hi - tol:
            return "upper"
        if v <= self.lo + tol:
            return "lower"
        return None

    def edge_evidence(self, side: str) -> bool:
        """Do the evaluations say the power still rises towards this bound? A weighted line
        through the measurements nearest the bound (within 35 % of the bounds' width) whose
        slope points outward by more than ``noise_k`` (at least 2) standard errors."""
        width = self.hi - self.lo
        edge = self.hi if side == "upper" else self.lo
        near = [
            ev
            for ev in self.evaluations
            if abs(ev.candidate - edge) <= 0.35 * width and is_finite(ev.power)
        ]
        near.sort(key=lambda ev: abs(ev.candidate - edge))
        near = near[:6]
        if len({round(ev.candidate, 6) for ev in near}) < 2:
            return False
        g = np.array([ev.candidate for ev in near])
        p = np.array([ev.power for ev in near])
        se = np.array([ev.stderr if 0 < ev.stderr < math.inf else math.nan for ev in near])
        known = [ev.stderr for ev in near if 0 < ev.stderr < math.inf]  # (not np.nanmedian:
        floor = statistics.median(known) if known else 0.0  # it imports numpy.ma mid-loop)
        if floor <= 0.0:
            floor = max(1e-3 * float(np.abs(p).max()), 1e-12)
        se = np.where(np.isfinite(se), np.maximum(se, 0.5 * floor), floor)
        wts = 1.0 / se**2
        gm = float((wts * g).sum() / wts.sum())
        sxx = float((wts * (g - gm) ** 2).sum())
        if sxx <= 0.0:
            return False
        slope = float((wts * (g - gm) * p).sum()) / sxx
        slope_se = math.sqrt(1.0 / sxx)
        k = max(self.cfg.noise_k, 2.0)
        outward = slope if side == "upper" else -slope
        return outward > k * slope_se

    def converged_at(self, t: float, w: float, p: float | None) -> None:
        """Record the first convergence (the search's result, not an edge)."""
        if self.t_converged is None:
            self.t_converged, self.w_converged = t, w
            self.p_converged = p if p is not None and is_finite(p) else None

    # -- the loop's interface --------------------------------------------------------------
    def begin(self, w0: float) -> None:
        raise NotImplementedError

    def tell(self, t: float, q: float, p: float, e: float) -> Evaluation | None:
        """One period: p the measured power, e = w - wd. Non-finite input is held, not
        learnt from (see the module docstring)."""
        if not (is_finite(p) and is_finite(e)):
            self.nonfinite += 1
            self.hold(t)
            return None
        return self.update(t, q, p, e)

    def update(self, t: float, q: float, p: float, e: float) -> Evaluation | None:
        raise NotImplementedError

    def hold(self, t: float) -> None:
        """Advance the reference one period without learning anything."""
        raise NotImplementedError

    # -- what a session reads --------------------------------------------------------------
    def best(self) -> Evaluation | None:
        return max(self.evaluations, key=lambda ev: ev.power, default=None)

    def fraction(self) -> float:
        if self.done:
            return 1.0
        w0 = self.bracket0[1] - self.bracket0[0]
        w = max(self.bracket[1] - self.bracket[0], 1e-9)
        goal = min(self.cfg.threshold, w0)
        if w0 <= goal:
            return 0.0
        return min(max(math.log(w0 / w) / math.log(w0 / goal), 0.0), 0.99)

    def progress(self) -> SeekerProgress:
        return SeekerProgress(
            kind=self.kind,
            phase=PHASES[self.phase],
            target=self.target,
            bracket=self.bracket,
            evaluations=tuple(self.evaluations),
            best=self.best(),
            done=self.done,
            fraction=self.fraction(),
            reason=self.reason,
            at_bound=self.at_bound,
            optimum=self.optimum,
            tracking=self.tracking,
            bounds=(self.lo, self.hi),
        )


class FilteredSeeker(Seeker):
    """Candidates through the trajectory filter, measured by Step 3, chosen by ``plan()``;
    then, with ``track``, the optimum followed by a :class:`Tracker`."""

    __slots__ = ("filter", "averager", "plan_gen", "e1", "e2", "delay", "rows", "tracker")

    def __init__(self, cfg: SeekerConfig, dt: float, max_velocity: float) -> None:
        super().__init__(cfg, dt, max_velocity)
        self.filter = TrajectoryFilter(cfg.filter.order, cfg.filter.pole, dt)
        self.averager = PowerAverager(cfg.window, cfg.max_window, cfg.quiet)
        self.e1 = cfg.e1
        self.e2 = cfg.e2
        self.delay = cfg.start_delay
        self.plan_gen: Plan | None = None
        self.rows = Rows(dt)  # every sample after the start delay, for the tracker
        self.tracker = None

    def plan(self, lo: float, guess: float, hi: float) -> Plan:
        raise NotImplementedError

    def begin(self, w0: float) -> None:
        """Start from the machine's current velocity: wd = w0, ad = jd = 0 (bumpless)."""
        self.filter.reset(w0)
        self._copy_reference()
        cfg = self.cfg
        self.plan_gen = self.plan(self.lo, self.clamp(cfg.bracket[1]), self.hi)
        self._next(None, 0.0)
        self.phase = DELAY

    def _copy_reference(self) -> None:
        f = self.filter
        self.wd, self.ad, self.jd = f.wd, f.ad, f.jd

    def _next(self, ev: Evaluation | None, t: float) -> None:
        assert self.plan_gen is not None
        try:
            cand = next(self.plan_gen) if ev is None else self.plan_gen.send(ev)
        except StopIteration as stop:
            final, reason = stop.value
            self._finish(final, reason, t)
            return
        self.target = self.clamp(cand)
        self.phase = SETTLING

    def _finish(self, final: float, reason: str, t: float) -> None:
        """The plan has ended on ``final``: an edge with the power rising outward is
        expanded (``expand``) or reported (``at_bound``); anything else has converged."""
        final = self.clamp(final)
        side = self.edge(final)
        if side is not None and self.edge_evidence(side):
            if self.expand(side):
                edge = self.hi if side == "upper" else self.lo
                inner = max(self.lo, min(self.hi, final))
                lo, hi = (inner, self.hi) if side == "upper" else (self.lo, inner)
                self.bracket = (lo, hi)
                guess = 0.5 * (lo + hi) if hi - lo > 2 * self.cfg.min_step else edge
                self.plan_gen = self.plan(lo, guess, hi)
                self._next(None, t)
                return
            self.at_bound = side
            final = self.hi if side == "upper" else self.lo
            reason = (
                f"the optimum lies beyond the {side} bound ({final:.3g} rad/s): widen the bracket"
            )
        else:
            self.at_bound = None
        self.target = final
        self.optimum = final
        self.optimum_power = self._power_near(final)
        self.done = True
        self.reason = reason
        self.phase = DONE
        if self.at_bound is None:
            self.converged_at(t, final, self.optimum_power)
        if self.cfg.track and self.kind not in ("fixed", "parabolic-as-printed"):
            self.start_tracking(t)  # (the misprint's demonstration runs Appendix A alone)

    def _power_near(self, v: float) -> float | None:
        if not self.evaluations:
            return None
        near = min(self.evaluations, key=lambda ev: (abs(ev.candidate - v), -ev.t))
        return near.power if is_finite(near.power) else None

    def curvature_hint(self) -> float | None:
        """d²p/dw² near the optimum, if the plan knows it (for the tracker's Newton steps)."""
        return None

    def start_tracking(self, t: float) -> None:
        from sessions.seekers.tracker import Tracker

        assert self.optimum is not None
        self.tracker = Tracker(self, self.optimum, self.curvature_hint(), t, self.rows)
        self.tracking = True

    def drive(self, f: Callable[[float], float], stderr: float = 0.0) -> float:
        """Run the plan offline against a function p = f(γ), one evaluation a unit of time,
        and return the setpoint it ends on: the search logic alone, without a machine. For
        tests and what-if studies."""
        self.plan_gen = self.plan(self.lo, self.clamp(self.cfg.bracket[1]), self.hi)
        self._next(None, 0.0)
        n = 0
        tracking, self.cfg = self.cfg.track, self.cfg.model_copy(update={"track": False})
        try:
            while not self.done and n < 10 * self.cfg.max_evaluations:
                n += 1
                ev = Evaluation(float(n), self.target, f(self.target), stderr)
                self.evaluations.append(ev)
                self._next(ev, float(n))
        finally:
            self.cfg = self.cfg.model_copy(update={"track": tracking})
        return self.target

    def update(self, t: float, q: float, p: float, e: float) -> Evaluation | None:
        ev = None
        phase = self.phase
        x = self.wd + e if self.velocity_abscissa else self.wd  # where p was measured
        if t >= self.delay:
            self.rows.add(t, q, p, x, self.wd)
        if phase == MEASURING:
            if self.averager.add(t, q, p, x):
                m = self.averager.result(t)
                ev = Evaluation(t, m.velocity, m.mean, m.stderr)
                self.evaluations.append(ev)
                self._next(ev, t)
        elif phase == DONE:
            tracker = self.tracker
            if tracker is not None:
                ev = tracker.update(t)
                self.target = tracker.target(t + self.dt)
        elif t >= self.delay:
            if abs(e) <= self.e1 and abs(self.wd - self.target) <= self.e2:
                self.phase = MEASURING
                self.averager.start(t, q)
                self.averager.add(t, q, p, x)
            else:
                self.phase = SETTLING
        self.filter.step(self.target)
        f = self.filter
        self.wd, self.ad, self.jd = f.wd, f.ad, f.jd
        return ev

    def hold(self, t: float) -> None:
        self.filter.step(self.target)
        self._copy_reference()
