"""The configuration's sections of the site service and the control room: serve, mqtt,
control_room, storage."""

from __future__ import annotations

from dataclasses import dataclass, field

from stereopose.checks import DAY_S
from stereopose.config.fields import Section, _schema, number
from stereopose.errors import ConfigError


@_schema("serve")
@dataclass(frozen=True)
class ServeConfig(Section):
    """`stereopose serve`: its HTTP server and its health watch."""

    # address of the health/metrics server; anything but loopback is reachable from the network
    host: str = "127.0.0.1"
    port: int = number(8787, integer=True, ge=0, le=65535)  # 0: any free port
    # the console's address as others reach it (https://...): a control room links to it
    public_url: str = ""
    # a camera with no frame for this long raises camera_down
    camera_timeout_s: float = number(5.0, gt=0.0, le=DAY_S)
    # a camera's reprojection error above this many times its baseline: calibration_drift
    calib_warn_factor: float = number(2.0, gt=1.0, le=1000.0)
    # samples (a camera's steps with people) its baseline error is the median of, and the
    # running error's window: fewer warn sooner, on noisier figures
    calib_baseline_samples: int = number(300, integer=True, ge=10, le=100_000)
    calib_window_samples: int = number(150, integer=True, ge=5, le=10_000)
    # a drifted camera placed again from the people the others see is applied at once (false:
    # proposed, for an admin to accept: POST /api/calibration/<camera>/accept)
    calibration_auto: bool = True
    # a restart loads the correction the service wrote (<name>.corrected.toml beside the
    # calibration, or in the output folder) when it is newer than the calibration named
    calibration_corrected: bool = True
    # steps with people sampled before a drifted camera is placed again
    calibration_samples: int = number(150, integer=True, ge=10, le=10_000)
    # how often status.json (the health snapshot) is rewritten
    status_interval_s: float = number(10.0, gt=0.0, le=DAY_S)
    # HTTPS: a PEM certificate (chain) and its private key (relative to the config file; both
    # or neither; the key readable by its owner only)
    certificate: str | None = None
    key: str | None = None
    # Host names (and addresses) the service answers to besides the bound address, the
    # loopback names and, bound to 0.0.0.0, the machine's names and addresses; another Host
    # header is refused (421, against DNS rebinding). "*": any; "*.example.org": a domain.
    allowed_hosts: tuple[str, ...] = ()
    # reverse proxies in front of the service (addresses or networks, "10.0.0.0/24"): their
    # connections are not capped per address (every client behind one shares it), and the
    # client address they forward (X-Forwarded-For) counts for the login limits instead of
    # theirs; anyone else's X-Forwarded-For is ignored
    trusted_proxies: tuple[str, ...] = ()
    # work and operation tickets (files, relative to the config file) on the ticket desk from
    # the start, planned: started from the console or over the API (docs/formats.md#tickets)
    tickets: tuple[str, ...] = ()


@_schema("mqtt")
@dataclass(frozen=True)
class MqttConfig(Section):
    """Events, zone occupancy and people out over MQTT (serve); host empty: MQTT off."""

    host: str = ""
    port: int = number(1883, integer=True, ge=1, le=65535)
    site: str = "site"  # this installation's name, a topic level
    topic_prefix: str = "stereopose"
    username: str | None = None
    password: str | None = field(default=None, repr=False)  # never shown
    # or a file holding the password (its first line; relative to the config file), so the
    # configuration itself holds no secret and the file can be readable by the service only
    password_file: str | None = None
    tls: bool = False
    ca_file: str | None = None  # relative to the config file
    # people updates per second (0: none)
    people_hz: float = number(5.0, ge=0.0, le=1000.0)
    # messages held at most while the broker is away (then counted as dropped)
    queue_size: int = number(10_000, integer=True, ge=1, le=10_000_000)
    # the event log as an outbox: every stored event on <prefix>/<site>/log/events with its
    # id, sent again until a receiver confirms it (site.outbox, docs/mqtt.md)
    outbox: bool = True
    # the receiver's confirmed mark behind what was sent for this long: sent again (0: only on
    # a new connection)
    outbox_resend_s: float = number(30.0, ge=0.0, le=DAY_S)
    # zones switched off and on over MQTT: <prefix>/<site>/zones/<zone>/enabled (docs/mqtt.md;
    # who may is the broker's ACL's to say); off: no command is taken
    commands: bool = False


