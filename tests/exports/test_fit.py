"""FIT export: every written file decoded by independent decoders (fitdecode; Garmin's own
decoder for a second opinion) and compared with the telemetry it was written from."""

from __future__ import annotations

import math
import struct
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import fitdecode
import numpy as np
import pytest

from sessions.exports.data import ExportError, Phase
from sessions.exports.fit import FitOptions, encode_fit, write_fit
from sessions.summary import SessionSummary
from sessions.telemetry import NAMES
from testing.exports import simulated_session

RPM = 60.0 / (2.0 * math.pi)  # independent of sessions.units
FIT_EPOCH = datetime(1989, 12, 31, tzinfo=UTC)
# a start a quarter second past the second, so no 1 kHz sample sits on a record boundary
START = datetime(2026, 3, 1, 9, 30, 12, 250_400, tzinfo=UTC)
PHASES = (
    Phase("warm-up", 0.0, 8.0, "warmup"),
    Phase("seek γ ≤ 6 rad/s — Zoë", 8.0, 30.0, "seek", optimum_w=3.05, at_bound="upper"),
    Phase("work 1", 30.0, 34.5, "work", mean_power=2.5, peak_power=3.25, work=11.0),
    Phase("rest 1", 34.5, 36.0, "rest"),
    Phase("cool-down", 36.0, 40.0, "cooldown"),
)


@pytest.fixture(scope="module")
def session() -> dict[str, np.ndarray]:
    run = simulated_session(40.0, seed=3)
    return {name: run.column(name).copy() for name in NAMES}


def decode(data: bytes) -> dict[str, list[dict[str, Any]]]:
    """Every data message by name, fields by name (developer fields included); fitdecode checks
    the header's and the file's CRC and raises on a mismatch."""
    out: dict[str, list[dict[str, Any]]] = {}
    with fitdecode.FitReader(data, check_crc=fitdecode.CrcCheck.RAISE) as reader:
        for frame in reader:
            if isinstance(frame, fitdecode.FitDataMessage):
                out.setdefault(frame.name, []).append({f.name: f.value for f in frame.fields})
    return out


def fit_seconds(value: datetime) -> float:
    return (value - FIT_EPOCH).total_seconds()


def expected_records(cols: dict[str, np.ndarray], start: datetime, interval: int = 1) -> list:
    """The documented rule, computed sample by sample: the record stamped T holds the samples
    whose absolute time lies in [T - interval, T), boundaries counted from the start's whole
    second; a sample within 1 µs below a boundary counts as after it."""
    abs_t = start.timestamp() + cols["t"]
    base = math.floor(start.timestamp())
    k = np.floor((abs_t - base) / interval + 1e-6).astype(int) + 1
    out = []
    for rec in np.unique(k):
        m = k == rec
        last = np.flatnonzero(m)[-1]
        out.append((base + rec * interval, m, last))
    return out


@pytest.mark.parametrize("phases", [PHASES, ()], ids=["phases", "no-phases"])
@pytest.mark.parametrize("start", [START, START.astimezone(timezone(timedelta(hours=-5)))])
def test_every_record_equals_the_telemetry_at_its_time(
    session: dict[str, np.ndarray], phases: tuple[Phase, ...], start: datetime
) -> None:
    msgs = decode(encode_fit(start, session, phases))
    records = msgs["record"]
    expected = expected_records(session, start)
    assert len(records) == len(expected)
    assert sum(int(m.sum()) for _, m, _ in expected) == len(session["t"])  # every sample once
    for rec, (stamp, m, last) in zip(records, expected, strict=True):
        assert rec["timestamp"].timestamp() == stamp
        power = float(np.mean(session["tau"][m] * session["w"][m]))
        assert rec["power"] == max(round(power), 0)
        assert rec["mean_power"] == np.float32(power)
        rpm = float(np.mean(session["w"][m])) * RPM
        assert rec["cadence"] + rec["fractional_cadence"] == round(max(rpm, 0) * 128) / 128
        assert rec["torque"] == np.float32(np.mean(session["tau"][m]))
        assert rec["desired_cadence"] == np.float32(np.mean(session["wd"][m]) * RPM)
        assert rec["target_cadence"] == np.float32(session["gamma"][last] * RPM)


