"""GET /api/health: is the service delivering, and what each camera and queue is doing.

Open without login: the bind address and the firewall protect it. 200 while ok or degraded,
503 while down (no camera delivering), so a plain HTTP probe tells down from up.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Response
from pydantic import BaseModel

from stereopose.service.api.deps import service_state
from stereopose.service.state import ServiceState, Snapshot

router = APIRouter(tags=["health"])


class CameraHealth(BaseModel):
    """One camera. last_frame_age_s: null before its first frame."""

    fps: float
    last_frame_age_s: float | None
    state: Literal["up", "down"]
    frames: int
    reconnects: int
    dropped_frames: int


class Health(BaseModel):
    """The service now. queues: messages waiting per queue (null: its probe failed);
    storage: bytes per kind of stored data; problems: why it is degraded or down."""

    status: Literal["ok", "degraded", "down"]
    uptime_s: float
    version: str
    frames: int
    people: int
    cameras: dict[str, CameraHealth]
    queues: dict[str, int | None]
    storage: dict[str, int]
    problems: list[str]


def health_of(s: Snapshot) -> Health:
    """The health answer of one snapshot."""
    return Health(
        status=s.status,
        uptime_s=s.uptime_s,
        version=s.version,
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
        problems=list(s.problems) or (["no camera delivering"] if s.status == "down" else []),
    )


@router.get("/api/health", response_model=Health, responses={503: {"model": Health}})
def health(response: Response, state: Annotated[ServiceState, Depends(service_state)]) -> Health:
    """The service's health (sync: its probes run in the thread pool, off the event loop)."""
    answer = health_of(state.snapshot())
    response.status_code = 503 if answer.status == "down" else 200
    response.headers["Cache-Control"] = "no-store"
    return answer
