"""Appendix A of the paper: successive parabolic interpolation, as published, Step 7 corrected.

Steps 1-4 measure p at γ1, γ2, γ3. Step 5 puts the next candidate at the vertex of the
parabola through the three points:
    γ4 = γ2 - ½ g1/g2                                                           (34)
    g1 = (γ2-γ1)²[p(γ2)-p(γ3)] - (γ2-γ3)²[p(γ2)-p(γ1)]                          (35)
    g2 = (γ2-γ1)[p(γ2)-p(γ3)] - (γ2-γ3)[p(γ2)-p(γ1)]                            (36)
Step 7 keeps the three points that still bracket the maximum. The paper prints its two
outcomes swapped (see docs/erratum.md); the correct rule is
    (p4 ≥ p2 and γ4 < γ2) or (p2 ≥ p4 and γ4 > γ2)  →  {γ1, γ2, γ4},  else {γ2, γ3, γ4}.
Step 8 stops when γ3 - γ1 < threshold.

Not in the paper, guards a practical implementation needs: a vertex within min_step of a
measured point ends the search there if the measurements pin the vertex down to better than
min_step, else it is moved min_step away from that point into the wider side of the bracket (a
repeated point teaches nothing; Numerical Recipes' minimum step); the search stops at the best
point when
there is no such room, when the three points are no longer concave (the vertex would be a
minimum: noise near the optimum), or when the evaluation budget is spent. The setpoint it then
holds is the least-squares peak of the measurements near the top (:mod:`.fit`), not the single
luckiest one: the paper does not say which point to keep.
:class:`ParabolicAsPrintedSeeker` runs Step 7 exactly as printed with only Step 8 and the
budget to stop it, to show what the misprint does.
"""

from __future__ import annotations

import math

from sessions.seekers.base import Evaluation, FilteredSeeker, Plan
from sessions.seekers.fit import final_estimate, top_curvature


def parabola_vertex(
    g1: float, p1: float, g2: float, p2: float, g3: float, p3: float
) -> float | None:
    """γ4 of (34)-(36), or None when the three points are collinear."""
    n = (g2 - g1) ** 2 * (p2 - p3) - (g2 - g3) ** 2 * (p2 - p1)  # (35)
    d = (g2 - g1) * (p2 - p3) - (g2 - g3) * (p2 - p1)  # (36)
    if d == 0.0:
        return None
    return g2 - 0.5 * n / d  # (34)


def curvature(g1: float, p1: float, g2: float, p2: float, g3: float, p3: float) -> float:
    """Second divided difference: negative when the three points are concave (a maximum)."""
    return ((p3 - p2) / (g3 - g2) - (p2 - p1) / (g2 - g1)) / (g3 - g1)


def vertex_stderr(pts: list[tuple[float, float]], stderr: list[float]) -> float:
    """Standard error of the vertex (34) from the measurements' standard errors (linearised)."""
    (g1, p1), (g2, p2), (g3, p3) = pts
    v0 = parabola_vertex(g1, p1, g2, p2, g3, p3)
    if v0 is None or not all(math.isfinite(e) for e in stderr):
        return math.inf
    var = 0.0
    for i, e in enumerate(stderr):
        h = max(e, 1e-9)
        ps = [p1, p2, p3]
        ps[i] += h
        v = parabola_vertex(g1, ps[0], g2, ps[1], g3, ps[2])
        if v is None:
            return math.inf
        var += (v - v0) ** 2
    return math.sqrt(var)


def nudge(g4: float, known: list[float], min_step: float) -> float | None:
    """Keep a new point at least min_step from every known one: a vertex on top of a measured
    point teaches nothing. Move it away from that point into the wider side of the bracket;
    None when there is no such room."""
    g1, g3 = min(known), max(known)
    near = min(known, key=lambda g: abs(g - g4))
    if abs(g4 - near) >= min_step:
        return g4
    wide_left = (near - g1) > (g3 - near)
    cand = near - min_step if wide_left else near + min_step
    if all(abs(cand - g) >= min_step * (1 - 1e-9) for g in known) and g1 < cand < g3:
        return cand
    return None


def step7(
    pts: list[tuple[float, float]], g4: float, p4: float, *, as_printed: bool = False
) -> list[tuple[float, float]]:
    """Step 7: the three points kept after measuring p(γ4); ``pts`` sorted by γ."""
    (g1, p1), (g2, p2), (g3, p3) = pts
    left = (p4 >= p2 and g4 < g2) or (p2 >= p4 and g4 > g2)
    if as_printed:
        left = not left
    kept = [(g1, p1), (g2, p2), (g4, p4)] if left else [(g2, p2), (g3, p3), (g4, p4)]
    return sorted(kept)


class ParabolicSeeker(FilteredSeeker):
    kind = "parabolic"
    as_printed = False
    __slots__ = ()

    def plan(self, lo: float, guess: float, hi: float) -> Plan:
        cfg = self.cfg
        pts: list[tuple[float, float]] = []
        for g in (lo, guess, hi):  # Steps 1-4
            ev: Evaluation = yield g
            pts.append((ev.candidate, ev.power))
        pts.sort()
        guarded = not self.as_printed
        while True:
            (g1, p1), (g2, p2), (g3, p3) = pts
            self.bracket = (g1, g3)
            best = max(pts, key=lambda x: x[1])[0]
            if guarded:  # the estimate: all measurements near the top, not the luckiest one
                best = final_estimate(self.evaluations, g1, g3, best)
            if g3 - g1 < cfg.threshold:  # Step 8
                return best, "bracket narrower than the threshold"
            if len(self.evaluations) >= cfg.max_evaluations:
                return best, "evaluation budget spent"
            if guarded and curvature(g1, p1, g2, p2, g3, p3) >= 0.0:
                return best, "points no longer concave: differences below the noise"
            g4 = parabola_vertex(g1, p1, g2, p2, g3, p3)  # Step 5
            if g4 is None:
                return best, "degenerate parabola"
            g4 = self.clamp(g4)  # Step 6: every candidate within (γ1, γ3), the hard bounds
            if guarded and min(abs(g4 - g) for g, _ in pts) < cfg.min_step:
                se = {ev.candidate: ev.stderr for ev in self.evaluations}
                if vertex_stderr(pts, [se.get(g, math.inf) for g, _ in pts]) < cfg.min_step:
                    return g4, "vertex repeats a measured point"
                g4 = nudge(g4, [g for g, _ in pts], cfg.min_step)
                if g4 is None:
                    return best, "no room left for a new point"
            ev = yield g4  # Step 6
            pts = step7(pts, ev.candidate, ev.power, as_printed=self.as_printed)  # Step 7

    def curvature_hint(self) -> float | None:
        return top_curvature(self.evaluations)


class ParabolicAsPrintedSeeker(ParabolicSeeker):
    """Appendix A with Step 7 exactly as the paper prints it (the erratum not fixed)."""

    kind = "parabolic-as-printed"
    as_printed = True
    __slots__ = ()
