"""A session writer for the crash tests, run as its own process:

    python -m testing.store_writer URL [PROGRESS]

Opens the store, starts a session and feeds it in real time through a background
:class:`~sessions.store.SessionRecorder`: 1 kHz telemetry (``testing.store.telemetry``)
in 10 ms blocks, an evaluation every 0.25 s and an event every second. Sample k is fed
once ``k`` ms have passed since ``start``, so at any moment everything fed has
``t ≤ now - start``. Prints one JSON line ``{"session": id, "start": monotonic}`` when
feeding begins, then runs until killed (or 60 s). With ``PROGRESS``, the newest time of each block
is appended there just before the block goes to the recorder: the last line a SIGKILL leaves
bounds what was fed from above, within a block (a writer a loaded machine stalls feeds
less than the wall clock since ``start`` says)."""

from __future__ import annotations

import json
import sys
import time

from sessions.config import parse_session_config
from sessions.seekers import Evaluation
from sessions.store import open_store
from testing.store import FAST_HASHER, telemetry

SECONDS = 60.0


def evaluation(k: int) -> Evaluation:
    return Evaluation(0.25 * k, 1.0 + 0.05 * k, 4.0 + 0.1 * k, 0.01 * k)


def main(url: str, progress_path: str | None = None) -> None:
    store = open_store(url, password_hasher=FAST_HASHER)
    user = store.users.create("crash test")
    cfg = parse_session_config({"duration": SECONDS})
    sid = store.sessions.start(user.id, cfg).id
    rows = telemetry(SECONDS)
    rec = store.recorder(sid)
    start = time.monotonic()
    progress = open(progress_path, "a") if progress_path else None  # noqa: SIM115
    print(json.dumps({"session": sid, "start": start}), flush=True)
    fed = evs = events = 0
    while fed < len(rows):
        now = time.monotonic() - start
        upto = min(len(rows), int(now * 1000) + 1)  # samples with t ≤ now
        if upto - fed >= 10 or upto == len(rows):
            if progress is not None:  # (a write(2): in the page cache, whatever kills us)
                progress.write(f"{float(rows[upto - 1, 0])!r}\n")  # before: a bound above
                progress.flush()
            rec.add_rows(rows[fed:upto])
            fed = upto
            t = rows[fed - 1, 0]
            while 0.25 * evs <= t:
                rec.add_evaluation(evaluation(evs))
                evs += 1
            while events <= t:
                rec.add_event(float(events), "info", {"n": events})
                events += 1
        time.sleep(0.002)
    rec.finish("completed")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else None)
