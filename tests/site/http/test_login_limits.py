"""Password guesses against a real server, from several real client addresses (127.0.0.x):
throttled by address first, per account counted before the hash (a parallel burst holds),
nobody locked out by another's failures, the own-password change within the same limit, the
password policy (API and `stereopose users`), and `Cache-Control: no-store` on every answer
that carries users or sessions."""

from __future__ import annotations

import json
import threading

import httpx
import pytest
from argon2 import PasswordHasher

from consoled import PASSWORDS, console_server, fast_hasher
from stereopose.login_limit import ACCOUNT_BURST, MAX_FAILURES
from stereopose.web.connections import ConnectionLimits


class CountingHasher(PasswordHasher):
    """argon2id as the store uses it, counting the passwords it checks."""

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.checked = 0
        self._lock = threading.Lock()

    def verify(self, hash, password) -> bool:  # argon2's own names
        with self._lock:
            self.checked += 1
        return super().verify(hash, password)


@pytest.fixture
def served(tmp_path):
    with console_server(tmp_path / "out") as s:
        yield s


def _from(served, n: int, **kw) -> httpx.Client:
    """A client whose connections come from 127.0.0.`n` (a client address of its own)."""
    transport = httpx.HTTPTransport(local_address=f"127.0.0.{n}")
    return httpx.Client(base_url=served.url, timeout=60, transport=transport, **kw)


def _login(c: httpx.Client, user: str, password: str | None = None) -> httpx.Response:
    return c.post("/api/login", json={"username": user, "password": password or PASSWORDS[user]})


def test_failures_from_one_address_throttle_it_not_the_operator_elsewhere(served):
    with _from(served, 2) as guesser, _from(served, 3) as operator:
        for _ in range(MAX_FAILURES):
            assert _login(guesser, "otto", "not-his-password").status_code == 401
        r = _login(guesser, "otto")  # even the right one, from there: refused unchecked
        assert r.status_code == 429 and 1 <= int(r.headers["retry-after"]) <= 60
        assert _login(guesser, "vera").status_code == 429  # the address, for any name
        r = _login(operator, "otto")  # the operator, from their own address
        assert r.status_code == 200, r.text
        assert operator.get("/api/me").json()["username"] == "otto"


@pytest.fixture
def roomy(tmp_path):
    """A server whose per-address connection cap lets 24 connections of one address in (the
    login limit, not the connection table, is what the burst meets)."""
    with console_server(tmp_path / "out", limits=ConnectionLimits(max_per_address=32)) as s:
        yield s