@_schema("control_room")
@dataclass(frozen=True)
class ControlRoomConfig(Section):
    """`stereopose control-room` (stereopose.controlroom, docs/control-room.md)."""

    # the store: an SQLite file (relative to `output`; empty: <output>/control.sqlite), or
    # PostgreSQL: "postgresql://USER@HOST:PORT/DATABASE" (needs the `postgresql` extra)
    database: str = ""
    # the PostgreSQL password: a file readable by its owner only (relative to the config
    # file), so none is in the configuration; or in the URL
    database_password_file: str | None = None
    # a site with no message for this long is shown offline
    offline_after_s: float = number(90.0, gt=0.0, le=DAY_S)
    # a site whose clock is further than this from the control room's raises an incident
    clock_tolerance_s: float = number(5.0, gt=0.0, le=DAY_S)
    # this control room's name: a site's console shows an acknowledgement made here as
    # "USER via NAME"
    name: str = "control-room"
    # how often an acknowledgement not yet answered by its site is asked again
    command_resend_s: float = number(5.0, gt=0.0, le=3600.0)
    # several control-room workers on one PostgreSQL store: the MQTT shared subscription's
    # group they share the sites' messages in ("": one worker takes every message)
    shared_group: str = ""
    # the store keeps events (and closed incidents, answered acknowledgements) this long
    retention_days: float = number(365.0, gt=0.0, le=36500.0)
    # sites taken besides those enrolled (`control-room sites add NAME`, which gives each
    # its broker login); a message of any other name is refused, counted, and raises one
    # control-room incident
    sites: tuple[str, ...] = ()
    # the most sites `control-room sites add` enrols
    max_sites: int = number(1000, integer=True, ge=1, le=100_000)
    # a site's outbox message (an event, an incident's change) larger than this is refused
    max_event_bytes: int = number(65_536, integer=True, ge=1024, le=16 << 20)
    # a heartbeat larger than this is refused (its summary: a few numbers and a status)
    max_heartbeat_bytes: int = number(8192, integer=True, ge=512, le=1 << 20)
    # an event id more than this beyond the last id its site announced is not taken as the
    # site's new mark: refused, counted, and a control-room incident
    ids_ahead: int = number(100_000, integer=True, ge=100, le=2**40)

    def _check(self) -> None:
        for s in self.sites:
            if not (0 < len(s) <= 200 and s.isprintable()):
                raise ConfigError(f"control_room.sites: {s[:40]!r}: 1 to 200 printable characters")
        if not (0 < len(self.name) <= 64 and self.name.isprintable()):
            raise ConfigError("control_room.name: 1 to 64 printable characters")
        g = self.shared_group
        if g and not (len(g) <= 64 and g.isprintable() and not set(g) & set("/+#")):
            raise ConfigError("control_room.shared_group: up to 64 printable characters, no / + #")


@_schema("storage")
@dataclass(frozen=True)
class StorageConfig(Section):
    """What serve keeps in its output folder, and for how long."""

    # seconds of poses per segment file
    segment_s: float = number(3600.0, ge=1.0, le=DAY_S)
    # pose segments are deleted after this many days
    retention_days: float = number(7.0, gt=0.0, le=36500.0)
    # pose segments and clips together at most this many GB (0: no cap)
    max_gb: float = number(20.0, ge=0.0, le=1e6)
    clip_retention_days: float = number(30.0, gt=0.0, le=36500.0)
    event_retention_days: float = number(365.0, gt=0.0, le=36500.0)
    clips: bool = True  # an MP4 per camera for each alarm
    # seconds of clip before and after an alarm
    clip_pre_s: float = number(5.0, ge=0.0, le=60.0)
    clip_post_s: float = number(5.0, ge=0.0, le=600.0)
    # seconds between retention passes
    maintenance_interval_s: float = number(60.0, gt=0.0, le=DAY_S)
