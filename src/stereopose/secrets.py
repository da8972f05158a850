"""What may be shown of a secret: URLs without their password, and secret keys' values never.

Used wherever a value could reach a log, an error message or a stored row: camera URLs with a
login (rtsp://user:password@host/...), webhook and database URLs, and configuration values of
keys that hold passwords or tokens.
"""

from __future__ import annotations

import re
from urllib.parse import urlsplit

HIDDEN = "<hidden>"
# configuration keys whose values are secrets (the last part of a key path, lower case)
_SECRET_KEY = re.compile(r"(^|_)(password|passwd|token|secret|api_key|private_key)$")
# keys whose values are URLs that may carry a login
_URL_KEYS = frozenset({"source", "detect", "webhook", "database", "url", "endpoint"})


def redact(url: str) -> str:
    """The URL without its password (user:secret@host -> user:***@host), for messages."""
    try:
        parts = urlsplit(url)
        password = parts.password
    except ValueError:  # malformed: shown up to its host part, which may hold a password
        return url.split("@", 1)[-1] if "@" in url else url
    if password is None:
        return url
    start = url.find("//") + 2  # the netloc follows verbatim: the rest is kept as it was
    netloc = parts.netloc.replace(f":{password}@", ":***@", 1)
    return url[:start] + netloc + url[start + len(parts.netloc) :]


_URL = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*://[^\s,\"']+")


def redact_all(text: str, logins: bool = False) -> str:
    """Every URL in `text` (a list of sources joined by ", ", say) without its password;
    logins: without any user part either (a token given as the user: token@host)."""
    if logins:
        return _URL.sub(lambda m: re.sub(r"//[^/@]*@", "//***@", m.group(0), count=1), text)
    return _URL.sub(lambda m: redact(m.group(0)), text)


def is_secret_key(key: str) -> bool:
    """Whether a configuration key path's last part names a secret (mqtt.password, ...)."""
    last = re.sub(r"\[\d+\]$", "", key.rsplit(".", 1)[-1]).lower()
    return bool(_SECRET_KEY.search(last))


def shown(key: str, value: object) -> str:
    """`value` of the configuration key path `key` as an error message may show it: a
    secret key's value hidden whatever its type, URLs without their password."""
    if is_secret_key(key):
        return HIDDEN
    text = repr(value)
    last = re.sub(r"\[\d+\]$", "", key.rsplit(".", 1)[-1]).lower()
    if last in _URL_KEYS or "://" in text:
        return redact_all(text)
    return text


_TOML_KEY = re.compile(r"^(\s*)([A-Za-z0-9_-]+)(\s*=\s*)(.*)$")


def masked_toml(text: str) -> str:
    """A configuration file's text as a copy of it may keep it: each secret key's value
    replaced by "<hidden>", every URL without its login (user and password); the rest as
    written."""
    out = []
    for line in text.splitlines(keepends=True):
        m = _TOML_KEY.match(line.rstrip("\r\n"))
        if m and is_secret_key(m.group(2)):
            end = line[len(line.rstrip("\r\n")) :]
            line = f'{m.group(1)}{m.group(2)}{m.group(3)}"{HIDDEN}"{end}'
        else:
            line = redact_all(line, logins=True)
        out.append(line)
    return "".join(out)
