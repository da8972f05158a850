"""No user takes another's place, on a real server with real client connections, each user
from a client address of their own (127.0.0.x): sessions (a viewer's 1,000 logins leave the
operator's session), live streams (a viewer holding 32 never keeps an operator's alarm
channel away; places kept for operators and admins) and clip players (two per user, a freed
place back at once)."""

from __future__ import annotations

import contextlib
import json
import threading

import cv2
import httpx
import numpy as np
import pytest

from consoled import PASSWORDS, console_server, demo_plan
from stereopose.site.http.api import clips as clip_api
from stereopose.site.http.places import BUMPED, REPLACED
from stereopose.site.live import STREAMS_PER_USER
from waiting import wait_until

ADDRESS = {"vera": 2, "otto": 3, "ada": 4, "olav": 5, **{f"v{i}": 10 + i for i in range(8)}}
PASSWORDS = {
    **PASSWORDS,
    "olav": "olav-operator-1",
    **{f"v{i}": f"viewer-{i}-pass" for i in range(8)},
}


def _client(served, user: str, *, login: bool = True) -> httpx.Client:
    """A client of `user` from their own address, logged in (cookies and CSRF) when asked."""
    transport = httpx.HTTPTransport(local_address=f"127.0.0.{ADDRESS[user]}")
    c = httpx.Client(base_url=served.url, timeout=30, transport=transport)
    if login:
        r = c.post("/api/login", json={"username": user, "password": PASSWORDS[user]})
        assert r.status_code == 200, r.text
        c.headers["X-CSRF-Token"] = r.json()["csrf"]
    return c


def _add_users(served, *names: str) -> None:
    for name in names:
        served.console.users.add(name, PASSWORDS[name], "operator" if name == "olav" else "viewer")


@pytest.mark.slow  # 1,000 argon2 checks
def test_a_thousand_logins_of_a_viewer_leave_the_operators_session(tmp_path):
    with console_server(tmp_path / "out") as served:
        otto = _client(served, "otto")
        vera = _client(served, "vera", login=False)
        try:
            tokens = []
            for _ in range(1000):
                r = vera.post(
                    "/api/login", json={"username": "vera", "password": PASSWORDS["vera"]}
                )
                assert r.status_code == 200, r.text
                tokens.append(r.json()["token"])
            assert otto.get("/api/me").json()["username"] == "otto"  # still logged in
            sessions = served.console.sessions
            assert sessions.count("vera") == 10 and sessions.count("otto") == 1
            me = [
                vera.get("/api/me", headers={"Authorization": f"Bearer {t}"}).status_code
                for t in (tokens[0], tokens[989], tokens[990], tokens[-1])
            ]
            assert me == [401, 401, 200, 200]  # her own oldest went, nobody else's
        finally:
            otto.close()
            vera.close()


class _Live:
    """One /api/live stream read on a thread: its status and (event, data) pairs in order."""

    def __init__(self, client: httpx.Client) -> None:
        self.status: int | None = None
        self.messages: list[tuple[str, dict]] = []
        self.over = False
        self._client = client
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        wait_until(lambda: self.status is not None, "the live channel's answer")
        if self.status == 200:
            wait_until(lambda: self.kinds() >= {"cameras"}, "the first cameras message")

    def _read(self) -> None:
        try:
            with self._client.stream("GET", "/api/live") as r:
                kind = None
                for line in r.iter_lines():
                    if self.status is None and r.status_code != 200:
                        break
                    self.status = r.status_code
                    if line.startswith("event: "):
                        kind = line[7:]
                    elif line.startswith("data: ") and kind:
                        self.messages.append((kind, json.loads(line[6:])))
                        kind = None
                self.status = r.status_code
        except httpx.HTTPError:
            pass
        finally:
            self.over = True
            if self.status is None:
                self.status = 0

    def kinds(self) -> set[str]:
        return {k for k, _ in self.messages}

    def closed_because(self) -> str | None:
        return next((body["reason"] for k, body in self.messages if k == "closed"), None)


