"""GET /api/health: is the service delivering, and what each camera and queue is doing.

Open without login: the bind address and the firewall protect it. 200 while ok or degraded,
503 while down (no camera delivering), so a plain HTTP probe tells down from up. Degraded
names each alarm output (MQTT, the webhook, the event log, ...) that is failing or falling
behind in `problems`, and `outputs` gives each one's state. The version is null unless the
request carries a live session (an anonymous client learns nothing to look up).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Request, Response
from pydantic import BaseModel

from stereopose.site.health.alarm_outputs import OutputSnapshot
from stereopose.site.health.snapshots import Snapshot
from stereopose.site.health.state import ServiceState
from stereopose.site.http.api.deps import service_state
from stereopose.site.http.api.visitor import has_session

router = APIRouter(tags=["health"])


class CameraHealth(BaseModel):
    """One camera. last_frame_age_s: null before its first frame."""

    fps: float
    last_frame_age_s: float | None
    state: Literal["up", "down"]
    frames: int
    reconnects: int
    dropped_frames: int


class OutputHealth(BaseModel):
    """One alarm output. waiting: messages not delivered yet (null: not known); reason: why
    it is down (null while up); backlog_s: how long it has had messages waiting."""

    state: Literal["up", "down"]
    waiting: int | None
    reason: str | None
    backlog_s: float


class Health(BaseModel):
    """The service now. version: null without a session; queues: messages waiting per queue
    (null: its probe failed); storage: bytes per kind of stored data; outputs: each alarm
    output; problems: why it is degraded or down; alarms: the operator's alarm load
    (notifications in 10 minutes and an hour against the flood line, chattering, standing
    and open incidents: alarms.rates), null without a session or an incident book."""

    status: Literal["ok", "degraded", "down"]
    uptime_s: float
    version: str | None
    frames: int
    people: int
    cameras: dict[str, CameraHealth]
    queues: dict[str, int | None]
    storage: dict[str, int]
    problems: list[str]
    outputs: dict[str, OutputHealth]
    alarms: dict[str, Any] | None = None


def _output(o: OutputSnapshot) -> OutputHealth:
    return OutputHealth(state=o.state, waiting=o.waiting, reason=o.reason, backlog_s=o.backlog_s)


def health_of(s: Snapshot, *, show_version: bool = True) -> Health:
    """The health answer of one snapshot (show_version False: version and alarms null)."""
    return Health(
        status=s.status,
        uptime_s=s.uptime_s,
        version=s.version if show_version else None,
        frames=s.frames,
        people=s.people,
        cameras={
            c.name: CameraHealth(
                fps=c.fps,
                last_frame_age_s=c.last_frame_age_s,
                state=c.state,
                frames=c.frames,
                reconnects=c.reconnects,
                dropped_frames=c.dropped_frames,
            )
            for c in s.cameras
        },
        queues={q.name: q.size for q in s.queues},
        storage=dict(s.storage),
        outputs={o.name: _output(o) for o in s.outputs},
        problems=list(s.problems) or (["no camera delivering"] if s.status == "down" else []),
        alarms=dict(s.alarms) if show_version and s.alarms else None,
    )


@router.get("/api/health", response_model=Health, responses={503: {"model": Health}})
def health(
    request: Request, response: Response, state: Annotated[ServiceState, Depends(service_state)]
) -> Health:
    """The service's health (sync: its probes run in the thread pool, off the event loop)."""
    answer = health_of(state.snapshot(), show_version=has_session(request))
    response.status_code = 503 if answer.status == "down" else 200
    response.headers["Cache-Control"] = "no-store"
    return answer
