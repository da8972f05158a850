"""GET /metrics: Prometheus text format from the app's own registry. Open without login."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Response
from prometheus_client import CollectorRegistry

from stereopose.service.api.deps import metrics_registry
from stereopose.service.metrics import CONTENT_TYPE, exposition

router = APIRouter(tags=["metrics"])


@router.get("/metrics", response_class=Response)
def metrics(registry: Annotated[CollectorRegistry, Depends(metrics_registry)]) -> Response:
    """Every stereopose_ metric (sync: the state's probes run in the thread pool)."""
    return Response(exposition(registry), media_type=CONTENT_TYPE,
                    headers={"Cache-Control": "no-store"})  # fmt: skip
