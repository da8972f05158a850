"""`serve`'s standing parts built in one place (site.service.SiteService): each part made with
what it needs, started in one ordered list and closed in its mirror, and nothing set on the
service once it is built; the frame loop's parts reach the standing ones through their desks
(site.handover), attached as they start and detached as they close."""

from __future__ import annotations

import json

import pytest

from brokers import free_port
from stereopose.pipeline.demo import write_serve_demo_config
from stereopose.site.plan import plan_serve
from stereopose.site.restart import Resume
from stereopose.site.service import SiteService
from waiting import http_get

pytestmark = pytest.mark.realdata


def _health(url: str) -> str:
    code, body = http_get(url + "/api/health")
    assert code in (200, 503), code
    return json.loads(body)["status"]


@pytest.fixture
def service(tmp_path):
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", free_port(), imgsz=320)
    plan = plan_serve(config)
    built = SiteService(plan, Resume.from_log(plan.events_db))
    yield built
    built.close()


def test_the_standing_parts_start_in_one_order_and_close_in_its_mirror(service) -> None:
    names = [p.name for p in service.parts.order]
    assert names == [
        "the HTTP server",
        "the console",
        "the output folder",
        "the site desk",
        "the storage maintainer",
        "the zone state's sources",
    ]
    assert service.parts.started == []
    with pytest.raises(RuntimeError, match="not started"):
        service.server.url  # noqa: B018  # made, not listening
    url = service.start()
    assert service.parts.started == names
    assert _health(url) != "ok"  # it answers: no step yet, no camera
    service.close()
    assert service.parts.started == []
    assert http_get(url + "/api/health")[0] == 0  # the HTTP server closed last


def test_nothing_is_set_on_the_service_once_built(service) -> None:
    before = dict(vars(service))
    for name in ("console", "power", "tickets", "parts", "anything_new"):
        with pytest.raises(AttributeError, match=f"built: {name} cannot be set"):
            setattr(service, name, None)
    service.start()
    service.close()
    after = vars(service)
    assert after.keys() == before.keys()
    assert all(after[k] is before[k] for k in before)  # the same parts, none replaced


def test_the_api_reaches_the_loops_parts_only_while_attached(service) -> None:
    """The app is made with the service's desks (never given another later); before the frame
    loop runs, each says there is none, and a part attached is there until detached."""
    state = service.server.app.state
    assert state.incidents is service.desk
    assert state.calibration is service.calibration_desk
    assert state.warnings is service.warnings
    desks = (service.desk, service.calibration_desk, service.warnings)
    assert [d.current for d in desks] == [None, None, None]
    assert not service.desk.running
    url = service.start()
    assert _health(url) != "ok"
    marker = object()
    service.warnings.attach(marker)  # type: ignore[arg-type]  # any part: the desk holds it
    assert service.warnings.onsite is marker
    service.warnings.detach()
    assert service.warnings.onsite is None
