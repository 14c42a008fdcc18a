"""The running session's seeker as the dashboard shows it: every measured candidate, the
current bracket, the best so far, the target and how far along the search is.

Built from the ``seeker`` event frames of the LiveHub (candidate, power, target, done; and
``bracket_lo``, ``bracket_hi``, ``fraction`` when the worker sends them) and, for a session
already running when the dashboard starts, the evaluations in the store. Without the worker's
bracket, the bracket is the nearest measured candidates on either side of the best (the
interval a bracketing search keeps), within the session's initial bracket; the fraction is
the seeker's own rule (``sessions.seekers.base.Seeker.fraction``) applied to it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import viser

from sessions.config import SessionConfig
from webui.charts import seeker_chart, seeker_data, seeker_range, seeker_scales, seeker_x_range
from webui.escape import Markdown, MarkdownBox, md, md_lines


@dataclass
class SeekerProgressView:
    session_id: int | None = None
    kind: str = ""
    bracket0: tuple[float, float] | None = None
    threshold: float = 0.1
    evaluations: list[tuple[float, float]] = field(default_factory=list)  # (candidate, power)
    target: float | None = None
    done: bool = False
    reported_bracket: tuple[float, float] | None = None
    reported_fraction: float | None = None
    seen: set[float] = field(default_factory=set)  # session times of evaluations counted
    version: int = 0  # bumped on every change, so views redraw only when needed

    def reset(self, session_id: int | None, cfg: SessionConfig | None) -> None:
        self.session_id = session_id
        self.evaluations = []
        self.seen = set()
        self.target = None
        self.done = False
        self.reported_bracket = None
        self.reported_fraction = None
        if cfg is not None:
            s = cfg.seeker
            self.kind = s.kind
            self.bracket0 = (float(s.bracket[0]), float(s.bracket[2]))
            self.threshold = float(s.threshold)
            self.target = float(s.bracket[1]) if s.kind != "fixed" else s.setpoint
        else:
            self.kind, self.bracket0 = "", None
        self.version += 1

    def add(self, frame: dict[str, Any]) -> None:
        """One ``seeker`` event frame, or a stored evaluation as a dict with ``session_t``
        (the same evaluation seen both ways counts once)."""
        at = frame.get("session_t")
        if at is not None:
            key = round(float(at), 4)
            if key in self.seen:
                return
            self.seen.add(key)
        c, p = frame.get("candidate"), frame.get("power")
        if c is not None and p is not None and math.isfinite(c) and math.isfinite(p):
            self.evaluations.append((float(c), float(p)))
        if frame.get("target") is not None:
            self.target = float(frame["target"])
        self.done = bool(frame.get("done", self.done))
        lo, hi = frame.get("bracket_lo"), frame.get("bracket_hi")
        if lo is not None and hi is not None:
            self.reported_bracket = (float(lo), float(hi))
        if frame.get("fraction") is not None:
            self.reported_fraction = float(frame["fraction"])
        self.version += 1

    @property
    def best(self) -> tuple[float, float] | None:
        return max(self.evaluations, key=lambda e: e[1], default=None)

    @property
    def bracket(self) -> tuple[float, float] | None:
        if self.reported_bracket is not None:
            return self.reported_bracket
        best = self.best
        if best is None:
            return self.bracket0
        lo, hi = self.bracket0 if self.bracket0 is not None else (-math.inf, math.inf)
        below = [c for c, _ in self.evaluations if lo <= c < best[0]]
        above = [c for c, _ in self.evaluations if hi >= c > best[0]]
        left = max(below) if below else lo
        right = min(above) if above else hi
        if not (math.isfinite(left) and math.isfinite(right)):
            return None
        return (left, right)

    @property
    def fraction(self) -> float:
        if self.done:
            return 1.0
        if self.reported_fraction is not None:
            return min(max(self.reported_fraction, 0.0), 1.0)
        if self.bracket0 is None or self.kind in ("fixed", "perturbation"):
            return 0.0
        b = self.bracket
        w0 = self.bracket0[1] - self.bracket0[0]
        w = max(b[1] - b[0], 1e-9) if b is not None else w0
        goal = min(self.threshold, w0)
        if w0 <= goal:
            return 0.0
        return min(max(math.log(w0 / w) / math.log(w0 / goal), 0.0), 0.99)

    def describe(self) -> Markdown:
        """Markdown: seeker, evaluations, bracket, best, target, or the optimum when done."""
        if self.session_id is None and not self.evaluations:
            return md("Seeker: no session yet.")
        lines = [md("Seeker **{}** · {} evaluations", self.kind or "?", len(self.evaluations))]
        b = self.bracket
        if b is not None:
            lines.append(md("Bracket: [{:.3f}, {:.3f}] rad/s", b[0], b[1]))
        best = self.best
        if best is not None:
            lines.append(md("Best so far: {:.3f} rad/s at {:.3f} W", best[0], best[1]))
        if self.done and self.target is not None:
            lines.append(md("**Optimum: {:.3f} rad/s** (converged)", self.target))
        elif self.target is not None:
            lines.append(md("Target: {:.3f} rad/s", self.target))
        return md_lines(lines)


class SeekerPanel:
    """The seeker's progress bar, its state in words and the power-vs-velocity chart (one
    browser's: the bar is an input element, which only its own browser may hold)."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self.progress = gui.add_progress_bar(0.0)
        self.text = MarkdownBox(gui, md("Seeker: no session yet."))
        self.chart = seeker_chart(gui)
        self._version = -1
        self._ranges: tuple[tuple[float, float], ...] | None = None

    def render(self, view: SeekerProgressView) -> None:
        if view.version == self._version:
            return
        self._version = view.version
        self.progress.value = round(100.0 * view.fraction, 1)
        self.text.show(view.describe())
        bracket = view.bracket
        wanted = (seeker_range(view.evaluations), seeker_x_range(view.evaluations, bracket))
        if wanted != self._ranges:
            self._ranges = wanted
            self.chart.scales = seeker_scales(view.evaluations, bracket)
        self.chart.data = seeker_data(view.evaluations, bracket, view.best)
