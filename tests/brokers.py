"""A real MQTT broker for tests: mosquitto on a free 127.0.0.1 port, configured in a folder,
and a real paho subscriber that records what it gets."""

from __future__ import annotations

import getpass
import json
import os
import shutil
import signal
import socket
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as paho
import pytest

from waiting import listening, wait_until

_SBIN = os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/sbin"])
MOSQUITTO = shutil.which("mosquitto", path=_SBIN)
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd", path=_SBIN)


def require_mosquitto() -> str:
    """The mosquitto binary; skip without it, unless CI requires it (STEREOPOSE_REQUIRE_BROKER)."""
    if MOSQUITTO is None:
        if os.environ.get("STEREOPOSE_REQUIRE_BROKER") == "1":
            pytest.fail("mosquitto not found; install Debian's mosquitto package")
        pytest.skip("mosquitto not installed (Debian package mosquitto)")
    return MOSQUITTO


def make_certificate(folder: Path, name: str = "cert") -> tuple[Path, Path]:
    """A self-signed certificate for localhost and 127.0.0.1 and its key, in `folder`; skip
    where openssl cannot make one."""
    cert, key = folder / f"{name}.pem", folder / f"{name}-key.pem"
    openssl = [
        "openssl",
        "req",
        "-x509",
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
        "-days",
        "1",
        "-subj",
        "/CN=localhost",
        "-addext",
        "subjectAltName=DNS:localhost,IP:127.0.0.1",
        "-keyout",
        str(key),
        "-out",
        str(cert),
    ]
    try:
        subprocess.run(openssl, check=True, capture_output=True)
    except (OSError, subprocess.CalledProcessError) as e:
        pytest.skip(f"cannot make a test certificate with openssl: {e}")
    return cert, key


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Broker:
    """mosquitto with its config, persistence and log in `folder`; not started until `start`.

    users: name -> password (then anonymous clients are refused). tls: (cert, key) files to
    listen with TLS. extra: more configuration lines (an acl_file, a bridge). Retained messages
    and persistent sessions survive `restart` (the broker saves them when it stops)."""

    def __init__(
        self,
        folder: Path,
        users: dict[str, str] | None = None,
        tls: tuple[Path, Path] | None = None,
        extra: tuple[str, ...] = (),
    ) -> None:
        self.binary = require_mosquitto()
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.proc: subprocess.Popen | None = None
        lines = [
            f"listener {self.port} 127.0.0.1",
            f"user {getpass.getuser()}",  # root stays root: the files are in a private tmp
            "persistence true",
            f"persistence_location {folder}/",
            "queue_qos0_messages true",
            "log_dest stdout",
            "log_type error",
            "log_type warning",
            "log_type notice",
            "log_type information",
        ]
        if users:
            passwd = folder / "passwd"
            passwd.write_text("")
            for name, password in users.items():
                assert MOSQUITTO_PASSWD is not None, "mosquitto_passwd comes with mosquitto"
                subprocess.run([MOSQUITTO_PASSWD, "-b", str(passwd), name, password], check=True)
            lines += ["allow_anonymous false", f"password_file {passwd}"]
        else:
            lines.append("allow_anonymous true")
        if tls:
            lines += [f"certfile {tls[0]}", f"keyfile {tls[1]}"]
        lines += list(extra)  # an ACL, a bridge, ...
        self.config = folder / "mosquitto.conf"
        self.config.write_text("\n".join(lines) + "\n")
        self.log = folder / "mosquitto.log"

    def start(self) -> Broker:
        with open(self.log, "a") as log:
            self.proc = subprocess.Popen(
                [self.binary, "-c", str(self.config)], stdout=log, stderr=subprocess.STDOUT
            )
        wait_until(lambda: listening(self.port) or self.proc.poll() is not None, "mosquitto")
        if self.proc.poll() is not None:
            pytest.fail(f"mosquitto did not start:\n{self.log.read_text()}")
        return self

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None
        wait_until(lambda: not listening(self.port), "mosquitto's port to close")

    def restart(self) -> None:
        self.stop()
        self.start()


