"""GET /metrics: Prometheus text format from the app's own registry. Open without login; the
version label of stereopose_info is empty unless the scrape carries a session (a bearer
token in Prometheus' authorization settings)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response
from prometheus_client import CollectorRegistry

from stereopose.site.health.metrics import CONTENT_TYPE, VERSION_SHOWN, exposition
from stereopose.site.http.api.deps import metrics_registry
from stereopose.site.http.api.visitor import has_session

router = APIRouter(tags=["metrics"])


@router.get("/metrics", response_class=Response)
def metrics(
    request: Request, registry: Annotated[CollectorRegistry, Depends(metrics_registry)]
) -> Response:
    """Every stereopose_ metric (sync: the state's probes run in the thread pool)."""
    shown = VERSION_SHOWN.set(has_session(request))
    try:
        text = exposition(registry)
    finally:
        VERSION_SHOWN.reset(shown)
    return Response(text, media_type=CONTENT_TYPE, headers={"Cache-Control": "no-store"})
