"""The names in an output (data) folder, in one place: what `run` and `serve` write there, and
what the console, retention, restart and other tools read back."""

from __future__ import annotations

__all__ = ["CLIPS_DIR", "EVENTS_DB", "POSES_DIR", "STATUS", "USERS_FILE"]

EVENTS_DB = "events.sqlite"  # the event log (site.eventlog; docs/formats.md)
CLIPS_DIR = "clips"  # event clips (io.sinks.clips)
POSES_DIR = "poses"  # serve's 3D pose segments (io.sinks.segments)
STATUS = "status.json"  # serve's health snapshot
USERS_FILE = "users.json"  # the console's accounts (web.users)