def test_laps_match_the_phases(session: dict[str, np.ndarray]) -> None:
    msgs = decode(encode_fit(START, session, PHASES))
    laps, t, W = msgs["lap"], session["t"], session["W"]
    assert len(laps) == len(PHASES)
    intensity = {"warmup": "warmup", "seek": "active", "work": "interval", "rest": "rest",
                 "cooldown": "cooldown"}  # fmt: skip
    for i, (lap, ph) in enumerate(zip(laps, PHASES, strict=True)):
        m = (t >= ph.start) & (t < ph.end)
        power = session["tau"][m] * session["w"][m]
        first, last = np.flatnonzero(m)[[0, -1]]
        work = W[last] - (W[first - 1] if first else 0.0)
        assert lap["message_index"] == i
        assert lap["phase"] == ph.name
        assert lap["intensity"] == intensity[ph.kind]
        assert lap["total_elapsed_time"] == pytest.approx(ph.end - ph.start, abs=1e-3)
        assert fit_seconds(lap["start_time"]) == math.floor(fit_seconds(START) + ph.start)
        given = ph.mean_power is not None
        assert lap["avg_power"] == round(ph.mean_power if given else float(power.mean()))
        assert lap["max_power"] == round(ph.peak_power if given else float(power.max()))
        assert lap["total_work"] == round(ph.work if given else work)
        avg_rpm = float(session["w"][m].mean()) * RPM
        assert lap["avg_cadence"] + lap["avg_fractional_cadence"] == round(avg_rpm * 128) / 128
        if ph.optimum_w is None:
            assert "optimum_cadence" not in lap
        else:
            assert lap["optimum_cadence"] == np.float32(ph.optimum_w * RPM)
        assert lap.get("optimum_at_bound") == ph.at_bound
    ends = [fit_seconds(lap["timestamp"]) for lap in laps]
    starts = [fit_seconds(lap["start_time"]) for lap in laps]
    assert starts[1:] == ends[:-1]  # contiguous
    assert ends[-1] == fit_seconds(msgs["session"][0]["timestamp"])
    assert [lap["lap_trigger"] for lap in laps] == ["time"] * 4 + ["session_end"]


def test_one_lap_and_the_totals_without_phases(session: dict[str, np.ndarray]) -> None:
    summary = SessionSummary(optimum_w=3.1, optimum_p=2.9, converged=True, seeker="brent",
                             mean_power=2.61, peak_power=3.47, work=104.6, duration=40.0,
                             passivity_min=-0.2, evaluations=7)  # fmt: skip
    msgs = decode(encode_fit(START, session, (), summary=summary))
    (lap,), (ses,), (act,) = msgs["lap"], msgs["session"], msgs["activity"]
    assert lap["phase"] == "session" and lap["lap_trigger"] == "session_end"
    assert lap["total_elapsed_time"] == pytest.approx(40.0, abs=1e-3)
    for m in (lap, ses):
        assert m["start_time"] == START.replace(microsecond=0)
    assert ses["total_elapsed_time"] == ses["total_timer_time"] == pytest.approx(40.0, abs=1e-3)
    assert ses["total_work"] == 105
    assert ses["avg_power"] == 3 and ses["max_power"] == 3
    assert ses["total_calories"] == round(104.6 / 4184 / 0.24)
    assert ses["optimum_cadence"] == np.float32(3.1 * RPM) and "optimum_at_bound" not in ses
    assert ses["num_laps"] == 1 and ses["sport"] == "fitness_equipment"
    rpm = float(session["w"].mean()) * RPM
    assert ses["avg_cadence"] + ses["avg_fractional_cadence"] == round(rpm * 128) / 128
    assert act["num_sessions"] == 1 and act["total_timer_time"] == pytest.approx(40.0, abs=1e-3)
    assert msgs["file_id"][0]["type"] == "activity"
    assert msgs["file_id"][0]["time_created"] == START.replace(microsecond=0)
    events = [(e["event"], e["event_type"]) for e in msgs["event"]]
    assert events == [("timer", "start"), ("timer", "stop_all")]
    edge = summary.model_copy(update={"optimum_w": 1.0, "at_bound": "lower", "converged": False})
    ses = decode(encode_fit(START, session, (), summary=edge))["session"][0]
    assert ses["optimum_cadence"] == np.float32(1.0 * RPM) and ses["optimum_at_bound"] == "lower"


