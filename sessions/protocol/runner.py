"""The protocol runner: the loop's reference generator, phase after phase.

It offers the loop what a seeker offers (``wd, ad, jd``, ``target``, ``begin``, ``tell``) and
wraps the session's seeker: during a seek phase the reference is the seeker's own, untouched
(a session without a protocol is one seek phase, so it runs exactly as the seeker alone); in
every other segment the runner feeds its own γ through the same trajectory filter (32)/(33)
(:mod:`sessions.filters`) behind the same controller and limits. Switching from the seeker's
reference to the runner's is bumpless: the runner's filter takes the seeker's wd, ad, jd.

Per period (:meth:`ProtocolRunner.tell`, run in the 1 kHz loop): the measured power and error
in, the next period's reference out; a segment change happens between periods and is the only
thing that allocates (a :class:`~sessions.protocol.stage.Stage`, left in ``changed`` for that
period and kept in ``log``).

Every session ends with a controlled stop at rest: the last phase is a cool-down, or the
runner adds its own stop (γ down to 0 at STOP_DECELERATION, then rest). :meth:`wind_down`
(the worker's controlled stop, the duration reached) goes to that stop at once. ``finished``
turns true once the handle has stayed at rest: only then does the worker release the torque.
"""

from __future__ import annotations

import math

from sessions.config import FilterConfig, SessionConfig
from sessions.filters import TrajectoryFilter
from sessions.protocol import seeking
from sessions.protocol.config import (
    REST_HOLD,
    REST_VELOCITY,
    STOP,
    Protocol,
    Seek,
    Train,
    phase_label,
)
from sessions.protocol.plan import (
    HOLD,
    MODES,
    RAMP,
    REST,
    SEEK,
    TRACK,
    PhasePlan,
    Segment,
    plan_phase,
    stop_plan,
)
from sessions.protocol.stage import Stage
from sessions.seekers import Evaluation, Seeker


def implicit_protocol(duration: float) -> Protocol:
    """A session without a protocol: one seek phase for its whole duration."""
    seek = Seek.model_construct(kind="seek", name="", duration=duration, until_converged=False,
                                hold=0.0)  # fmt: skip
    return Protocol.model_construct(name="", phases=(seek,))


def adopt(f: TrajectoryFilter, wd: float, ad: float, jd: float) -> None:
    """Set the filter's states so that it outputs wd, ad, jd (and no third derivative): the
    inverse of ad = p (yₙ₋₁ − yₙ), jd = p² (yₙ₋₂ − 2yₙ₋₁ + yₙ) and the next difference."""
    p = f.pole
    y_n = wd
    y_n1 = wd + ad / p
    y_n2 = jd / (p * p) + 2.0 * y_n1 - y_n
    y_n3 = 3.0 * y_n2 - 3.0 * y_n1 + y_n
    if f.order == 4:
        f.y1, f.y2, f.y3, f.y4 = y_n3, y_n2, y_n1, y_n
    else:
        f.y1, f.y2, f.y3 = y_n2, y_n1, y_n
    f.wd, f.ad, f.jd = wd, ad, jd


def towards_rest(f: TrajectoryFilter) -> float:
    """Make the filter's output move only towards rest from now on while its input does (a
    stop never speeds the handle up), changing no state it need not: each lag's state is
    pulled to no farther from 0 than the next lag's (and not past 0). A lag whose input moves
    monotonically towards 0 from no farther out than its own state moves so itself, so by
    induction down the cascade wd does. Returns the first lag's state, where the stop's ramp
    of γ must start. A reference already falling in order is left as it was (bumpless); one
    still rising loses its acceleration at once (a step of J·ad in the feedforward)."""
    ys = [f.y1, f.y2, f.y3, f.y4][: f.order]
    s = 1.0 if ys[-1] >= 0.0 else -1.0
    for i in range(f.order - 2, -1, -1):  # from the lag before wd out to the first
        ys[i] = s * min(max(s * ys[i], 0.0), s * ys[i + 1])
    if f.order == 4:
        f.y1, f.y2, f.y3, f.y4 = ys
    else:
        f.y1, f.y2, f.y3 = ys
    p, n = f.pole, f.order
    f.ad = p * (ys[n - 2] - ys[n - 1])
    f.jd = p * p * (ys[n - 3] - 2.0 * ys[n - 2] + ys[n - 1])
    return ys[0]


