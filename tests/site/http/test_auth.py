"""The console's doors, on a real server: login (200, 401, 429), every route behind it 401
without a session, bearer tokens, CSRF on cookie writes, roles, logout and the sessions a
password change or removal ends, the page's security headers, HTTPS, and no listening beyond
this machine without a user."""

from __future__ import annotations

import re
import ssl
import subprocess

import httpx
import pytest

from consoled import PASSWORDS, console_server, demo_plan, fast_hasher
from stereopose.errors import ConfigError
from stereopose.web.auth import (
    LoginLimiter,
    Sessions,
    SessionsFullError,
    TooManyAttemptsError,
)
from stereopose.web.server import ServeError, ServeSettings
from stereopose.web.users import UserStore

OPEN = {"/api/health", "/metrics", "/api/login", "/openapi.json", "/docs", "/"}


@pytest.fixture
def served(tmp_path):
    with console_server(tmp_path / "out") as s:
        yield s


def test_login_gives_a_token_and_two_strict_cookies(served):
    with httpx.Client(base_url=served.url, timeout=30) as c:
        r = c.post("/api/login", json={"username": "otto", "password": PASSWORDS["otto"]})
        assert r.status_code == 200
        body = r.json()
        assert body["username"] == "otto" and body["role"] == "operator"
        assert len(body["token"]) >= 32 and body["csrf"] and body["expires_at"] > 0
        cookies = {c.split("=", 1)[0]: c for c in r.headers.get_list("set-cookie")}
        session, csrf = cookies["stereopose_session"], cookies["stereopose_csrf"]
        assert body["token"] in session and "HttpOnly" in session
        assert "samesite=strict" in session.lower() and "Path=/" in session
        assert "Secure" not in session  # plain HTTP here; see the HTTPS test
        assert body["csrf"] in csrf and "HttpOnly" not in csrf
        assert c.get("/api/me").json() == {
            "username": "otto",
            "role": "operator",
            "expires_at": body["expires_at"],
        }
        assert r.headers["cache-control"] == "no-store"


def test_a_wrong_password_and_an_unknown_name_get_the_same_401(served):
    with httpx.Client(base_url=served.url, timeout=30) as c:
        wrong = c.post("/api/login", json={"username": "otto", "password": "not-his-password"})
        unknown = c.post("/api/login", json={"username": "nobody", "password": "whatever-pw"})
        assert wrong.status_code == unknown.status_code == 401
        assert wrong.json() == unknown.json()
        assert "set-cookie" not in wrong.headers
        assert c.get("/api/me").status_code == 401


def test_five_failures_from_one_address_then_429_with_retry_after(served):
    with httpx.Client(base_url=served.url, timeout=30) as c:
        for n in range(5):
            r = c.post("/api/login", json={"username": f"guess{n}", "password": "guess-pw-x"})
            assert r.status_code == 401
        r = c.post("/api/login", json={"username": "otto", "password": PASSWORDS["otto"]})
        assert r.status_code == 429  # refused before the password is looked at
        assert 1 <= int(r.headers["retry-after"]) <= 60


def test_the_limiter_throttles_addresses_then_accounts_and_forgets_after_its_window():
    now = [0.0]
    limiter = LoginLimiter(
        window_s=60, max_failures=5, per_hour=60, burst=8, pair_s=600, clock=lambda: now[0]
    )
    for _ in range(5):
        limiter.end(limiter.begin("a", "ann"), ok=False)
    with pytest.raises(TooManyAttemptsError, match="address") as refused:
        limiter.begin("a", "bob")  # the address, for any name
    assert refused.value.retry_after == 60
    limiter.end(limiter.begin("b", "ann"), ok=True)  # not the name from elsewhere
    now[0] = 45.5
    with pytest.raises(TooManyAttemptsError) as refused:
        limiter.begin("a", "ann")
    assert refused.value.retry_after == 15
    now[0] = 60.0  # the account has 3 + 1 tokens (one a minute)
    for _ in range(4):
        limiter.end(limiter.begin("c", "ann"), ok=False)
    with pytest.raises(TooManyAttemptsError, match="account") as refused:
        limiter.begin("c", "ann")  # an address that failed for ann waits for a token
    assert refused.value.retry_after == 60
    clean = limiter.begin("d", "ann")  # one that did not is still checked, one at a time
    with pytest.raises(TooManyAttemptsError, match="account"):
        limiter.begin("d", "ann")
    limiter.end(clean, ok=True)
    limiter.end(limiter.begin("d", "ann"), ok=True)  # a success leaves it clean
    assert limiter.checked == 12 and limiter.refused == 4 and limiter.clean == 2
    now[0] = 120.0
    limiter.end(limiter.begin("c", "ann"), ok=False)  # a token came back, c's window passed