@dataclass(frozen=True)
class Received:
    topic: str
    payload: str
    retain: bool


class Subscriber:
    """A paho client subscribed to `topics` (QoS 1), recording every message.

    session: a client id for a persistent session (the broker keeps its messages while it is
    away and across broker restarts); None for a clean one."""

    def __init__(
        self,
        port: int,
        *topics: str,
        session: str | None = None,
        username: str | None = None,
        password: str | None = None,
    ) -> None:
        self.messages: list[Received] = []
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client = paho.Client(
            paho.CallbackAPIVersion.VERSION2,
            client_id=session or "",
            clean_session=session is None,
            protocol=paho.MQTTv311,
        )
        self.client.reconnect_delay_set(0.05, 0.2)
        if username is not None:
            self.client.username_pw_set(username, password)
        self.topics = topics
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *_: self._subscribed.set()
        self.client.on_message = self._on_message
        self.client.connect_async("127.0.0.1", port, keepalive=10)
        self.client.loop_start()
        wait_until(self._subscribed.is_set, "the subscription")

    def _on_connect(self, client, userdata, flags, reason, props) -> None:
        if not reason.is_failure:
            client.subscribe([(t, 1) for t in self.topics])

    def _on_message(self, client, userdata, msg) -> None:
        with self._lock:
            self.messages.append(Received(msg.topic, msg.payload.decode(), bool(msg.retain)))

    def on(self, topic: str) -> list[str]:
        """The payloads received on `topic`, in order."""
        with self._lock:
            return [m.payload for m in self.messages if m.topic == topic]

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


class LogReceiver:
    """A control room's side of the protocol (docs/mqtt.md): stores each event by (site, id)
    once, accepts an event whose prev is at most its mark and raises the mark to its id,
    confirms the mark (retained), and asks for a replay after its mark when an event's prev
    lies beyond it. `lose(n)`: drop the next n events unseen, as a bridge cut would."""

    def __init__(
        self,
        port: int,
        mark: int = 0,
        replay_on_start: bool = True,
        base: str = "stereopose/north%2Fyard/log",
    ) -> None:
        self.base = base
        self.stored: dict[int, dict] = {}
        self.received = 0
        self.replays = 0
        self.mark = mark
        self._lose = 0
        self._lock = threading.Lock()
        self._ready = threading.Event()
        self.replay_on_start = replay_on_start
        self.client = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
        self.client.reconnect_delay_set(0.05, 0.2)
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *_: self._ready.set()
        self.client.on_message = self._on_message
        self.client.connect_async("127.0.0.1", port, keepalive=10)
        self.client.loop_start()
        wait_until(self._ready.is_set, "the receiver's subscription")

    def _on_connect(self, client, userdata, flags, reason, props) -> None:
        if reason.is_failure:
            return
        client.subscribe(f"{self.base}/events", qos=1)
        self._confirm()
        if self.replay_on_start:
            client.publish(f"{self.base}/replay", json.dumps({"after_id": self.mark}), qos=1)

    def _confirm(self) -> None:
        self.client.publish(
            f"{self.base}/confirmed", json.dumps({"events": self.mark}), qos=1, retain=True
        )

    def _on_message(self, client, userdata, msg) -> None:
        e = json.loads(msg.payload)
        with self._lock:
            self.received += 1
            if self._lose:
                self._lose -= 1
                return
            if e["prev"] > self.mark:  # some were lost before it: ask again after the mark
                self.replays += 1
                client.publish(f"{self.base}/replay", json.dumps({"after_id": self.mark}), qos=1)
                return
            self.stored.setdefault(e["id"], e)
            self.mark = max(self.mark, e["id"])
        self._confirm()

    def lose(self, n: int) -> None:
        with self._lock:
            self._lose = n

    def ids(self) -> list[int]:
        with self._lock:
            return sorted(self.stored)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()
