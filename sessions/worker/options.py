"""How the worker runs: plain validated data, pickled to the worker process; the server's
settings nest it (``worker.*``). The session's own loop rate comes from its config."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

LIVE_RATE_MAX = 5000.0  # Hz: the fastest loop the live worker is built to keep (the engine
# itself simulates up to SessionConfig's bound)


class WorkerOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    ring_capacity: int = Field(1 << 15, ge=1024, le=1 << 24, description="records (32 s at 1 kHz)")
    spin_us: float = Field(
        200.0, ge=0, le=5000.0, description="spin on the clock this long before each deadline, µs"
    )
    cpu: int | None = Field(None, ge=0, description="pin the worker to this CPU")
    realtime: bool = Field(True, description="ask for SCHED_FIFO (quietly refused if not allowed)")
    priority: int = Field(50, ge=1, le=99, description="SCHED_FIFO priority")
    timer_slack_ns: int | None = Field(
        1000, ge=1, description="prctl(PR_SET_TIMERSLACK): sharper sleeps, ns"
    )
    stop_ramp: float = Field(0.5, gt=0, le=10.0, description="torque ramp of a controlled stop, s")
    catch_up_max: float = Field(
        0.1,
        gt=0,
        le=1.0,
        description="s of missed periods the loop steps late on a free-running machine (a real "
        "drive); a longer stall ends the session, zero torque",
    )
    heartbeat_timeout: float = Field(
        0.1, gt=0, le=10.0, description="no heartbeat this long: the parent declares it lost, s"
    )
    timing_interval: float = Field(1.0, gt=0, description="s between Timing events")
    idle_poll: float = Field(
        0.002, gt=0, le=0.05, description="s between heartbeats when no session runs"
    )
    start_timeout: float = Field(
        60.0, gt=0, description="s for the worker to import, connect and report ready"
    )
