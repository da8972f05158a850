"""Secrets never shown: configuration errors hide a secret key's value whatever its type, URLs
lose their password, and the event log stores no camera's password (older logs masked)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from stereopose.config import load_config
from stereopose.errors import ConfigError
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.pipeline.sources import source_label
from stereopose.secrets import HIDDEN, is_secret_key, redact_all, shown

SECRET = "s3cr3t-Passw0rd"


@pytest.mark.parametrize(
    ("text", "key"),
    [
        (f'[mqtt]\npassword = ["{SECRET}"]\n', "mqtt.password"),
        (f'[mqtt]\npassword = {{ value = "{SECRET}" }}\n', "mqtt.password"),
        (f"[mqtt]\npassword = 12{SECRET.count('s')}\n", "mqtt.password"),
        (f'[outputs]\nwebhook = ["https://user:{SECRET}@hooks.example/x"]\n', "outputs.webhook"),
        (
            f'[[cameras]]\nname = "a"\nsource = ["rtsp://admin:{SECRET}@10.0.0.5/s"]\n',
            "cameras[0].source",
        ),
        (
            f'[control_room]\ndatabase = ["postgresql://sp:{SECRET}@db/fleet"]\n',
            "control_room.database",
        ),
    ],
)
def test_a_configuration_error_never_prints_a_secret(tmp_path, text, key):
    path = tmp_path / "serve.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    message = str(e.value)
    assert key in message and SECRET not in message
    if key == "mqtt.password":
        assert HIDDEN in message


def test_what_may_be_shown_of_a_value():
    assert is_secret_key("mqtt.password") and is_secret_key("opcua.users[2].password")
    assert is_secret_key("x.api_token") and not is_secret_key("mqtt.password_file")
    assert shown("mqtt.password", "abc") == HIDDEN
    assert shown("serve.port", 8080) == "8080"
    assert SECRET not in shown("cameras[0].source", f"rtsp://u:{SECRET}@h/s")
    text = f"rtsp://u:{SECRET}@10.0.0.1/a, http://plain/b, rtsp://v:{SECRET}x@h:554/c?x=1"
    assert redact_all(text) == "rtsp://u:***@10.0.0.1/a, http://plain/b, rtsp://v:***@h:554/c?x=1"


def test_the_event_log_stores_no_cameras_password_and_masks_older_logs(tmp_path: Path):
    db = tmp_path / "events.sqlite"
    urls = [f"rtsp://admin:{SECRET}@10.0.0.5:554/main", "rtsp://10.0.0.6/main"]
    label = source_label(urls)
    assert SECRET not in label and "admin:***@10.0.0.5" in label and "10.0.0.6" in label
    SqliteSink(db, "site.toml", ", ".join(urls)).close()  # masked by the log itself too
    # a log an earlier version wrote: the URL as configured
    with sqlite3.connect(db) as c:
        c.execute(
            "INSERT INTO runs(started, site, source) VALUES (1.0, 'site', ?)", (", ".join(urls),)
        )
    SqliteSink(db, "site.toml", label).close()
    with sqlite3.connect(db) as c:
        sources = [r[0] for r in c.execute("SELECT source FROM runs ORDER BY id")]
    assert len(sources) == 3 and all("admin:***@10.0.0.5" in s for s in sources)
    for f in tmp_path.iterdir():  # nor in the file's free pages or its write-ahead log
        assert SECRET.encode() not in f.read_bytes(), f.name


def test_a_configuration_copy_keeps_no_secret():
    from stereopose.secrets import masked_toml

    text = (
        f'[mqtt]\nhost = "b"\npassword = "{SECRET}"  # the broker\'s\n'
        f'[[cameras]]\nsource = "rtsp://admin:{SECRET}@10.0.0.5/s"\n'
        f'[outputs]\nwebhook = "https://{SECRET}@hooks.example/x?y=1"\n'
    )
    masked = masked_toml(text)
    assert SECRET not in masked
    assert 'password = "<hidden>"' in masked and 'host = "b"' in masked
    assert 'source = "rtsp://***@10.0.0.5/s"' in masked
    assert 'webhook = "https://***@hooks.example/x?y=1"' in masked