def test_totals_computed_from_telemetry_without_a_summary(session: dict[str, np.ndarray]) -> None:
    ses = decode(encode_fit(START, session))["session"][0]
    power = session["tau"] * session["w"]
    assert ses["avg_power"] == round(float(power.mean()))
    assert ses["max_power"] == round(float(power.max()))
    assert ses["total_work"] == round(float(session["W"][-1]))
    assert ses["total_elapsed_time"] == pytest.approx(40.0, abs=1e-3)


def test_local_time_of_the_activity(session: dict[str, np.ndarray]) -> None:
    start = START.astimezone(timezone(timedelta(hours=2)))
    act = decode(encode_fit(start, session))["activity"][0]
    utc = fit_seconds(act["timestamp"])
    local = act["local_timestamp"]  # fitdecode gives local_date_time as seconds or datetime
    local = fit_seconds(local) if isinstance(local, datetime) else local
    assert local - utc == 7200


def test_records_every_five_seconds(session: dict[str, np.ndarray]) -> None:
    records = decode(encode_fit(START, session, options=FitOptions(record_interval=5)))["record"]
    expected = expected_records(session, START, 5)
    assert len(records) == len(expected) == 9
    for rec, (stamp, m, _) in zip(records, expected, strict=True):
        assert rec["timestamp"].timestamp() == stamp
        assert rec["torque"] == np.float32(np.mean(session["tau"][m]))


def test_negative_power_and_velocity_are_written_as_zero() -> None:
    n = 3000
    t = np.arange(n) / 1000.0
    cols = {name: np.zeros(n) for name in NAMES} | {"t": t, "w": np.full(n, -0.5),
                                                   "tau": np.full(n, 2.0)}  # fmt: skip
    records = decode(encode_fit(START, cols))["record"]
    assert all(r["power"] == 0 and r["cadence"] == 0 for r in records)
    assert all(r["mean_power"] == np.float32(-1.0) for r in records)  # the truth is kept too


def fit_crc(data: bytes) -> int:
    """CRC-16 as the FIT protocol specifies it (nibble table), written out independently."""
    table = [0x0000, 0xCC01, 0xD801, 0x1400, 0xF001, 0x3C00, 0x2800, 0xE401,
             0xA001, 0x6C00, 0x7800, 0xB401, 0x5000, 0x9C01, 0x8801, 0x4400]  # fmt: skip
    crc = 0
    for byte in data:
        for nibble in (byte & 0xF, byte >> 4):
            tmp = table[crc & 0xF]
            crc = ((crc >> 4) & 0x0FFF) ^ tmp ^ table[nibble]
    return crc


