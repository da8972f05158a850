"""The console's running parts, as the routers get them (web.auth.console_parts).

`Console.in_folder(out_dir, ...)` builds them over a service's output folder: the users
(`users.json`), the sessions and the login limit (in memory), the event log and its
acknowledgements (`events.sqlite`), the clips folder (`clips/`), the pose segments (`poses/`,
for the 3D replay) and the live hub.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from stereopose.io.datafolder import CLIPS_DIR, EVENTS_DB, POSES_DIR
from stereopose.site.acks import AckStore
from stereopose.site.eventlog import EventLog
from stereopose.site.live import LiveHub
from stereopose.web.auth import LoginLimiter, Sessions
from stereopose.web.users import UserStore


@dataclass
class Console:
    """users, sessions, limiter: who may log in; log, acks: the event log (None: none);
    clips_dir: the only folder clips are read from (None: no clips); hub: the live side (None:
    no live data: people, zones, cameras and the push channel answer 503)."""

    users: UserStore
    sessions: Sessions
    limiter: LoginLimiter = field(default_factory=LoginLimiter)
    log: EventLog | None = None
    acks: AckStore | None = None
    clips_dir: Path | None = None
    hub: LiveHub | None = None
    poses_dir: Path | None = None  # the pose segments the 3D replay reads (None: no replay)

    @classmethod
    def in_folder(
        cls, out_dir: str | Path, hub: LiveHub | None = None, users: UserStore | None = None
    ) -> Console:
        out = Path(out_dir)
        users = users or UserStore.in_folder(out)
        clips = out / CLIPS_DIR
        return cls(
            users=users,
            sessions=Sessions(users),
            log=EventLog(out / EVENTS_DB, clips),
            acks=AckStore(out / EVENTS_DB),
            clips_dir=clips,
            hub=hub,
            poses_dir=out / POSES_DIR,
        )

    def close(self) -> None:
        if self.hub is not None:
            self.hub.close()
        if self.acks is not None:
            self.acks.close()