def _routes(app) -> list[tuple[str, str]]:
    out = []
    for path, ops in app.openapi()["paths"].items():
        for method in ops:
            out.append((method.upper(), re.sub(r"\{[^}]+\}", "1", path)))
    return out


def test_every_route_but_the_open_ones_is_401_without_a_session(served):
    routes = [(m, p) for m, p in _routes(served.server.app) if p not in OPEN]
    assert {p for _, p in routes} >= {
        "/api/people",
        "/api/events",
        "/api/events.csv",
        "/api/events/1/ack",
        "/api/cameras",
        "/api/zones",
        "/api/cameras/1/snapshot.jpg",
        "/api/clips/1",
        "/api/live",
        "/api/users",
        "/api/users/1",
        "/api/users/1/password",
        "/api/me",
        "/api/logout",
    }
    with httpx.Client(base_url=served.url, timeout=30) as c:
        for method, path in routes:
            for headers in (
                {},
                {"Authorization": "Bearer not-a-token"},
                {"Cookie": "stereopose_session=not-a-token"},
            ):
                r = c.request(method, path, headers=headers, json={})
                assert r.status_code == 401, (method, path, headers, r.text)
        for path in ("/api/health", "/metrics", "/", "/login", "/docs", "/openapi.json"):
            assert c.get(path).status_code in (200, 503), path  # health: 503 with no camera


def test_a_bearer_token_works_without_cookie_or_csrf(served):
    with httpx.Client(base_url=served.url, timeout=30) as c:
        login = {"username": "otto", "password": PASSWORDS["otto"]}
        token = c.post("/api/login", json=login).json()["token"]
    with httpx.Client(
        base_url=served.url, timeout=30, headers={"Authorization": f"Bearer {token}"}
    ) as c:
        assert c.get("/api/me").json()["username"] == "otto"
        assert c.get("/api/events").status_code == 200
        assert c.post("/api/events/123456/ack").status_code == 404  # no CSRF asked: a bearer


def test_a_cookie_write_needs_the_csrf_header(served):
    c = served.client("otto")
    csrf = c.headers.pop("X-CSRF-Token")
    try:
        assert c.post("/api/events/123456/ack").status_code == 403
        wrong = csrf[:-1] + ("y" if csrf.endswith("x") else "x")  # never the token itself
        r = c.post("/api/events/123456/ack", headers={"X-CSRF-Token": wrong})
        assert r.status_code == 403
        assert c.post("/api/events/123456/ack", headers={"X-CSRF-Token": csrf}).status_code == 404
        assert c.get("/api/events").status_code == 200  # reads need none
    finally:
        c.close()


def test_roles_viewer_reads_operator_acks_admin_manages_users(served):
    viewer, operator, admin = (served.client(u) for u in ("vera", "otto", "ada"))
    try:
        assert viewer.get("/api/events").status_code == 200
        assert viewer.post("/api/events/1/ack").status_code == 403
        assert operator.post("/api/events/999999/ack").status_code == 404
        for c in (viewer, operator):
            assert c.get("/api/users").status_code == 403
            new = {"username": "eve", "password": "eve-pass-123", "role": "admin"}
            assert c.post("/api/users", json=new).status_code == 403
            assert c.delete("/api/users/vera").status_code == 403
        assert [u["username"] for u in admin.get("/api/users").json()] == ["ada", "otto", "vera"]
        r = admin.post(
            "/api/users", json={"username": "eve", "password": "eve-pass-123", "role": "viewer"}
        )
        assert r.status_code == 201 and r.json()["role"] == "viewer"
        dup = admin.post(
            "/api/users", json={"username": "eve", "password": "eve-pass-123", "role": "viewer"}
        )
        assert dup.status_code == 409
        short = admin.post(
            "/api/users", json={"username": "sam", "password": "short", "role": "viewer"}
        )
        assert short.status_code == 422 and "too short" in short.text
        assert admin.delete("/api/users/eve").status_code == 204
        assert admin.delete("/api/users/eve").status_code == 404
        assert admin.delete("/api/users/ada").status_code == 409  # the last admin
    finally:
        for c in (viewer, operator, admin):
            c.close()


def test_logout_ends_the_session_and_clears_the_cookies(served):
    c = served.client("vera")
    try:
        token = c.cookies["stereopose_session"]
        r = c.post("/api/logout")
        assert r.status_code == 204
        assert all(
            "Max-Age=0" in h or "expires" in h.lower() for h in r.headers.get_list("set-cookie")
        )
        bearer = {"Authorization": f"Bearer {token}"}
        assert httpx.get(served.url + "/api/me", headers=bearer).status_code == 401
    finally:
        c.close()


