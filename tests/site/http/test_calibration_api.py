"""GET /api/calibration and POST /api/calibration/{camera}/accept on a real server: a pose
proposed for a knocked camera (calibration_auto = false) shown to every role, accepted by an
admin only (403 for operators and viewers, CSRF for cookie sessions), applied at the next
step; 404 for a camera with nothing proposed; 503 before the keeper runs."""

from __future__ import annotations

import httpx
import pytest

from consoled import PASSWORDS, console_server
from knocked import proposed_keeper
from stereopose.site.health.calib_keeper import KeeperDesk
from stereopose.site.http.app import Desks

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def proposed(tmp_path_factory):
    return proposed_keeper(tmp_path_factory.mktemp("calib"))


def _login(c: httpx.Client, name: str) -> str:
    return c.post("/api/login", json={"username": name, "password": PASSWORDS[name]}).json()[
        "token"
    ]


def test_the_proposal_is_shown_and_only_an_admin_accepts_it(proposed, tmp_path) -> None:
    keeper, applied, steps = proposed
    desk = KeeperDesk()
    desk.attach(keeper)
    with (
        console_server(tmp_path / "out", app_kw={"desks": Desks(calibration=desk)}) as s,
        httpx.Client(base_url=s.url, timeout=30) as c,
    ):
        for name in ("vera", "otto"):
            auth = {"Authorization": f"Bearer {_login(c, name)}"}
            body = c.get("/api/calibration", headers=auth).json()
            assert body["running"] and not body["auto"]
            assert 1.3 < body["proposals"]["cam02"]["turned_deg"] < 1.7
            assert c.post("/api/calibration/cam02/accept", headers=auth).status_code == 403
        # a cookie session without its CSRF header is refused
        r = c.post("/api/login", json={"username": "ada", "password": PASSWORDS["ada"]})
        assert c.post("/api/calibration/cam02/accept").status_code == 403
        csrf = {"X-CSRF-Token": r.json()["csrf"]}
        assert c.post("/api/calibration/cam01/accept", headers=csrf).status_code == 404
        assert c.post("/api/calibration/bad%20name/accept", headers=csrf).status_code == 422
        ok = c.post("/api/calibration/cam02/accept", headers=csrf)
        assert ok.status_code == 200 and ok.json() == {"accepted": "cam02", "by": "ada"}
    assert not applied
    events = keeper.update(len(steps), len(steps) * 0.08, steps[-1], [])
    assert [e.type for e in events] == ["calibration_corrected"] and applied
    assert events[0].result["accepted_by"] == "ada"


def test_before_the_keeper_runs_the_api_says_so(tmp_path) -> None:
    with (
        console_server(tmp_path / "out", app_kw={"desks": Desks(calibration=KeeperDesk())}) as s,
        httpx.Client(base_url=s.url, timeout=30) as c,
    ):
        admin = {"Authorization": f"Bearer {_login(c, 'ada')}"}
        assert c.get("/api/calibration", headers=admin).json() == {"running": False}
        assert c.post("/api/calibration/cam02/accept", headers=admin).status_code == 503
