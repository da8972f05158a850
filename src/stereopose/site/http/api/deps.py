"""Dependencies shared by the routers: the running parts the app was created with."""

from __future__ import annotations

from fastapi import Request
from prometheus_client import CollectorRegistry

from stereopose.site.health.state import ServiceState


def service_state(request: Request) -> ServiceState:
    """The ServiceState given to create_app."""
    return request.app.state.service


def metrics_registry(request: Request) -> CollectorRegistry:
    """The app's own metrics registry."""
    return request.app.state.metrics_registry
