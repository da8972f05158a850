"""The MQTT sink's settings and its topic rules: names made safe as topic levels.

Every settings value is checked at once; a bad one is a ConfigError naming its key
(``mqtt.<key>``), as the configuration file will spell it.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from stereopose.errors import ConfigError

logger = logging.getLogger(__name__)

if TYPE_CHECKING:
    import paho.mqtt.client as mqtt
    import paho.mqtt.client as paho

__all__ = ["MqttSettings", "make_client", "topic_name", "topic_part"]


@dataclass(frozen=True, kw_only=True)
class MqttSettings:
    """Where and how the MQTT sink publishes; checked at once (ConfigError naming the key).

    host, port: the broker. site: this installation's name, a topic level. topic_prefix: the
    first topic level(s), '/'-separated. username, password: broker login (the password is
    never shown). tls: connect with TLS, checking the broker's certificate against the system
    CAs or ca_file. client_id: default ``stereopose-<site>-<random>``. keepalive_s: the broker
    declares the link lost (and sends the will) after 1.5 keepalive_s of silence. queue_size:
    events and people updates waiting at most while the broker is away. people_hz: people
    updates per second of frame time (0: none). reconnect_min_s .. reconnect_max_s: the
    reconnect backoff. close_timeout_s: how long `close` waits for the queue to drain.
    """

    host: str
    site: str
    port: int = 1883
    topic_prefix: str = "stereopose"
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    tls: bool = False
    ca_file: Path | None = None
    client_id: str | None = None
    keepalive_s: int = 30
    queue_size: int = 10_000
    people_hz: float = 5.0
    reconnect_min_s: float = 1.0
    reconnect_max_s: float = 30.0
    close_timeout_s: float = 5.0

    def __post_init__(self) -> None:
        if not isinstance(self.host, str) or not self.host.strip():
            raise ConfigError(f"mqtt.host: expected a broker host name, got {self.host!r}")
        port = self.port
        if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
            raise ConfigError(f"mqtt.port: expected an integer in 1..65535, got {self.port!r}")
        if not isinstance(self.site, str) or not self.site.strip():
            raise ConfigError(f"mqtt.site: expected a non-empty site name, got {self.site!r}")
        _check_prefix(self.topic_prefix)
        if self.ca_file is not None:
            if not self.tls:
                raise ConfigError("mqtt.ca_file: given, but mqtt.tls is false")
            if not Path(self.ca_file).is_file():
                raise ConfigError(f"mqtt.ca_file: no such file {str(self.ca_file)!r}")
        if self.password is not None and self.username is None:
            raise ConfigError("mqtt.password: given without mqtt.username")
        for key, value in (("keepalive_s", self.keepalive_s), ("queue_size", self.queue_size)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"mqtt.{key}: expected an integer >= 1, got {value!r}")
        for key, value in (
            ("people_hz", self.people_hz),
            ("reconnect_min_s", self.reconnect_min_s),
            ("reconnect_max_s", self.reconnect_max_s),
            ("close_timeout_s", self.close_timeout_s),
        ):
            if not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
                raise ConfigError(f"mqtt.{key}: expected a number >= 0, got {value!r}")
        if not 0 < self.reconnect_min_s <= self.reconnect_max_s:
            raise ConfigError(
                f"mqtt.reconnect_min_s: expected 0 < reconnect_min_s <= reconnect_max_s, got "
                f"{self.reconnect_min_s!r} and {self.reconnect_max_s!r}"
            )


def make_client(s: MqttSettings, client_id: str) -> mqtt.Client:
    """A paho client (MQTT 3.1.1) with the settings' login, TLS (a ConfigError naming
    mqtt.ca_file when its CAs cannot be loaded) and reconnect backoff; callbacks are the
    caller's."""
    import ssl

    import paho.mqtt.client as paho
    from paho.mqtt.enums import CallbackAPIVersion

    c = paho.Client(CallbackAPIVersion.VERSION2, client_id=client_id, protocol=paho.MQTTv311)
    if s.username is not None:
        c.username_pw_set(s.username, s.password)
    if s.tls:
        try:
            c.tls_set(ca_certs=None if s.ca_file is None else str(s.ca_file))
        except (ssl.SSLError, OSError) as e:
            raise ConfigError(f"mqtt.ca_file: cannot load CAs from {s.ca_file}: {e}") from None
    # paho waits fractions of a second too, whatever its annotation says (int)
    c.reconnect_delay_set(s.reconnect_min_s, s.reconnect_max_s)  # pyright: ignore[reportArgumentType]
    return c