class ProtocolRunner:
    """Runs ``cfg.protocol`` (or one seek phase) around ``seeker``."""

    kind = "protocol"
    __slots__ = (
        "protocol", "phases", "seeker", "dt", "bracket", "filt", "filter", "max_velocity",
        "wd", "ad", "jd", "target", "effort", "k", "k0", "k_end", "mode", "gamma0", "slope",
        "effort0", "effort_slope", "phase", "plan", "seg_i", "phase_k0", "seek_begun",
        "until_converged", "seek_hold", "pending", "stopping", "still", "still_need", "k_min",
        "finished", "changed", "log", "work_velocity", "open_ended",
    )  # fmt: skip

    def __init__(self, cfg: SessionConfig, seeker: Seeker) -> None:
        self.protocol = (
            cfg.protocol if cfg.protocol is not None else implicit_protocol(cfg.duration)
        )
        self.phases = self.protocol.phases
        # no protocol: the seek lasts until the worker winds it down (the duration reached),
        # so a simulation for the duration is the seeker's alone, to its last sample
        self.open_ended = cfg.protocol is None
        if self.open_ended:  # the session's end is the seek's: its track phase ends on θ there
            seeker.ends_at = cfg.duration
        self.seeker = seeker
        self.dt = cfg.dt
        self.bracket = cfg.seeker.bracket
        self.filt: FilterConfig = cfg.seeker.filter
        self.filter = TrajectoryFilter(self.filt.order, self.filt.pole, cfg.dt)
        self.max_velocity = cfg.machine.max_velocity
        self.wd = self.ad = self.jd = 0.0
        self.target = 0.0
        self.effort = 1.0
        self.k = 0  # the period the current reference is for
        self.k0 = self.k_end = 0  # the segment's first period, and the first after it
        self.mode = HOLD
        self.gamma0 = self.slope = self.effort0 = self.effort_slope = 0.0
        self.phase = -1
        self.plan = PhasePlan(())
        self.seg_i = 0
        self.phase_k0 = 0
        self.seek_begun = False
        self.until_converged = False
        self.seek_hold = 0
        self.pending = False  # end the segment before the next period
        self.stopping = False
        self.still = self.still_need = self.k_min = 0
        self.finished = False
        self.changed: Stage | None = None
        self.log: list[Stage] = []
        self.work_velocity: float | None = None

    # -- the loop's interface --------------------------------------------------------------
    @property
    def seeking(self) -> bool:
        """The target is the seeker's (seeking or tracking), not a protocol's own velocity."""
        return self.mode in (SEEK, TRACK)

    def begin(self, w0: float) -> None:
        """Start at the machine's velocity (bumpless), in the first phase."""
        self.filter.reset(w0)
        self.wd, self.ad, self.jd = w0, 0.0, 0.0
        self.target = w0
        self.k = 0
        self._enter_phase(0, 0)

    def tell(self, t: float, q: float, p: float, e: float) -> Evaluation | None:
        """One period: what was measured in it in, the next period's reference out."""
        self.changed = None
        j = self.k + 1
        self.k = j
        if j >= self.k_end or self.pending:
            self._next(j)
        mode = self.mode
        if mode == SEEK:
            s = self.seeker
            ev = s.tell(t, q, p, e)
            self.wd, self.ad, self.jd, self.target = s.wd, s.ad, s.jd, s.target
            if self.until_converged and s.done:
                self._converged(j)
            return ev
        ev = None
        if mode == TRACK:
            s = self.seeker
            ev = s.tell(t, q, p, self.wd + e - s.wd)  # its error against its own reference
            self.target = s.target
        elif mode == RAMP:
            x = j - self.k0
            self.target = self.gamma0 + self.slope * x
            self.effort = self.effort0 + self.effort_slope * x
        elif mode == REST:
            w = self.wd + e
            self.still = self.still + 1 if -REST_VELOCITY < w < REST_VELOCITY else 0
            if j >= self.k_min and self.still >= self.still_need:
                self.pending = True
        f = self.filter
        f.step(self.target)
        self.wd, self.ad, self.jd = f.wd, f.ad, f.jd
        return ev

    def wind_down(self) -> None:
        """Go to the controlled stop at rest now (a stop asked for, the duration reached)."""
        if not self.stopping:
            self.stopping = True
            # (already stopping, or at rest at the end of a cool-down: nothing to cut short)
            self.pending = self.phase_kind != STOP and self.mode != REST

    @property
    def phase_kind(self) -> str:
        return self.phases[self.phase].kind if self.phase < len(self.phases) else STOP

    # -- between periods -------------------------------------------------------------------
    def _converged(self, j: int) -> None:
        """The seeker has converged: the seek phase ends after its hold."""
        self.until_converged = False
        self.k_end = min(self.k_end, j + self.seek_hold)
        self._tell_seek_end()

    def _next(self, j: int) -> None:
        """The segment is over (or a stop was asked for): the next one begins at period j."""
        self.pending = False
        if self.stopping and self.phase_kind != STOP and self.mode != REST:
            self._enter_stop(j)
            return
        self.seg_i += 1
        if self.seg_i < len(self.plan.segments):
            self._enter_segment(j)
        elif self.phase + 1 < len(self.phases) and not self.stopping:
            self._enter_phase(self.phase + 1, j)
        elif self.phase_kind == STOP or self.protocol.ends_at_rest:
            self._finish(j)  # the closing rest is over: the handle is still (or its grace ran out)
        else:
            self._enter_stop(j)

    def _enter_phase(self, i: int, j: int) -> None:
        ph = self.phases[i]
        self.phase = i
        self.phase_k0 = j
        if isinstance(ph, Train):
            self.work_velocity = self._train_velocity(ph)
        if isinstance(ph, Seek):
            self.until_converged = ph.until_converged
            self.seek_hold = max(0, round(ph.hold / self.dt))
        self.plan = plan_phase(ph, self.bracket, self.wd, self.filt)
        self.seg_i = 0
        self._enter_segment(j)

    def _enter_stop(self, j: int) -> None:
        self.phase = len(self.phases)
        self.phase_k0 = j
        self.plan = stop_plan(self.wd)
        self.seg_i = 0
        self._enter_segment(j)
        f = self.filter
        start = towards_rest(f)
        self.ad, self.jd = f.ad, f.jd
        if self.mode == RAMP:  # γ from the first lag's state down to 0, no farther out
            self.gamma0 = self.target = start
            self.slope = -start / (self.k_end - self.k0)

    def _finish(self, j: int) -> None:
        """At rest: hold γ = 0 until the worker releases the torque."""
        self.finished = True
        self.mode = HOLD
        self.target = 0.0
        self.effort = 0.0
        self.k0, self.k_end = j, 2**62

    def _tell_seek_end(self) -> None:
        """Tell the seeker when a protocol's seek phase ends, unless the next phase follows
        its optimum on: its track phase then ends on the optimum, the one stored and trained
        at (without a protocol the session's duration, told at the start)."""
        if self.open_ended:
            return
        nxt = self.phases[self.phase + 1] if self.phase + 1 < len(self.phases) else None
        tracked = isinstance(nxt, Train) and nxt.track and nxt.velocity is None
        self.seeker.ends_at = math.inf if tracked else self.k_end * self.dt

    def _train_velocity(self, ph: Train) -> float:
        if ph.velocity is not None:
            return ph.velocity
        found = seeking.optimum(self.seeker) if self.seek_begun else None
        return found if found is not None else self.bracket[1]

    def _gamma(self, seg: Segment) -> float:
        """A segment's velocity; the work velocity (WORK) is the optimum as it is now."""
        if not math.isnan(seg.gamma):
            return seg.gamma
        if self.seek_begun and seeking.can_track(self.seeker) and self._tracking_allowed():
            return self.seeker.target
        return self.work_velocity if self.work_velocity is not None else self.bracket[1]

    def _tracking_allowed(self) -> bool:
        ph = self.phases[self.phase] if self.phase < len(self.phases) else None
        return isinstance(ph, Train) and ph.track and ph.velocity is None

    def _enter_segment(self, j: int) -> None:
        seg = self.plan.segments[self.seg_i]
        if self.mode == SEEK and seg.mode != SEEK:  # the runner's filter takes over, bumpless
            adopt(self.filter, self.wd, self.ad, self.jd)
        mode = seg.mode
        if mode == TRACK and not (
            self.seek_begun and seeking.can_track(self.seeker) and self._tracking_allowed()
        ):
            mode = HOLD  # nothing to track: hold the optimum found
        n = max(1, round(seg.duration / self.dt))
        self.k0, self.k_end = j, j + n
        if self.open_ended and mode == SEEK:
            self.k_end = 2**62
        self.mode = mode
        self.effort = seg.effort
        gamma = self._gamma(seg)
        if mode == SEEK:
            s = self.seeker
            if not self.seek_begun:
                s.begin(self.wd)
                self.seek_begun = True
            self.wd, self.ad, self.jd = s.wd, s.ad, s.jd  # the seeker's reference, as it began
            self.target = gamma = s.target
            self.effort = 1.0
            self._tell_seek_end()
        elif mode == TRACK:  # the protocol goes on: the track phase keeps learning
            self.seeker.ends_at = math.inf
        elif mode == RAMP:
            self.gamma0 = self.wd
            self.slope = (gamma - self.wd) / n
            self.target = self.gamma0
            self.effort0 = seg.effort
            end = seg.effort if seg.effort_end is None else seg.effort_end
            self.effort_slope = (end - seg.effort) / n
        elif mode == REST:
            self.target = 0.0
            self.still = 0
            self.still_need = max(1, round(REST_HOLD / self.dt))
            self.k_min = j + round(seg.minimum / self.dt)
        else:
            self.target = gamma
        self._report(seg, mode, j, gamma)

    def _report(self, seg: Segment, mode: int, j: int, gamma: float) -> None:
        dt, i = self.dt, self.phase
        nxt = self.phases[i + 1] if i + 1 < len(self.phases) else None
        plan = self.plan
        kind = self.phase_kind
        last = kind == STOP or (i == len(self.phases) - 1 and self.protocol.ends_at_rest)
        if i < len(self.phases):
            ph = self.phases[i]
            name = phase_label(ph, i)
            intervals = getattr(ph, "intervals", getattr(ph, "count", 0))
        else:
            name, intervals = STOP, 0
        profile = ()
        if plan.profile is not None and self.seg_i == 0:
            profile = tuple((s.velocity, s.start, s.settled, s.end) for s in plan.profile.steps)
        stage = Stage(
            phase=i, kind=kind, name=name, segment=self.seg_i, role=seg.role, mode=MODES[mode],
            start=j * dt, end=(j + round(seg.duration / dt)) * dt, phase_start=self.phase_k0 * dt,
            phase_end=self.phase_k0 * dt + plan.duration, velocity=gamma, effort=self.effort,
            interval=seg.interval, intervals=intervals,
            next_kind=nxt.kind if nxt is not None else (None if last else STOP),
            next_name=phase_label(nxt, i + 1) if nxt is not None else None,
            optimum=seeking.optimum(self.seeker) if self.seek_begun else None, profile=profile,
            at_bound=seeking.at_bound(self.seeker) if self.seek_begun else None,
        )  # fmt: skip
        self.changed = stage
        self.log.append(stage)
