"""The console's users: the store (argon2id hashes, 0600, atomic, re-read on change) and
`stereopose users add|list|remove|passwd` as a process, the password on standard input."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import pytest

from consoled import fast_hasher
from stereopose.web.users import UserError, UserStore


@pytest.fixture
def store(tmp_path):
    return UserStore.in_folder(tmp_path / "out", hasher=fast_hasher())


def test_add_verify_and_the_file_holds_no_password(store):
    store.add("ann", "ann-secret-1", "operator")
    assert stat.S_IMODE(store.path.stat().st_mode) == 0o600
    text = store.path.read_text()
    assert "ann-secret-1" not in text and "$argon2id$" in text
    assert store.verify("ann", "ann-secret-1").role == "operator"
    assert store.verify("ann", "ann-secret-2") is None
    assert store.verify("bob", "ann-secret-1") is None
    assert store.verify("ann", "x" * 5000) is None
    assert [(u.name, u.role) for u in store.users()] == [("ann", "operator")]
    assert not [p for p in store.path.parent.iterdir() if p.name.endswith(".tmp")]


def test_bad_names_passwords_roles_and_a_second_add_are_refused(store):
    store.add("ann", "ann-secret-1", "viewer")
    for name in ("", "a/b", "../x", ".hidden", "x" * 33, "née", "a b"):
        with pytest.raises(UserError, match="user name"):
            store.add(name, "good-password", "viewer")
    with pytest.raises(UserError, match="empty"):
        store.add("bob", "", "viewer")
    with pytest.raises(UserError, match="too short"):
        store.add("bob", "seven77", "viewer")
    with pytest.raises(UserError, match="role"):
        store.add("bob", "good-password", "root")
    with pytest.raises(UserError, match="already exists"):
        store.add("ann", "another-password", "admin")
    assert store.get("ann").role == "viewer"


def test_passwd_and_remove_change_the_stamp_and_other_stores_see_it(store):
    other = UserStore(store.path, hasher=fast_hasher())  # another process's view
    ann = store.add("ann", "ann-secret-1", "viewer")
    assert other.get("ann").stamp == ann.stamp
    changed = store.set_password("ann", "ann-secret-2")
    assert changed.stamp != ann.stamp and other.get("ann").stamp == changed.stamp
    assert other.verify("ann", "ann-secret-2") is not None
    store.remove("ann")
    assert other.get("ann") is None and other.count() == 0
    with pytest.raises(UserError, match="no user 'ann'"):
        store.remove("ann")
    with pytest.raises(UserError, match="no user 'ann'"):
        store.set_password("ann", "ann-secret-3")


def test_a_damaged_file_is_an_error_naming_it(store):
    store.path.parent.mkdir(parents=True)
    store.path.write_text("{not json")
    with pytest.raises(UserError, match=r"users\.json: not a users file"):
        store.users()
    store.path.write_text(json.dumps({"users": {"a/b": {"role": "admin", "hash": "x"}}}))
    with pytest.raises(UserError, match="not a users file"):
        store.count()


def _users(config, *args, stdin: str = "") -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run(
        [sys.executable, "-m", "stereopose.cli", "users", *args, "--config", str(config)],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )


@pytest.mark.slow
def test_the_users_command_as_a_process(tmp_path):
    config = tmp_path / "serve.toml"
    config.write_text('output = "data"\n')
    users_json = tmp_path / "data" / "users.json"
    r = _users(config, "add", "ann", "--role", "admin", stdin="ann-secret-1\n")
    assert r.returncode == 0, r.stderr
    assert "added ann (admin)" in r.stdout and "ann-secret-1" not in r.stdout + r.stderr
    assert stat.S_IMODE(users_json.stat().st_mode) == 0o600
    r = _users(config, "add", "ann", "--role", "viewer", stdin="other-secret\n")
    assert r.returncode == 2 and "already exists" in r.stderr
    r = _users(config, "add", "bob", "--role", "viewer", stdin="short\n")
    assert r.returncode == 2 and "too short" in r.stderr
    r = _users(config, "add", "bob", "--role", "viewer", stdin="")
    assert r.returncode == 2 and "empty" in r.stderr
    r = _users(config, "add", "bob", stdin="bob-secret-1\n")
    assert r.returncode == 2 and "--role" in r.stderr
    assert (
        _users(config, "add", "bob", "--role", "operator", stdin="bob-secret-1\n").returncode == 0
    )
    r = _users(config, "list")
    assert r.returncode == 0 and r.stdout.split() == ["ann", "admin", "bob", "operator"]
    assert _users(config, "passwd", "bob", stdin="bob-secret-2\n").returncode == 0
    store = UserStore(users_json)
    assert store.verify("bob", "bob-secret-2") and not store.verify("bob", "bob-secret-1")
    r = _users(config, "remove", "bob")
    assert r.returncode == 0 and "removed bob" in r.stdout
    r = _users(config, "remove", "bob")
    assert r.returncode == 2 and "no user 'bob'" in r.stderr
    assert [u.name for u in store.users()] == ["ann"]
    r = _users(config, "add", "../x", "--role", "viewer", stdin="good-password\n")
    assert r.returncode == 2 and "user name" in r.stderr and "Traceback" not in r.stderr
    r = _users(tmp_path / "missing.toml", "list")
    assert r.returncode == 2 and "not found" in r.stderr


@pytest.mark.slow
def test_the_users_command_refuses_weak_passwords_clearly(tmp_path):
    config = tmp_path / "serve.toml"
    config.write_text('output = "data"\n')
    weak = [
        ("eleven-char", "too short"),
        ("password1234", "too common"),
        ("Dragon2024!!", "too common"),
        ("abababababab", "too simple"),
    ]
    for password, why in weak:
        r = _users(config, "add", "bob", "--role", "viewer", stdin=password + "\n")
        assert r.returncode == 2 and why in r.stderr, (password, r.stderr)
        assert "Traceback" not in r.stderr and password not in r.stdout + r.stderr
    assert _users(config, "add", "bob", "--role", "viewer", stdin="bob-secret-1\n").returncode == 0
    r = _users(config, "passwd", "bob", stdin="qwertyuiop12\n")
    assert r.returncode == 2 and "too common" in r.stderr and "Traceback" not in r.stderr
    assert UserStore(tmp_path / "data" / "users.json").verify("bob", "bob-secret-1")


def test_the_policy_length_common_list_and_variety():
    from stereopose.web.users import MIN_PASSWORD, check_password, common_passwords

    assert MIN_PASSWORD == 12 and len(common_passwords()) > 5000
    assert {"password", "123456", "qwertyuiopas", "1qaz2wsx3edc"} <= common_passwords()
    for weak in (
        "Password!2024",
        "password12345",
        "1234567890123",
        "!!Football2023",
        "zzzzzzzzzzzz",
    ):
        with pytest.raises(UserError, match=r"too (common|simple)"):
            check_password(weak)
    assert check_password("vera's long passphrase") == "vera's long passphrase"


def test_serve_says_where_the_console_is_and_how_to_add_its_first_user(tmp_path):
    from stereopose.cli.serve import _console_line

    config = tmp_path / "serve.toml"
    line = _console_line("http://127.0.0.1:8787", config, tmp_path / "data")
    assert line.startswith("operator console: http://127.0.0.1:8787/; no user yet")
    assert f"stereopose users add NAME --role admin --config {config}" in line
    UserStore.in_folder(tmp_path / "data", hasher=fast_hasher()).add("ann", "ann-secret-1", "admin")
    assert _console_line("http://127.0.0.1:8787", config, tmp_path / "data") == (
        "operator console: http://127.0.0.1:8787/"
    )