def test_a_password_change_or_a_removal_ends_that_users_sessions(served):
    vera, otto = served.client("vera"), served.client("otto")
    try:
        store = UserStore.in_folder(served.out, hasher=fast_hasher())  # the CLI's view
        store.set_password("vera", "a-new-password")
        assert vera.get("/api/me").status_code == 401
        assert otto.get("/api/me").status_code == 200
        store.remove("otto")
        assert otto.get("/api/me").status_code == 401
        store.add("nina", "nina-password", "viewer")  # added while it runs: seen at once
        nina = {"username": "nina", "password": "nina-password"}
        r = httpx.post(served.url + "/api/login", json=nina, timeout=30)
        assert r.status_code == 200
    finally:
        vera.close()
        otto.close()


def test_own_password_change_needs_the_old_one(served):
    c = served.client("vera")
    try:
        r = c.post("/api/users/vera/password", json={"password": "vera-new-pass"})
        assert r.status_code == 403
        change = {"password": "x-new-pass-1", "old_password": PASSWORDS["vera"]}
        r = c.post("/api/users/otto/password", json=change)
        assert r.status_code == 403
        change = {"password": "vera-new-pass", "old_password": PASSWORDS["vera"]}
        r = c.post("/api/users/vera/password", json=change)
        assert r.status_code == 204
        assert c.get("/api/me").status_code == 401  # its own sessions end too
        vera = {"username": "vera", "password": "vera-new-pass"}
        r = httpx.post(served.url + "/api/login", json=vera, timeout=30)
        assert r.status_code == 200
    finally:
        c.close()


def test_sessions_are_bounded_and_expire():
    store = UserStore.__new__(UserStore)  # a store answering one user, without a file
    from stereopose.web.users import User

    ann = User("ann", "viewer", 0.0, 0.0, "stamp")
    store.get = lambda name: ann if name == "ann" else None
    now = [1000.0]
    sessions = Sessions(store, lifetime_s=100, idle_s=30, max_sessions=3, clock=lambda: now[0])
    tokens = [sessions.create(ann)[0] for _ in range(4)]
    assert len(sessions) == 3 and sessions.evicted == 1
    assert sessions.find(tokens[0]) is None and sessions.find(tokens[1]) is not None
    now[0] += 31
    assert sessions.find(tokens[2]) is None  # idle too long
    t = sessions.create(ann)[0]
    for _ in range(4):
        now[0] += 20
        assert sessions.find(t) is not None  # kept alive by use...
    now[0] += 20
    assert sessions.find(t) is None  # ...until its absolute expiry, 100 s after its login


def test_a_full_session_table_is_shared_fairly():
    from stereopose.web.users import User

    roles = {"ann": "viewer", "bea": "viewer", "oli": "operator", "ada": "admin"}
    people = {n: User(n, r, 0.0, 0.0, "stamp") for n, r in roles.items()}
    store = UserStore.__new__(UserStore)  # a store answering these users, without a file
    store.get = people.get
    sessions = Sessions(store, max_sessions=6, per_user=3)
    ann = [sessions.create(people["ann"])[0] for _ in range(5)]  # her own oldest go
    assert sessions.count("ann") == 3 and sessions.find(ann[1]) is None
    oli = [sessions.create(people["oli"])[0] for _ in range(3)]
    sessions.create(people["bea"])  # full: the one holding the most (ann) loses her oldest
    assert sessions.count("ann") == 2 and sessions.find(ann[2]) is None
    sessions.create(people["ada"])  # a viewer's before an operator's
    sessions.create(people["ada"])
    assert (sessions.count("ann"), sessions.count("bea")) == (0, 1)
    assert all(sessions.find(t) is not None for t in oli)
    sessions.create(people["ada"])  # only viewers left to lose: ann's or bea's last
    assert sessions.count("ann") + sessions.count("bea") == 0 and len(sessions) == 6
    with pytest.raises(SessionsFullError):  # a viewer never ends an operator's or admin's
        sessions.create(people["bea"])
    assert all(sessions.find(t) is not None for t in oli) and sessions.count("ada") == 3


def test_the_page_carries_its_security_headers(served):
    with httpx.Client(base_url=served.url, timeout=30) as c:
        for path in ("/", "/login", "/console/plotly.min.js"):
            r = c.get(path)
            assert r.status_code == 200, path
            assert "default-src 'self'" in r.headers["content-security-policy"]
            assert "'unsafe-inline'" not in r.headers["content-security-policy"]
            assert r.headers["x-frame-options"] == "DENY"
            assert r.headers["referrer-policy"] == "no-referrer"
        assert c.get("/console/plotly.min.js").content.startswith(b"/**")


