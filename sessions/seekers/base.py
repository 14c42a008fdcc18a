"""The one online interface every seeker offers the loop, and what a session can read of it.

Each loop period the loop reads the reference ``wd, ad, jd`` (attributes, for speed), computes
its control, then calls ``tell(t, q, p, e)`` with the power it measured; that advances the
seeker one period. ``tell`` returns an :class:`Evaluation` when a candidate has just been
measured. ``progress()`` gives plain data (bracket, candidates with measured power, best so
far, done) for events, the store and the dashboard.

:class:`FilteredSeeker` is the common machinery of the numerical seekers (Appendix A): a
candidate γ is fed through the trajectory filter (32)/(33); after the start delay the seeker
waits until |e| ≤ ē1 and |wd - γ| ≤ ē2 (Step 3), averages p (see :mod:`.averaging`), and
hands the measurement to its *plan*, a generator that yields candidates and receives
evaluations. A plan reads like the algorithm it implements.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from dataclasses import dataclass, field

from sessions.codes import DELAY, DONE, MEASURING, PHASES, SETTLING
from sessions.config import SeekerConfig
from sessions.filters import TrajectoryFilter
from sessions.seekers.averaging import PowerAverager


@dataclass(frozen=True, slots=True)
class Evaluation:
    """One measured candidate: when the measurement ended, the velocity it was measured at
    (the mean of wd over the window), the mean p and its standard error."""

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


Plan = Generator[float, Evaluation, tuple[float, str]]


class Seeker:
    """Base: holds the reference outputs and the record every seeker keeps."""

    kind = "seeker"
    __slots__ = (
        "cfg", "dt", "v_lo", "v_hi", "wd", "ad", "jd", "target", "phase", "done",
        "reason", "evaluations", "bracket", "bracket0",
    )  # fmt: skip

    def __init__(self, cfg: SeekerConfig, dt: float, max_velocity: float) -> None:
        self.cfg = cfg
        self.dt = dt
        # Never ask for less than a crawl or more than 95 % of the machine's limit.
        self.v_lo = min(cfg.min_step, cfg.bracket[0])
        self.v_hi = 0.95 * max_velocity
        self.wd = self.ad = self.jd = 0.0
        self.target = cfg.bracket[1]
        self.phase = DELAY
        self.done = False
        self.reason = ""
        self.evaluations: list[Evaluation] = []
        self.bracket = (cfg.bracket[0], cfg.bracket[2])
        self.bracket0 = self.bracket

    def clamp(self, v: float) -> float:
        return min(max(v, self.v_lo), self.v_hi)

    def begin(self, w0: float) -> None:
        raise NotImplementedError

    def tell(self, t: float, q: float, p: float, e: float) -> Evaluation | None:
        raise NotImplementedError

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
        )


class FilteredSeeker(Seeker):
    """Candidates through the trajectory filter, measured by Step 3, chosen by ``plan()``."""

    __slots__ = ("filter", "averager", "plan_gen", "e1", "e2", "delay")

    def __init__(self, cfg: SeekerConfig, dt: float, max_velocity: float) -> None:
        super().__init__(cfg, dt, max_velocity)
        self.filter = TrajectoryFilter(cfg.filter.order, cfg.filter.pole, dt)
        self.averager = PowerAverager(cfg.window, cfg.max_window, cfg.quiet)
        self.e1 = cfg.e1
        self.e2 = cfg.e2
        self.delay = cfg.start_delay
        self.plan_gen: Plan | None = None

    def plan(self) -> Plan:
        raise NotImplementedError

    def begin(self, w0: float) -> None:
        """Start from the machine's current velocity: wd = w0, ad = jd = 0 (bumpless)."""
        self.filter.reset(w0)
        self._copy_reference()
        self.plan_gen = self.plan()
        self._next(None)
        self.phase = DELAY

    def _copy_reference(self) -> None:
        f = self.filter
        self.wd, self.ad, self.jd = f.wd, f.ad, f.jd

    def _next(self, ev: Evaluation | None) -> None:
        assert self.plan_gen is not None
        try:
            cand = next(self.plan_gen) if ev is None else self.plan_gen.send(ev)
        except StopIteration as stop:
            final, reason = stop.value
            self.target = self.clamp(final)
            self.done = True
            self.reason = reason
            self.phase = DONE
            return
        self.target = self.clamp(cand)
        self.phase = SETTLING

    def drive(self, f: Callable[[float], float], stderr: float = 0.0) -> float:
        """Run the plan offline against a function p = f(γ), one evaluation a unit of time,
        and return the setpoint it ends on: the search logic alone, without a machine. For
        tests and what-if studies."""
        self.plan_gen = self.plan()
        self._next(None)
        n = 0
        while not self.done and n < 10 * self.cfg.max_evaluations:
            n += 1
            ev = Evaluation(float(n), self.target, f(self.target), stderr)
            self.evaluations.append(ev)
            self._next(ev)
        return self.target

    def tell(self, t: float, q: float, p: float, e: float) -> Evaluation | None:
        ev = None
        phase = self.phase
        if phase == MEASURING:
            if self.averager.add(t, q, p, self.wd):
                m = self.averager.result(t)
                # the velocity p was measured at: the filter may still be closing in on γ
                ev = Evaluation(t, m.velocity, m.mean, m.stderr)
                self.evaluations.append(ev)
                self._next(ev)
        elif phase != DONE:
            if t >= self.delay:
                if abs(e) <= self.e1 and abs(self.wd - self.target) <= self.e2:
                    self.phase = MEASURING
                    self.averager.start(t, q)
                    self.averager.add(t, q, p, self.wd)
                else:
                    self.phase = SETTLING
        self.filter.step(self.target)
        f = self.filter
        self.wd, self.ad, self.jd = f.wd, f.ad, f.jd
        return ev
