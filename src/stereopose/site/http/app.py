"""The service's HTTP app: `create_app(state, ...)` takes the running parts and mounts one
router per resource (site.http.api): /api/health, /metrics and the offline OpenAPI page /docs
(open), and the operator console: its page (/, /login, /console/...), /api/login and the
routes behind the login (people, events, cameras, zones, clips, the live channel, users),
over `console` (site.http.web.Console; without one, those routes answer 503).

Every answer is JSON or the resource's own format, never a traceback page: debug is off, unknown
paths are 404 and wrong methods 405 as {"detail": ...}, and an error inside a route is a 500
{"detail": "internal error"} (its traceback goes to the log). No answer names a file of the
server (web.error_answers): an error whose message holds a path is answered with a
generic one, the message going to the log. With allowed_hosts, a request for another Host is
refused (web.hosts).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from fastapi import FastAPI
from prometheus_client import CollectorRegistry

from stereopose import __version__
from stereopose.site.desk import IncidentDesk
from stereopose.site.health.metrics import make_registry
from stereopose.site.health.state import ServiceState
from stereopose.site.http.api import (
    cameras,
    clips,
    docs,
    events,
    health,
    live,
    metrics,
    page,
    people,
    users,
    zones,
)
from stereopose.tickets import TicketDesk
from stereopose.web import error_answers
from stereopose.web import login as auth
from stereopose.web.error_answers import internal_error
from stereopose.web.hosts import HostCheck
from stereopose.web.limits import MAX_BODY_BYTES, RequestLimits

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Desks:
    """What the API acts through. incidents: the incident desk (site.desk: the incident book
    once it runs; None: a desk of its own, never attached); tickets: the site's tickets
    (stereopose.tickets.TicketDesk; None: no site, the tickets API answers 503); calibration:
    the calibration keeper's desk (site.health.calib_keeper.KeeperDesk; None: the calibration
    API answers that it is not running); site: the running site's desk (site.site_desk.
    SiteDesk; None: the site API answers 503); warnings: the warnings on site's desk
    (site.http.api.warnings.WarningsDesk; None: the warnings API answers 503)."""

    incidents: IncidentDesk | None = None
    tickets: TicketDesk | None = None
    calibration: object | None = None
    site: object | None = None
    warnings: object | None = None


def create_app(
    state: ServiceState,
    *,
    registry: CollectorRegistry | None = None,
    max_body_bytes: int = MAX_BODY_BYTES,
    lifespan: Callable[[FastAPI], Any] | None = None,
    console: object | None = None,
    allowed_hosts: Iterable[str] | None = None,
    desks: Desks = Desks(),
) -> FastAPI:
    """The app over `state`. registry: the metrics registry (None: one of its own over
    `state`); max_body_bytes: larger request bodies are refused (413); lifespan: what starts
    and stops with the server (the frame loop, the sinks); console: the console's parts
    (site.http.web.Console); allowed_hosts: the Host names served
    (web.hosts.allowed_hosts; None: any); desks: what the API acts through (Desks)."""
    incidents, tickets, calibration, site = (
        desks.incidents,
        desks.tickets,
        desks.calibration,
        desks.site,
    )
    app = FastAPI(
        title="stereopose",
        version=__version__,  # shown only with a session (api.docs serves /openapi.json)
        debug=False,
        docs_url=None,  # served from the package's files instead (api.docs)
        redoc_url=None,
        openapi_url=None,
        swagger_ui_oauth2_redirect_url=None,
        lifespan=lifespan,
    )
    app.state.service = state
    app.state.console = console
    app.state.incidents = incidents if incidents is not None else IncidentDesk()
    app.state.tickets = tickets
    app.state.calibration = calibration
    app.state.site = site
    app.state.warnings = desks.warnings
    app.state.metrics_registry = registry if registry is not None else make_registry(state)
    app.add_exception_handler(Exception, internal_error)
    error_answers.add_handlers(app)
    if allowed_hosts is not None:  # inside RequestLimits: its refusals get the extra headers
        app.add_middleware(HostCheck, allowed=tuple(allowed_hosts))
    app.add_middleware(RequestLimits, max_body_bytes=max_body_bytes)
    app.include_router(health.router)
    app.include_router(metrics.router)
    from stereopose.site.http.api import calibration as calib_api
    from stereopose.site.http.api import incidents, replay, tickets
    from stereopose.site.http.api import site as site_api
    from stereopose.site.http.api import warnings as warnings_api

    routers = (
        auth,
        people,
        events,
        incidents,
        tickets,
        replay,
        cameras,
        zones,
        clips,
        live,
        users,
        calib_api,
        site_api,
        warnings_api,
    )
    for router in routers:
        app.include_router(router.router)
    docs.mount_docs(app)
    page.mount_page(app)
    return app
