"""A session as a FIT activity file, the format Garmin Connect, Strava, intervals.icu and
GoldenCheetah import, written with Garmin's own FIT SDK (``garmin_fit_sdk.Encoder``).

The file (FIT protocol 2.0), in order: file_id (activity), developer_data_id and the
developer fields' descriptions, device_info, a timer start event, one record per
``record_interval`` s, a timer stop event, one lap per protocol phase (one lap for the whole
session when there are none), the session and the activity. docs/exports.md lists every field.

Records. FIT timestamps are whole seconds since 1989-12-31 00:00 UTC, so records are at most
1 Hz: the record stamped T holds the means over the samples whose absolute time (the session's
start plus ``t``) lies in [T - interval, T); the first record is one interval after the start
second. Standard fields: power (W, the mean of τ·w, τ̂·w under RISE, rounded) and cadence (rpm,
the mean handle velocity, with fractional_cadence carrying 1/128 rpm). Developer fields:
``torque`` (N·m, mean τ or τ̂), ``desired_cadence`` (rpm, mean wd) and ``target_cadence`` (rpm,
the seeker's γ at the end of the interval: the candidate while searching, the optimum once
found), all float32. FIT's power and cadence fields are unsigned: negative values (observer
transients, a handle turned backwards) are written as 0, as a power meter reports them.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
from garmin_fit_sdk import Encoder
from garmin_fit_sdk.util import FIT_EPOCH_S

from sessions.exports.data import (
    Columns,
    ExportError,
    Phase,
    Totals,
    check_phases,
    sample_period,
    telemetry_columns,
    totals,
    write_atomically,
)
from sessions.summary import SessionSummary
from sessions.units import RPM_PER_RAD_S

CHANNELS = ("t", "w", "tau", "wd", "gamma", "W")
APPLICATION_ID = list(uuid.uuid5(uuid.NAMESPACE_URL, "ergoseek:fit").bytes)
APPLICATION_VERSION = 1
FLOAT32, STRING = 136, 7  # FIT base type ids
MAX_STRING_BYTES = 63  # a lap's phase name, UTF-8, cut on a character boundary
JOULES_PER_KCAL = 4184.0
# Intensity of a lap by its phase's kind (FIT's intensity enum); anything else is "active".
INTENSITY = {
    "warmup": "warmup",
    "cooldown": "cooldown",
    "rest": "rest",
    "recovery": "recovery",
    "work": "interval",
    "interval": "interval",
}


@dataclass(frozen=True, slots=True)
class DeveloperField:
    number: int
    name: str
    units: str
    base_type: int
    message: int  # the FIT message it is written in (20 record, 19 lap, 18 session)


DEVELOPER_FIELDS = (
    DeveloperField(0, "torque", "N*m", FLOAT32, 20),
    DeveloperField(1, "desired_cadence", "rpm", FLOAT32, 20),
    DeveloperField(2, "target_cadence", "rpm", FLOAT32, 20),
    DeveloperField(3, "optimum_cadence", "rpm", FLOAT32, 19),  # laps and the session
    DeveloperField(4, "phase", "", STRING, 19),
    DeveloperField(5, "mean_power", "W", FLOAT32, 20),  # unrounded: a small user's 3 W
    DeveloperField(6, "optimum_at_bound", "", STRING, 19),  # laps and the session: upper, lower
)  # in order of number: some decoders key developer fields by the description's position


@dataclass(frozen=True, slots=True)
class FitOptions:
    """How the file is written. ``gross_efficiency``: the calories fields are the metabolic
    energy work/efficiency (None leaves them out; 0.24 is a typical gross efficiency of
    cycling-like exercise, for which kJ of work ≈ kcal burnt)."""

    record_interval: int = 1  # s, whole seconds (FIT timestamps)
    sport: str = "fitness_equipment"
    sub_sport: str = "generic"
    gross_efficiency: float | None = 0.24
    serial_number: int = 1
    product_name: str = "ergoseek"
    software_version: int = 1


def _fit_time(start: datetime) -> tuple[int, float]:
    """(FIT timestamp of the start's whole second, the start's fraction of a second)."""
    if not isinstance(start, datetime) or start.tzinfo is None or start.utcoffset() is None:
        raise ExportError("start: must be a timezone-aware datetime (UTC)")
    unix = start.timestamp()
    whole = math.floor(unix)
    return whole - FIT_EPOCH_S, unix - whole


def _clamp_int(x: float, hi: int) -> int | None:
    return None if not math.isfinite(x) else int(min(max(round(x), 0), hi))


def _cadence(w: float) -> dict[str, Any]:
    """cadence (uint8 rpm) + fractional_cadence (1/128 rpm) for a velocity w in rad/s."""
    if not math.isfinite(w):
        return {}
    ticks = min(max(round(w * RPM_PER_RAD_S * 128), 0), 254 * 128)
    return {"cadence": ticks // 128, "fractional_cadence": (ticks % 128) / 128}


def _bins(t: np.ndarray, fraction: float, interval: int) -> tuple[np.ndarray, np.ndarray]:
    """(first sample of each record's interval, record number k ≥ 1: stamped k·interval s
    after the start's whole second). A sample within 1 µs of a boundary counts as after it."""
    k = np.floor((t + fraction) / interval + 1e-6).astype(np.int64) + 1
    starts = np.concatenate(([0], np.flatnonzero(np.diff(k)) + 1)) if len(k) else np.zeros(0, int)
    return starts, k[starts] if len(k) else np.zeros(0, np.int64)


def _means(x: np.ndarray, starts: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x)
    sums = np.add.reduceat(np.where(ok, x, 0.0), starts)
    counts = np.add.reduceat(ok.astype(np.int64), starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def record_values(cols: Columns, fraction: float, interval: int) -> dict[str, np.ndarray]:
    """Per record, vectorised: its number k (stamped k·interval after the start second), mean
    power (W), mean velocity and wd (rad/s), mean torque (N·m), γ at the interval's end (rad/s)."""
    t = cols["t"]
    starts, k = _bins(t, fraction, interval)
    if not len(k):
        return {"k": k}
    ends = np.append(starts[1:], len(t)) - 1
    return {
        "k": k,
        "power": _means(cols["tau"] * cols["w"], starts),
        "w": _means(cols["w"], starts),
        "tau": _means(cols["tau"], starts),
        "wd": _means(cols["wd"], starts),
        "gamma": cols["gamma"][ends],
    }


def _records(values: dict[str, np.ndarray], base: int, interval: int) -> list[dict[str, Any]]:
    if not len(values["k"]):
        return []
    stamps = (base + values["k"] * interval).tolist()
    has_power = np.isfinite(values["power"]).tolist()
    power = np.clip(np.round(np.nan_to_num(values["power"])), 0, 65534).astype(int).tolist()
    tau = values["tau"].astype(np.float32).tolist()
    wd = (values["wd"] * RPM_PER_RAD_S).astype(np.float32).tolist()
    gamma = (values["gamma"] * RPM_PER_RAD_S).astype(np.float32).tolist()
    exact = values["power"].astype(np.float32).tolist()
    w = values["w"].tolist()
    out = []
    for i, stamp in enumerate(stamps):
        rec: dict[str, Any] = {"mesg_num": 20, "timestamp": stamp}
        if has_power[i]:
            rec["power"] = power[i]
        rec |= _cadence(w[i])
        pairs = ((0, tau[i]), (1, wd[i]), (2, gamma[i]), (5, exact[i]))
        dev = {key: v for key, v in pairs if math.isfinite(v)}
        if dev:
            rec["developer_fields"] = dev
        out.append(rec)
    return out


def _phase_name(name: str) -> str:
    raw = name.encode("utf-8")[:MAX_STRING_BYTES]
    return raw.decode("utf-8", errors="ignore").replace("\x00", "") or "phase"


def _summary_fields(tot: Totals, opts: FitOptions) -> dict[str, Any]:
    """The figures a lap and the session share (FIT names them alike)."""
    fields: dict[str, Any] = {
        "total_elapsed_time": tot.duration,
        "total_timer_time": tot.duration,
        "total_work": _clamp_int(tot.work, 2**32 - 2),
        "avg_power": _clamp_int(tot.mean_power, 65534),
        "max_power": _clamp_int(tot.peak_power, 65534),
        "sport": opts.sport,
        "sub_sport": opts.sub_sport,
    }
    avg, peak = _cadence(tot.mean_w), _cadence(tot.peak_w)
    if avg:
        fields |= {
            "avg_cadence": avg["cadence"],
            "avg_fractional_cadence": avg["fractional_cadence"],
        }
    if peak:
        fields |= {
            "max_cadence": peak["cadence"],
            "max_fractional_cadence": peak["fractional_cadence"],
        }
    if opts.gross_efficiency is not None and math.isfinite(tot.work):
        fields["total_calories"] = _clamp_int(
            tot.work / JOULES_PER_KCAL / opts.gross_efficiency, 65534
        )
    return fields


def _with_given(tot: Totals, ph: Phase | SessionSummary | None) -> Totals:
    """The runner's stored totals where it gave them, the telemetry's otherwise."""
    if ph is None:
        return tot
    pick = [getattr(ph, k) for k in ("mean_power", "peak_power", "work")]
    mean, peak, work = (
        x if x is not None else d
        for x, d in zip(pick, (tot.mean_power, tot.peak_power, tot.work), strict=True)
    )
    duration = ph.duration if isinstance(ph, SessionSummary) and ph.duration > 0 else tot.duration
    return Totals(duration, mean, peak, work, tot.mean_w, tot.peak_w)


def _optimum(fields: dict[str, Any], w: float | None, at_bound: str | None) -> dict[str, Any]:
    """The optimum (rpm) and, when it is the bracket's edge, which one ("upper", "lower")."""
    if w is not None and math.isfinite(w):
        dev = fields.setdefault("developer_fields", {})
        dev[3] = float(np.float32(w * RPM_PER_RAD_S))
        if at_bound:
            dev[6] = at_bound
    return fields


def _laps(
    cols: Columns,
    phases: tuple[Phase, ...],
    base: int,
    frac: float,
    duration: float,
    opts: FitOptions,
) -> list[dict[str, Any]]:
    spans = phases or (Phase("session", 0.0, duration),)
    laps = []
    for i, ph in enumerate(spans):
        end = duration if ph is spans[-1] and not phases else ph.end
        tot = _with_given(totals(cols, ph.start, end), ph if phases else None)
        lap = {
            "mesg_num": 19,
            "message_index": i,
            "timestamp": base + math.floor(frac + end),
            "start_time": base + math.floor(frac + ph.start),
            "event": "lap",
            "event_type": "stop",
            "lap_trigger": "session_end" if i == len(spans) - 1 else "time",
            "intensity": INTENSITY.get(ph.kind, "active"),
            **_summary_fields(tot, opts),
            "developer_fields": {4: _phase_name(ph.name)},
        }
        laps.append(_optimum(lap, ph.optimum_w, ph.at_bound))
    return laps


def _header(enc: Encoder, base: int, opts: FitOptions) -> None:
    dev_id = {
        "mesg_num": 207,
        "developer_data_index": 0,
        "application_id": APPLICATION_ID,
        "application_version": APPLICATION_VERSION,
    }
    enc.write_mesg(
        {
            "mesg_num": 0,
            "type": "activity",
            "manufacturer": "development",
            "product": 0,
            "serial_number": opts.serial_number,
            "time_created": base,
            "product_name": opts.product_name,
        }
    )
    enc.write_mesg(dev_id)
    for f in DEVELOPER_FIELDS:
        desc = {
            "mesg_num": 206,
            "developer_data_index": 0,
            "field_definition_number": f.number,
            "fit_base_type_id": f.base_type,
            "field_name": f.name,
            "native_mesg_num": f.message,
        }
        if f.units:
            desc["units"] = f.units
        enc.add_developer_field(f.number, dev_id, desc)
        enc.write_mesg(desc)
    enc.write_mesg(
        {
            "mesg_num": 23,
            "timestamp": base,
            "device_index": 0,
            "manufacturer": "development",
            "product": 0,
            "serial_number": opts.serial_number,
            "product_name": opts.product_name,
            "software_version": opts.software_version,
        }
    )
    enc.write_mesg({"mesg_num": 21, "timestamp": base, "event": "timer", "event_type": "start"})


def _check_options(opts: FitOptions) -> None:
    iv = opts.record_interval
    if not isinstance(iv, int) or isinstance(iv, bool) or not 1 <= iv <= 3600:
        raise ExportError(
            f"record_interval: must be whole seconds from 1 to 3600 (FIT timestamps are whole "
            f"seconds), got {iv!r}"
        )
    eff = opts.gross_efficiency
    if eff is not None and not 0.0 < eff <= 1.0:
        raise ExportError(f"gross_efficiency: must be in (0, 1] or None, got {eff!r}")
    if not 0 < opts.serial_number < 2**32 - 1:
        raise ExportError(f"serial_number: must be from 1 to 2³² - 2, got {opts.serial_number}")


def encode_fit(
    start: datetime,
    telemetry: Any,
    phases: Sequence[Phase] = (),
    *,
    summary: SessionSummary | None = None,
    options: FitOptions = FitOptions(),
) -> bytes:
    """The session as a FIT activity file. ``start``: when the session began (aware; stored
    as UTC, its UTC offset as the activity's local time). ``telemetry``: full-rate columns
    ``t, w, tau, wd, gamma, W`` (see :mod:`sessions.exports.data`). ``phases``: the protocol's
    phases, one lap each. ``summary``: the stored session totals (duration, mean and peak
    power, work, optimum), else computed from the telemetry the same way."""
    _check_options(options)
    base, frac = _fit_time(start)
    cols = telemetry_columns(telemetry, CHANNELS)
    phs = check_phases(phases)
    t = cols["t"]
    if not len(t):
        raise ExportError("telemetry: no samples")
    whole = totals(cols)
    duration = max(whole.duration, float(t[-1]) + sample_period(t))
    session_tot = _with_given(replace(whole, duration=duration), summary)
    interval = options.record_interval
    values = record_values(cols, frac, interval)
    # the session ends with its last record (stamped at the end of the interval it covers)
    end = base + max(int(values["k"][-1]) * interval, math.ceil(frac + session_tot.duration))
    enc = Encoder()
    _header(enc, base, options)
    for rec in _records(values, base, interval):
        enc.write_mesg(rec)
    enc.write_mesg({"mesg_num": 21, "timestamp": end, "event": "timer", "event_type": "stop_all"})
    laps = _laps(cols, phs, base, frac, session_tot.duration, options)
    laps[-1]["timestamp"] = end
    for lap in laps:
        enc.write_mesg(lap)
    _trailer(enc, start, base, end, session_tot, len(laps), summary, options)
    return enc.close()


def _trailer(
    enc: Encoder,
    start: datetime,
    base: int,
    end: int,
    tot: Totals,
    laps: int,
    summary: SessionSummary | None,
    opts: FitOptions,
) -> None:
    """The session and activity messages: the totals, written last as devices do."""
    session = {
        "mesg_num": 18,
        "message_index": 0,
        "timestamp": end,
        "start_time": base,
        "event": "session",
        "event_type": "stop",
        "trigger": "activity_end",
        "first_lap_index": 0,
        "num_laps": laps,
        **_summary_fields(tot, opts),
    }
    enc.write_mesg(
        _optimum(session, *((summary.optimum_w, summary.at_bound) if summary else (None, None)))
    )
    offset = start.utcoffset() or timedelta(0)
    activity = {
        "mesg_num": 34,
        "timestamp": end,
        "total_timer_time": tot.duration,
        "num_sessions": 1,
        "type": "manual",
        "event": "activity",
        "event_type": "stop",
        "local_timestamp": end + int(offset.total_seconds()),
    }
    enc.write_mesg(activity)


def write_fit(
    path: str | Path, start: datetime, telemetry: Any, phases: Sequence[Phase] = (), **kwargs: Any
) -> int:
    """:func:`encode_fit` to ``path``, atomically (never a partial file); returns its size."""
    data = encode_fit(start, telemetry, phases, **kwargs)
    return write_atomically(path, data)