def _self_signed(folder) -> tuple[str, str]:
    cert, key = folder / "cert.pem", folder / "key.pem"
    subprocess.run(
        [
            "openssl",
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-days",
            "2",
            "-subj",
            "/CN=127.0.0.1",
            "-addext",
            "subjectAltName=IP:127.0.0.1",
            "-keyout",
            str(key),
            "-out",
            str(cert),
        ],
        check=True,
        capture_output=True,
    )
    key.chmod(0o600)
    return str(cert), str(key)


def test_https_with_a_certificate_and_key(tmp_path):
    cert, key = _self_signed(tmp_path)
    settings = ServeSettings(port=0, certificate=cert, key=key)
    with console_server(tmp_path / "out", settings=settings) as s:
        assert s.url.startswith("https://127.0.0.1:")
        tls = ssl.create_default_context(cafile=cert)
        with httpx.Client(base_url=s.url, verify=tls, timeout=30) as c:
            r = c.post("/api/login", json={"username": "ada", "password": PASSWORDS["ada"]})
            assert r.status_code == 200
            assert all("Secure" in h for h in r.headers.get_list("set-cookie"))
            assert c.get("/api/me").json()["username"] == "ada"
            # a browser that saw the console over HTTPS never tries it in clear again
            for path in ("/api/health", "/console/", "/api/nothing"):
                hsts = c.get(path).headers.get("strict-transport-security", "")
                assert hsts.startswith("max-age=") and int(hsts.split("=")[1]) >= 15_552_000
        with pytest.raises(httpx.HTTPError):  # plain HTTP is not answered
            httpx.get(s.url.replace("https", "http") + "/api/health", timeout=5)


@pytest.mark.realdata  # the real demo's configuration
def test_the_configuration_checks_certificate_and_key(tmp_path):
    cert, key = _self_signed(tmp_path)
    plan = demo_plan(tmp_path)
    config = plan.config_path
    text = config.read_text()

    def with_serve(extra: str):
        config.write_text(text.replace("[serve]\n", f"[serve]\n{extra}\n", 1))
        return demo_plan.__globals__["plan_serve"](config)

    good = with_serve(f'certificate = "{cert}"\nkey = "{key}"')
    assert good.http.tls and good.http.certificate == cert
    with pytest.raises(ConfigError, match=r"serve\.certificate and serve\.key: give both"):
        with_serve(f'certificate = "{cert}"')
    with pytest.raises(ConfigError, match=r"serve\.key: cannot read .*missing\.pem"):
        with_serve(f'certificate = "{cert}"\nkey = "{tmp_path / "missing.pem"}"')
    (tmp_path / "key.pem").chmod(0o644)
    with pytest.raises(ConfigError, match=r"serve\.key: .* readable by every user"):
        with_serve(f'certificate = "{cert}"\nkey = "{key}"')
    (tmp_path / "key.pem").chmod(0o600)
    with pytest.raises(ConfigError, match=r"not a PEM certificate and its key"):
        with_serve(f'certificate = "{key}"\nkey = "{key}"')


def test_no_listening_beyond_this_machine_without_a_user(tmp_path):
    with (
        pytest.raises(ServeError, match=r"serve\.host '0\.0\.0\.0'.*no user.*stereopose users add"),
        console_server(tmp_path / "a", users=False, settings=ServeSettings(host="0.0.0.0", port=0)),
    ):
        pass
    with console_server(tmp_path / "b", users=False) as s:  # loopback: allowed, nobody can log in
        assert httpx.get(s.url + "/api/health").status_code == 503
    with console_server(tmp_path / "c", settings=ServeSettings(host="0.0.0.0", port=0)) as s:
        port = s.server.port
        r = httpx.post(
            f"http://127.0.0.1:{port}/api/login",
            json={"username": "ada", "password": PASSWORDS["ada"]},
        )
        assert r.status_code == 200


def test_a_damaged_users_file_lets_nobody_in_and_says_so(served):
    c = served.client("vera")
    try:
        (served.out / "users.json").write_text("{damaged")
        r = c.get("/api/me")
        assert r.status_code == 503 and "users cannot be read" in r.json()["detail"]
        r = c.post("/api/login", json={"username": "vera", "password": PASSWORDS["vera"]})
        assert r.status_code == 503
        assert "set-cookie" not in r.headers
    finally:
        c.close()
