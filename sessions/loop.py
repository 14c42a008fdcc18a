"""The control loop: one ``step()`` per period, shared by simulation and the real-time worker.

Per period (ros2_control's read → update → write, the read and write being the caller's):
    e = w - wd (3); u = controller (7) or (23); limits; τ or τ̂ (28); p (4) or (31);
    W += τ w dt (5); the seeker is told p and advances the reference to the next period.
The reference comes from the protocol runner (:mod:`sessions.protocol.runner`), which wraps the
seeker: a session without a protocol is one seek phase, whose reference is the seeker's own.
The loop knows nothing of clocks, processes or the web: time is the step count × dt.
Each step leaves its telemetry row in ``row`` (channels of :mod:`sessions.telemetry`), plain
floats for whoever records them (simulation arrays, the worker's shared-memory ring).

The power the seeker is told: p = τ̂·w^ρ at the measured velocity (``measure = "velocity"``,
the default), or the paper's (13) p = τ̂·wd^ρ (``measure = "desired"``); the surrogate (31) is
evaluated at the same abscissa. Near the top p is flat, so the few per cent by which w lags wd
while a candidate settles are worth more than p varies there (docs/engine.md).

Non-finite values: a NaN or infinite torque command is never returned (the step returns 0 and
sets ``fault``), and a non-finite power or error never reaches a target (the seeker holds, see
:mod:`sessions.seekers.base`); ``fault`` names the first such value, so the worker can zero
the torque and end the session with that reason.
"""

from __future__ import annotations

import math

from sessions.config import SessionConfig
from sessions.controllers import make_controller
from sessions.limits import Limits
from sessions.objective import modified_power, surrogate_power
from sessions.passivity import PassivityMonitor
from sessions.protocol.runner import ProtocolRunner
from sessions.seekers import Evaluation, make_seeker
from sessions.stability import deadbeat_gain
from sessions.telemetry import INDEX, WIDTH
from sessions.truth import RegretMeter, Truth


class Loop:
    __slots__ = (
        "cfg", "dt", "k", "controller", "seeker", "reference", "limits", "passivity", "rho",
        "surrogate", "at_w", "row", "flags", "evaluation", "peak_power", "power_sum", "stage",
        "target_min", "target_max", "fault", "regret_meter", "_calls",
    )  # fmt: skip

    def __init__(
        self, cfg: SessionConfig, *, as_printed: bool = False, truth: Truth | None = None
    ) -> None:
        m = cfg.machine
        self.cfg = cfg
        self.dt = cfg.dt
        self.k = 0
        self.controller = make_controller(cfg.controller, m.inertia)
        self.seeker = make_seeker(cfg.seeker, self.dt, m.max_velocity, as_printed=as_printed)
        self.reference = ProtocolRunner(cfg, self.seeker)  # wd, ad, γ: the seeker's in a seek
        self.limits = Limits(m.max_torque, m.max_velocity, deadbeat_gain(m.inertia, self.dt))
        self.passivity = PassivityMonitor(m.passivity_c2)
        self.rho = cfg.seeker.rho
        self.surrogate = cfg.seeker.objective == "surrogate"
        self.at_w = cfg.seeker.measure == "velocity"
        self.row: tuple[float, ...] = (0.0,) * WIDTH
        self.flags = 0
        self.evaluation: Evaluation | None = None
        self.peak_power = 0.0
        self.power_sum = 0.0
        self.stage = 0  # the protocol phase whose reference the last step used
        self.target_min = math.inf
        self.target_max = -math.inf
        self.fault: str | None = None
        self.regret_meter: RegretMeter | None = None
        if truth is not None:
            self.attach_truth(truth)
        # bound once: step() runs every period
        self._calls = (
            self.controller.command, self.limits.apply, self.controller.commit,
            self.passivity.add, self.reference.tell,
        )  # fmt: skip

    def attach_truth(self, truth: Truth) -> None:
        """The simulated person's truth (simulation, sim machine): enables ``regret``."""
        self.regret_meter = RegretMeter(truth, self.rho, self.cfg.seeker.start_delay, self.dt)

    def begin(self, q0: float, w0: float) -> None:
        """Start at the machine's current state: the reference starts at w0, u(t0) = 0 for RISE."""
        ref = self.reference
        ref.begin(w0)
        self.controller.begin(w0 - ref.wd, ref.ad)
        self.row = (0.0, q0, w0, ref.wd, ref.ad, 0.0, 0.0, 0.0, 0.0, ref.target)
        self.stage = ref.phase

    def step(
        self, q: float, w: float, tau_measured: float = math.nan, held: float | None = None
    ) -> float:
        """One period: the measured state in, the motor torque to apply out. ``held``: this
        period has passed already (the worker missed it) and the drive applied ``held`` over
        it; the step accounts for it with that torque (docs/engine.md, missed periods)."""
        dt = self.dt
        t = self.k * dt
        command, apply, commit, add_work, tell = self._calls
        ref = self.reference
        wd = ref.wd
        ad = ref.ad
        self.stage = ref.phase
        e = w - wd  # (3)
        u_cmd = command(e, ad, tau_measured)
        u = apply(u_cmd, w)
        if held is not None:  # the observer (28) and the record see what was applied
            u = u_cmd = held
        tau = commit(e, ad, tau_measured, u, u_cmd, dt)
        x = w if self.at_w else wd
        p = surrogate_power(x) if self.surrogate else modified_power(tau, x, self.rho)
        pm = tau * w
        if u - u == 0.0 and p - p == 0.0 and pm - pm == 0.0:  # all finite (nan - nan is nan)
            work = add_work(tau, w, dt)
            self.power_sum += pm
            if pm > self.peak_power:
                self.peak_power = pm
        else:
            u = self._nonfinite(u, tau, p, w)
            work = self.passivity.work
        self.evaluation = tell(t, q, p, e)
        target = ref.target
        if ref.seeking:  # the seeker's commanded extremes (a warm-up or the wind-down's aren't)
            if target < self.target_min:
                self.target_min = target
            if target > self.target_max:
                self.target_max = target
        if self.regret_meter is not None:
            self.regret_meter.add(t, w)
        self.row = (t, q, w, wd, ad, u, tau, p, work, target)
        self.flags = self.limits.flags
        self.k += 1
        return u

    def wind_down(self) -> None:
        """Bring the handle to rest under control (the protocol's closing stop), from now."""
        self.reference.wind_down()

    @property
    def finished(self) -> bool:
        """The protocol is over and the handle at rest: the torque may be released."""
        return self.reference.finished

    def _nonfinite(self, u: float, tau: float, p: float, w: float) -> float:
        """Name the first non-finite value; never return a non-finite torque."""
        if self.fault is None:
            if not math.isfinite(w):
                what = f"velocity w = {w}"
            elif not math.isfinite(tau):
                what = f"torque estimate τ = {tau}"
            elif not math.isfinite(u):
                what = f"torque command u = {u}"
            else:
                what = f"power p = {p}"
            self.fault = f"non-finite {what}"
        return u if math.isfinite(u) else 0.0

    def value(self, channel: str) -> float:
        """The last step's value of one telemetry channel."""
        return self.row[INDEX[channel]]

    @property
    def elapsed(self) -> float:
        return self.k * self.dt

    @property
    def mean_power(self) -> float:
        """Mean mechanical power τ·w (τ̂·w under RISE) so far, W."""
        return self.power_sum / self.k if self.k else 0.0

    @property
    def regret(self) -> float | None:
        """Regret against the person's truth so far; None without one (real hardware)."""
        return self.regret_meter.regret if self.regret_meter is not None else None
