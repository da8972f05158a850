"""What a configuration file refers to, read the same way by every command that reads one
(`serve`, `node`, `control-room`, `run`): paths resolved beside the file, secrets read from
files of their own, a section's settings with the file named in their errors, the MQTT and
the HTTPS settings."""

from __future__ import annotations

import stat
from collections.abc import Callable
from pathlib import Path
from typing import ParamSpec, TypeVar

from stereopose.config import Config
from stereopose.errors import ConfigError
from stereopose.io.sinks.mqtt_settings import MqttSettings
from stereopose.io.video import is_stream

__all__ = [
    "mqtt_settings",
    "read_secret",
    "resolve",
    "section_settings",
    "source_path",
    "tls_files",
]


def resolve(base: Path, value: str) -> Path:
    """A path of the configuration: absolute as given, or relative to `base` (its folder)."""
    p = Path(value).expanduser()
    return p if p.is_absolute() else base / p


P = ParamSpec("P")
T = TypeVar("T")


def source_path(base: Path, value: str) -> str:
    """A camera's source: a stream URL as given, a file resolved as `resolve` does."""
    return value if not value or is_stream(value) else str(resolve(base, value))


def section_settings(path: Path, make: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
    """A building block's settings; its ConfigError (naming `section.key`) names the file."""
    try:
        return make(*args, **kwargs)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None


def mqtt_settings(path: Path, base: Path, cfg: Config) -> MqttSettings | None:
    """[mqtt] checked (its password from `password_file` where given); None without a host."""
    m = cfg.mqtt
    if not m.host:
        return None
    ca = resolve(base, m.ca_file) if m.ca_file else None
    password = m.password
    if m.password_file:
        if m.password:
            raise ConfigError(f"{path}: mqtt.password and mqtt.password_file: give one of them")
        password = read_secret(resolve(base, m.password_file), "mqtt.password_file", path)
    return section_settings(
        path,
        MqttSettings,
        host=m.host,
        site=m.site,
        port=m.port,
        topic_prefix=m.topic_prefix,
        username=m.username,
        password=password,
        tls=m.tls,
        ca_file=ca,
        people_hz=m.people_hz,
        queue_size=m.queue_size,
    )


def tls_files(path: Path, base: Path, cfg: Config) -> tuple[str | None, str | None]:
    """[serve] certificate and key, resolved and checked: both or neither, each a readable
    file, the key not readable by other users; the pair loadable as TLS."""
    s = cfg.serve
    if not s.certificate and not s.key:
        return None, None
    if not s.certificate or not s.key:
        raise ConfigError(f"{path}: serve.certificate and serve.key: give both (HTTPS) or neither")
    cert, key = resolve(base, s.certificate), resolve(base, s.key)
    for name, file in (("serve.certificate", cert), ("serve.key", key)):
        try:
            st = file.stat()
            with open(file, "rb"):
                pass
        except OSError as e:
            raise ConfigError(f"{path}: {name}: cannot read {file}: {e.strerror}") from None
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(f"{path}: {name}: {file} is not a file")
        if name == "serve.key" and st.st_mode & 0o007:
            raise ConfigError(
                f"{path}: serve.key: {file} is readable by every user; chmod o-rwx it"
            )
    import ssl

    try:
        ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(cert, key)
    except (ssl.SSLError, OSError) as e:
        raise ConfigError(
            f"{path}: serve.certificate {cert} and serve.key {key} are not a "
            f"PEM certificate and its key: {e}"
        ) from None
    return str(cert), str(key)


def read_secret(secret: Path, key: str, path: Path) -> str:
    """The first line of a file holding a secret (a regular file of at most 4 KiB); a file
    others may read is refused, as ssh refuses such a key."""
    try:
        st = secret.stat()
        if not stat.S_ISREG(st.st_mode) or st.st_size > 4096:
            raise ConfigError(f"{path}: {key}: {secret} is not a small regular file")
        if st.st_mode & 0o007:
            raise ConfigError(f"{path}: {key}: {secret} is readable by every user; chmod o-rwx it")
        lines = secret.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise ConfigError(f"{path}: {key}: cannot read {secret}: {e.strerror}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: {key}: {secret} is not UTF-8 text") from None
    if not lines or not lines[0].strip():
        raise ConfigError(f"{path}: {key}: {secret} is empty")
    return lines[0].strip()