def test_file_header_and_crcs_are_valid(session: dict[str, np.ndarray]) -> None:
    data = encode_fit(START, session, PHASES)
    size, protocol, _profile, data_size, magic, header_crc = struct.unpack("<BBHI4sH", data[:14])
    assert (size, protocol, magic) == (14, 0x20, b".FIT")
    assert data_size == len(data) - 14 - 2
    assert header_crc == fit_crc(data[:12])
    assert struct.unpack("<H", data[-2:])[0] == fit_crc(data[:-2])
    assert fit_crc(data) == 0  # a whole file including its CRC checks to 0
    broken = bytearray(data)
    broken[len(data) // 2] ^= 0x40
    with pytest.raises(fitdecode.FitCRCError):
        decode(bytes(broken))


def test_garmins_decoder_agrees(session: dict[str, np.ndarray]) -> None:
    """A second independent opinion: Garmin's FIT SDK decoder (its integrity check too)."""
    sdk = pytest.importorskip("garmin_fit_sdk")
    data = encode_fit(START, session, PHASES)
    assert sdk.Decoder(sdk.Stream.from_byte_array(bytearray(data))).check_integrity()
    messages, errors = sdk.Decoder(sdk.Stream.from_byte_array(bytearray(data))).read()
    assert errors == []
    ours = decode(data)
    names = {d["key"]: d["field_name"] for d in messages["field_description_mesgs"]}
    assert len(messages["record_mesgs"]) == len(ours["record"])
    assert len(messages["lap_mesgs"]) == len(PHASES)
    for theirs, mine in zip(messages["record_mesgs"], ours["record"], strict=True):
        assert theirs["timestamp"] == mine["timestamp"]
        assert theirs["power"] == mine["power"] and theirs["cadence"] == mine["cadence"]
        dev = {names[k]: v for k, v in theirs["developer_fields"].items()}
        assert dev == {k: mine[k] for k in dev} and len(dev) == 4
    laps = [
        {names[k]: v for k, v in lap["developer_fields"].items()} for lap in messages["lap_mesgs"]
    ]
    assert [lap["phase"] for lap in laps] == [p.name for p in PHASES]


def test_write_fit_writes_the_same_bytes(session: dict[str, np.ndarray], tmp_path: Path) -> None:
    path = tmp_path / "session.fit"
    size = write_fit(path, START, session, PHASES)
    assert path.read_bytes() == encode_fit(START, session, PHASES)
    assert size == path.stat().st_size
    assert [p.name for p in tmp_path.iterdir()] == ["session.fit"]  # no temporary left


def test_long_phase_names_are_cut_on_a_character(session: dict[str, np.ndarray]) -> None:
    name = "é" * 100 + "\x00x"
    phases = (Phase(name, 0.0, 40.0, "train"),)
    lap = decode(encode_fit(START, session, phases))["lap"][0]
    assert lap["phase"] == "é" * 31  # 62 of the 63 bytes: never half a character


def test_bad_input_is_refused_with_the_argument_named(session: dict[str, np.ndarray]) -> None:
    naive = START.replace(tzinfo=None)
    nan_t = dict(session) | {"t": np.where(np.arange(len(session["t"])) == 5, np.nan, session["t"])}
    cases = [
        (lambda: encode_fit(naive, session), r"^start: must be a timezone-aware"),
        (lambda: encode_fit(START, {k: v for k, v in session.items() if k != "tau"}),
         r"^telemetry\.tau: missing"),
        (lambda: encode_fit(START, nan_t), r"^telemetry\.t: not finite"),
        (lambda: encode_fit(START, session | {"w": session["w"][:-1]}), r"^telemetry: columns"),
        (lambda: encode_fit(START, session, options=FitOptions(record_interval=0)),
         r"^record_interval"),
        (lambda: encode_fit(START, session, options=FitOptions(record_interval=0.5)),  # type: ignore[arg-type]
         r"^record_interval: must be whole seconds"),
        (lambda: encode_fit(START, session, (Phase("a", 0, 10), Phase("b", 5, 20))),
         r"^phases\[1\]\.start: overlaps"),
        (lambda: encode_fit(START, session, (Phase("a", 10, 10),)), r"^phases\[0\]\.end"),
        (lambda: encode_fit(START, session, options=FitOptions(gross_efficiency=0)),
         r"^gross_efficiency"),
        (lambda: encode_fit(START, {name: np.zeros(0) for name in NAMES}),
         r"^telemetry: no samples"),
    ]  # fmt: skip
    for call, message in cases:
        with pytest.raises(ExportError, match=message):
            call()