@pytest.mark.realdata  # the real demo's rig and site feed the live hub
def test_a_viewer_holding_many_streams_never_keeps_an_operators_alarm_channel_away(tmp_path):
    with console_server(tmp_path / "out", demo_plan(tmp_path)) as served:
        _add_users(served, "olav", *(f"v{i}" for i in range(6)))
        hub = served.console.hub
        clients = {
            u: _client(served, u)
            for u in ("vera", "otto", "ada", "olav", *(f"v{i}" for i in range(6)))
        }
        try:
            vera = [_Live(clients["vera"]) for _ in range(32)]
            assert all(s.status == 200 for s in vera)  # each newer one ends her own oldest
            wait_until(lambda: sum(not s.over for s in vera) == STREAMS_PER_USER, "her oldest end")
            assert {s.closed_because() for s in vera[:-STREAMS_PER_USER]} == {REPLACED}
            assert hub.clients == STREAMS_PER_USER
            otto = [_Live(clients["otto"])]
            assert otto[0].status == 200  # the operator's alarm channel is served

            # the viewers' share (32 - 8) full: a viewer is refused, operators still served
            viewers = [_Live(clients[f"v{i}"]) for i in range(5) for _ in range(STREAMS_PER_USER)]
            assert [s.status for s in viewers] == [200] * 20 and hub.clients == 25
            assert _Live(clients["v5"]).status == 503
            otto += [_Live(clients["otto"]) for _ in range(3)]
            admin = [_Live(clients["ada"]) for _ in range(4)]
            assert all(s.status == 200 for s in otto + admin) and hub.clients == 32
            first_viewer = next(s for s in vera if not s.over)

            # every place held: the oldest viewer's stream ends for another operator
            assert _Live(clients["olav"]).status == 200
            wait_until(lambda: first_viewer.over, "the oldest viewer stream ended")
            assert first_viewer.closed_because() == BUMPED and hub.clients == 32
            assert _Live(clients["v5"]).status == 503
            assert all(not s.over for s in otto + admin)  # never an operator's or admin's
        finally:
            for c in clients.values():
                c.close()
        wait_until(lambda: hub.clients == 0, "every stream closed", timeout_s=30)


def _write_clip(path, frames: int, fps: float) -> None:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (64, 48))
    for i in range(frames):
        w.write(np.full((48, 64, 3), i % 250, np.uint8))
    w.release()


class _Player:
    """A clip player held open, its first frame read; `rest()` reads it to its end."""

    def __init__(self, stack: contextlib.ExitStack, client: httpx.Client, clip: str) -> None:
        self.response = stack.enter_context(client.stream("GET", f"/api/clips/{clip}/play"))
        self.status = self.response.status_code
        self._chunks = self.response.iter_bytes()
        if self.status == 200:
            assert next(self._chunks).startswith(b"--clipframe")

    def rest(self) -> bytes:
        return b"".join(self._chunks)


def test_two_players_per_user_and_a_freed_place_back_at_once(tmp_path):
    clip = "20240501-130512_7_busbar_cam01.mp4"
    with console_server(tmp_path / "out") as served:
        (served.out / "clips").mkdir()
        _write_clip(served.out / "clips" / clip, frames=300, fps=10.0)  # 30 s: never ends here
        users = {u: _client(served, u) for u in ("vera", "otto", "ada")}
        try:
            with contextlib.ExitStack() as stack:
                vera = [_Player(stack, users["vera"], clip) for _ in range(3)]
                assert [p.status for p in vera] == [200, 200, 200]
                assert vera[0].rest().count(b"--clipframe") < 20  # her third ended her first
                assert clip_api.players.held_by("vera") == clip_api.PLAYERS_PER_USER
                otto = [_Player(stack, users["otto"], clip) for _ in range(2)]
                assert [p.status for p in otto] == [200, 200]
                refused = _Player(stack, users["ada"], clip)
                assert refused.status == 503 and refused.response.headers["retry-after"] == "5"
                otto[0].response.close()  # the client leaves mid-clip
                wait_until(lambda: len(clip_api.players) == 3, "the freed place", timeout_s=3)
                assert _Player(stack, users["ada"], clip).status == 200
        finally:
            for c in users.values():
                c.close()
        wait_until(lambda: len(clip_api.players) == 0, "every place given back", timeout_s=5)