# Characters a topic level cannot hold as they are: '/' separates levels, '+' and '#' are
# wildcards, '%' escapes; mosquitto drops a client that sends control characters,
# non-characters or lone surrogates in a topic, so those are escaped too.
def _escaped(ch: str) -> bool:
    o = ord(ch)
    return (
        ch in "/+#%"
        or o < 0x20
        or 0x7F <= o <= 0x9F
        or 0xD800 <= o <= 0xDFFF
        or 0xFDD0 <= o <= 0xFDEF
        or (o & 0xFFFF) >= 0xFFFE
    )


def topic_part(name: str) -> str:
    """A zone or site name as one topic level: each character of ``/ + # %``, the control
    characters and the Unicode non-characters percent-encoded (its UTF-8 bytes as ``%XX``),
    the rest unchanged; the empty name is a lone ``%``. The mapping is one-to-one
    (`topic_name` reverses it), so two zones never share a topic."""
    if not name:
        return "%"  # a lone '%' decodes to nothing else, and names never encode to it
    return "".join(
        "".join(f"%{b:02X}" for b in ch.encode("utf-8", "surrogatepass")) if _escaped(ch) else ch
        for ch in name
    )


def topic_name(part: str) -> str:
    """The name back from a topic level written by `topic_part`."""
    if part == "%":
        return ""
    out, raw, i = [], bytearray(), 0
    while i < len(part):
        if part[i] == "%":
            raw += bytes.fromhex(part[i + 1 : i + 3])
            i += 3
            continue
        if raw:
            out.append(raw.decode("utf-8", "surrogatepass"))
            raw.clear()
        out.append(part[i])
        i += 1
    if raw:
        out.append(raw.decode("utf-8", "surrogatepass"))
    return "".join(out)


def _check_prefix(prefix: str) -> None:
    if (
        not isinstance(prefix, str)
        or prefix.startswith("$")
        or any(not lv or topic_part(lv) != lv for lv in prefix.split("/"))
    ):
        raise ConfigError(
            f"mqtt.topic_prefix: expected '/'-separated non-empty levels without + # % or "
            f"control characters, not starting with $, got {prefix!r}"
        )


def loop_alive(client: paho.Client | None) -> bool:
    """Whether a started paho client's network thread (loop_start) runs; True for no client,
    and for one whose loop was stopped (loop_stop). paho forgets its thread when the thread
    ends, whatever ended it; loop_stop alone marks it terminated."""
    if client is None:
        return True
    thread = getattr(client, "_thread", None)
    if thread is not None:
        return thread.is_alive()
    return bool(getattr(client, "_thread_terminate", True))


def restart_loop(client: paho.Client | None) -> bool:
    """paho's network thread started again when it died (an error no callback caught ends it):
    True when it had to be. The connection is made anew (a thread that died mid-packet leaves
    the link's state half read), and the client's on_connect subscribes again; what the
    broker sent meanwhile is the sender's to send again."""
    if client is None or loop_alive(client):
        return False
    client.loop_stop()
    client.connect_async(client.host, client.port, keepalive=client.keepalive)
    client.loop_start()
    return True


def stop_loop(client: paho.Client, timeout_s: float) -> None:
    """paho's loop_stop joins without a limit: a connect in progress must not hang a close.
    Waits at most timeout_s + 1 s; the thread is left behind (logged) after that."""
    stopper = threading.Thread(target=client.loop_stop, daemon=True)
    stopper.start()
    stopper.join(timeout=timeout_s + 1.0)
    if stopper.is_alive():
        logger.warning("MQTT: the network thread did not stop; left behind")
