"""The two tracking controllers of the paper, behind one small interface.

``command(e, ad, τ)`` gives the motor torque before limits; ``commit(...)`` is told what was
applied and returns the user torque the seekers use (measured τ, or the observer's τ̂).
"""

from __future__ import annotations

from sessions.config import ControllerConfig
from sessions.controllers.measured import MeasuredTorqueController
from sessions.controllers.rise import RiseController

Controller = MeasuredTorqueController | RiseController


def make_controller(cfg: ControllerConfig, inertia: float) -> Controller:
    if cfg.kind == "measured":
        return MeasuredTorqueController(cfg.k, inertia)
    return RiseController(cfg.ks, cfg.beta, cfg.alpha_r, inertia)


__all__ = ["Controller", "MeasuredTorqueController", "RiseController", "make_controller"]
