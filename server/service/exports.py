"""A stored session as files other tools open: the one-page PDF report and the FIT activity,
built from the store (plain data in, bytes out; no HTTP). Both block for up to a second or
two on an hour's session: callers run them in a thread.

- the report gets the store's decimated telemetry (min/max pairs, from the chunks'
  overviews: no full-rate decoding), the phases with their stored summaries, the seeker's
  evaluations and the profile fit, in the reader's velocity unit;
- the FIT file gets the six channels it averages at full rate (read chunk batch by chunk
  batch), one lap per phase and the stored summary as the session's totals.

A running session has no report or activity yet (:class:`~sessions.store.ConflictError`), nor
one without telemetry.
"""

from __future__ import annotations

from datetime import tzinfo
from typing import Any

from server.service.phases import summarize_phases
from sessions.exports.data import Phase
from sessions.exports.fit import CHANNELS as FIT_CHANNELS
from sessions.exports.fit import FitOptions, encode_fit
from sessions.protocol.analysis import profile_from_dict
from sessions.protocol.config import Protocol, describe
from sessions.store import ConflictError, PhaseRecord, SessionDetail, Store
from sessions.units import VelocityUnit

REPORT_POINTS = 4800  # min/max pairs for the report's time charts (it draws 1200 columns)


def ended(store: Store, session_id: int) -> SessionDetail:
    """The session's detail, once it has ended and stored telemetry (409 otherwise), with its
    phases summarized."""
    detail = store.sessions.detail(session_id)
    s = detail.session
    if s.status == "running":
        raise ConflictError(f"session {session_id} is running: its exports exist once it ends")
    if store.telemetry.span(session_id).samples == 0:
        raise ConflictError(f"session {session_id} has no telemetry")
    if any(p.mean_power is None for p in detail.phases):
        phases = summarize_phases(store, session_id)
        detail = detail.model_copy(update={"phases": phases})
    return detail


def export_phases(phases: list[PhaseRecord]) -> list[Phase]:
    out = []
    for p in phases:
        if p.t_end is None or p.t_end <= p.t_start:
            continue
        out.append(
            Phase(
                name=p.name,
                start=p.t_start,
                end=p.t_end,
                kind=p.kind,
                mean_power=p.mean_power,
                peak_power=p.peak_power,
                work=p.work,
                optimum_w=p.optimum_w,
                at_bound=p.at_bound,
            )
        )
    return out


def protocol_title(config: dict[str, Any]) -> str:
    data = config.get("protocol")
    if not data:
        return "one seek phase (no protocol)"
    protocol = Protocol.model_validate(data)
    return protocol.name or describe(protocol)


def report_pdf(
    store: Store,
    session_id: int,
    *,
    velocity_unit: VelocityUnit = "rpm",
    timezone: tzinfo | None = None,
) -> bytes:
    # matplotlib (~1 CPU-s to load) only where a report is drawn, not in every server start
    from sessions.exports.report import ReportData, render_report

    detail = ended(store, session_id)
    s = detail.session
    user = store.users.get(s.user_id)
    telemetry = store.telemetry.load(session_id, points=REPORT_POINTS)
    cfg = s.config
    fits = [p.detail["profile"] for p in detail.phases if p.detail.get("profile")]
    bracket = cfg["seeker"]["bracket"]
    data = ReportData(
        user_name=user.name, started_at=s.started_at, telemetry=telemetry, summary=s.summary(),
        phases=export_phases(detail.phases), protocol=protocol_title(cfg),
        evaluations=detail.evaluations, bracket=(bracket[0], bracket[2]),
        profile=profile_from_dict(fits[0]) if fits else None, body_mass_kg=user.body_mass_kg,
        velocity_unit=velocity_unit, session_id=s.id, status=s.status,
        controller=cfg["controller"]["kind"], passivity_bound=cfg["machine"]["passivity_c2"],
        timezone=timezone,
    )  # fmt: skip
    return render_report(data)


def activity_fit(store: Store, session_id: int, *, record_interval: int = 1) -> bytes:
    detail = ended(store, session_id)
    s = detail.session
    cols = store.telemetry.columns(session_id, FIT_CHANNELS)
    return encode_fit(
        s.started_at, cols, export_phases(detail.phases), summary=s.summary(),
        options=FitOptions(record_interval=record_interval, serial_number=1),
    )  # fmt: skip