def test_a_parallel_burst_of_wrong_logins_checks_at_most_the_limit(roomy):
    served = roomy
    hasher = CountingHasher(time_cost=2, memory_cost=16 * 1024, parallelism=1)  # a slow hash
    served.console.users.hasher = hasher
    answers: list[int] = []
    start = threading.Barrier(24)

    def guess(n: int) -> None:
        with _from(served, 2) as c:
            start.wait()
            answers.append(_login(c, "otto", f"guess-number-{n}").status_code)

    threads = [threading.Thread(target=guess, args=(n,)) for n in range(24)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert sorted(answers) == [401] * MAX_FAILURES + [429] * (24 - MAX_FAILURES)
    assert hasher.checked == MAX_FAILURES  # counted before the hash: the rest never checked


def test_a_guessed_account_still_lets_the_right_password_in_from_a_clean_address(served):
    hasher = CountingHasher(time_cost=1, memory_cost=8 * 1024, parallelism=1)
    served.console.users.hasher = hasher
    clients = [_from(served, n) for n in range(10, 10 + ACCOUNT_BURST // MAX_FAILURES)]
    late, right = _from(served, 40), _from(served, 41)
    try:
        for c in clients:  # the account's burst spent, each address at its own limit
            for _ in range(MAX_FAILURES):
                assert _login(c, "otto", "still-not-it").status_code == 401
        assert _login(late, "otto", "still-not-it").status_code == 401  # clean: checked once
        r = _login(late, "otto", "another-guess")  # now it has failed for otto: it waits
        assert r.status_code == 429 and "account" in r.json()["detail"]
        assert hasher.checked == ACCOUNT_BURST + 1
        assert _login(right, "otto").status_code == 200  # nobody else is locked out
        assert _login(late, "vera").status_code == 200  # nor the guesser's other names
    finally:
        for c in [*clients, late, right]:
            c.close()


def test_the_own_password_change_is_limited_like_a_login(served):
    hasher = CountingHasher(time_cost=1, memory_cost=8 * 1024, parallelism=1)
    with _from(served, 2) as c:
        r = _login(c, "vera")
        c.headers["X-CSRF-Token"] = r.json()["csrf"]
        served.console.users.hasher = hasher
        for n in range(MAX_FAILURES):
            change = {"password": "vera-new-pass", "old_password": f"wrong-old-{n}"}
            assert c.post("/api/users/vera/password", json=change).status_code == 403
        change = {"password": "vera-new-pass", "old_password": PASSWORDS["vera"]}
        r = c.post("/api/users/vera/password", json=change)
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1
        assert r.headers["cache-control"] == "no-store"
        assert hasher.checked == MAX_FAILURES
        assert _login(c, "otto").status_code == 429  # the same address's failures
    with _from(served, 3) as other:
        assert _login(other, "vera").status_code == 200  # her password did not change


def test_weak_passwords_are_refused_and_an_old_weak_one_still_logs_in(served):
    with _from(served, 2) as admin:
        admin.headers["X-CSRF-Token"] = _login(admin, "ada").json()["csrf"]
        for password, why in (
            ("short-pw-1", "too short"),
            ("password1234", "too common"),
            ("Qwerty123456!", "too common"),
            ("aaaabbbbaaaa", "too simple"),
        ):
            new = {"username": "sam", "password": password, "role": "viewer"}
            r = admin.post("/api/users", json=new)
            assert r.status_code == 422 and why in r.json()["detail"], (password, r.text)
            r = admin.post("/api/users/vera/password", json={"password": password})
            assert r.status_code == 422 and why in r.json()["detail"]
    with _from(served, 3) as vera:
        vera.headers["X-CSRF-Token"] = _login(vera, "vera").json()["csrf"]
        change = {"password": "iloveyou2024", "old_password": PASSWORDS["vera"]}
        r = vera.post("/api/users/vera/password", json=change)
        assert r.status_code == 422 and "too common" in r.json()["detail"]
        assert vera.get("/api/me").status_code == 200  # nothing changed
    users = json.loads(served.console.users.path.read_text())
    users["users"]["old"] = {
        "role": "viewer",
        "hash": fast_hasher().hash("password"),
        "created": 0.0,
        "changed": 0.0,
    }  # set before the policy
    served.console.users.path.write_text(json.dumps(users))
    with _from(served, 4) as old:
        assert _login(old, "old", "password").status_code == 200


def test_answers_carrying_users_or_sessions_are_no_store(served):
    with _from(served, 2) as c:
        answers = [_login(c, "nobody", "wrong-password-x"), _login(c, "ada")]
        c.headers["X-CSRF-Token"] = answers[-1].json()["csrf"]
        answers += [
            c.get("/api/me"),
            c.get("/api/users"),
            c.post(
                "/api/users",
                json={"username": "sam", "password": "sam-secret-12", "role": "viewer"},
            ),
            c.post("/api/users/sam/password", json={"password": "sam-secret-13"}),
            c.post("/api/users", json={"username": "x", "password": "1", "role": "viewer"}),
            c.delete("/api/users/sam"),
            c.delete("/api/users/sam"),
            c.post("/api/logout"),
            c.get("/api/me"),  # 401 now
        ]
    assert [r.status_code for r in answers] == [
        401,
        200,
        200,
        200,
        201,
        204,
        422,
        204,
        404,
        204,
        401,
    ]
    for r in answers:
        assert r.headers.get("cache-control") == "no-store", (r.request.url, r.status_code)


def test_a_login_flood_from_many_addresses_never_holds_up_health_or_a_session(served):
    served.console.users.hasher = CountingHasher(
        time_cost=3, memory_cost=32 * 1024, parallelism=1
    )  # a slow hash: a real flood
    with _from(served, 3) as operator:
        assert _login(operator, "otto").status_code == 200  # logged in before the flood
        answers: list[httpx.Response] = []
        start = threading.Barrier(40)

        def guess(n: int) -> None:
            with _from(served, 10 + n) as c:  # 40 addresses, one wrong guess each
                start.wait()
                answers.append(_login(c, "vera", f"guess-number-{n}"))

        threads = [threading.Thread(target=guess, args=(n,)) for n in range(40)]
        for t in threads:
            t.start()
        try:
            # while the checks still queue: refused at once with a time to come back
            for _ in range(200):
                if any(r.status_code == 503 for r in answers):
                    break
                threading.Event().wait(0.05)
            busy = [r for r in answers if r.status_code == 503]
            assert busy, [r.status_code for r in answers]
            assert all(int(r.headers["retry-after"]) >= 1 for r in busy)
            # health and the logged-in console answer within a deadline meanwhile
            with httpx.Client(base_url=served.url, timeout=2.0) as probe:
                assert probe.get("/api/health").status_code in (200, 503)
            assert operator.get("/api/me", timeout=2.0).json()["username"] == "otto"
        finally:
            for t in threads:
                t.join(120)
    codes = sorted({r.status_code for r in answers})
    assert len(answers) == 40 and set(codes) <= {401, 503}
    checked = served.console.users.hasher.checked
    # the operator's own login, and each 401: a 503 checked nothing
    assert checked == 1 + sum(r.status_code == 401 for r in answers)
    assert served.console.users.checks_refused == sum(r.status_code == 503 for r in answers)
