"""A session's phases in the store: their boundaries as the pump records them, and their
summaries (:mod:`sessions.protocol.analysis`) computed from the stored telemetry.

- :func:`record_stage`: a stage the worker reported: an event of the session (``stage``, its
  whole description) and, for a phase's first stage, the phase's row (ending the one before);
- :func:`summarize_phases`: the summaries of the phases that have none yet (all of them once the
  session has ended, or the ones named), from the stored telemetry. Run off the event loop;
- :func:`session_phases`: the phases as REST and the dashboard read them (summarized first if
  the session has ended without them).

After a crash the boundaries are there (every stage is flushed as it comes); the summaries are
computed the next time they are asked for (:func:`summarize_phases` on a session that ended).
"""

from __future__ import annotations

from collections.abc import Iterable

from sessions.protocol.analysis import PhaseSpan, phase_spans, summarize_phase
from sessions.protocol.stage import Stage
from sessions.store import PhaseRecord, SessionRecorder, Store

STAGE_EVENT = "stage"
CHANNELS = ("t", "q", "w", "tau", "W")


def record_stage(store: Store, recorder: SessionRecorder, session_id: int, stage: Stage) -> None:
    """Persist one stage (blocking: call in a thread)."""
    recorder.add_event(stage.start, STAGE_EVENT, stage.to_dict())
    if stage.segment == 0:
        store.phases.begin(
            session_id, stage.phase, stage.kind, stage.name, stage.start,
            planned_end=stage.phase_end, detail={"stages": [stage.to_dict()]},
        )  # fmt: skip


def stored_stages(store: Store, session_id: int) -> list[Stage]:
    return [Stage.from_dict(e.detail) for e in store.sessions.events(session_id, kind=STAGE_EVENT)]


def spans(store: Store, session_id: int) -> list[PhaseSpan]:
    """The session's phases as its stored stages and telemetry show them."""
    record = store.sessions.get(session_id)
    span = store.telemetry.span(session_id)
    dt = 1.0 / float(record.config.get("rate", 1000.0))
    end = (span.t1 + dt) if span.t1 is not None else 0.0
    return phase_spans(stored_stages(store, session_id), end, record.optimum_w, record.at_bound)


def summarize_phases(
    store: Store, session_id: int, positions: Iterable[int] | None = None
) -> list[PhaseRecord]:
    """Summarize the phases at ``positions`` (default: every phase without a summary) from the
    stored telemetry; returns the session's phases afterwards."""
    record = store.sessions.get(session_id)
    stored = {p.position: p for p in store.phases.list(session_id)}
    wanted = (
        set(positions)
        if positions is not None
        else {pos for pos, p in stored.items() if p.mean_power is None}
    )
    profile_model = _profile_models(record.config)
    for span in spans(store, session_id):
        if span.index not in wanted or span.index not in stored:
            continue
        cols = store.telemetry.columns(session_id, CHANNELS, start=max(0.0, span.start - 0.01),
                                       end=span.end)  # fmt: skip
        result = summarize_phase(cols, span, profile_model=profile_model.get(span.index, "auto"))
        store.phases.summarize(session_id, result)
    return store.phases.list(session_id)


def session_phases(store: Store, session_id: int) -> list[PhaseRecord]:
    """A session's phases as REST and the dashboard show them: an ended session whose summaries
    were never made (a crash, or the pump not there yet) gets them now."""
    phases = store.phases.list(session_id)
    if store.sessions.get(session_id).status != "running" and any(
        p.mean_power is None for p in phases
    ):
        phases = summarize_phases(store, session_id)
    return phases


def _profile_models(config: dict[str, object]) -> dict[int, str]:
    protocol = config.get("protocol")
    if not isinstance(protocol, dict):
        return {}
    phases = protocol.get("phases") or []
    return {
        i: str(ph.get("model", "auto"))
        for i, ph in enumerate(phases)  # type: ignore[arg-type]
        if isinstance(ph, dict) and ph.get("kind") == "profile"
    }
