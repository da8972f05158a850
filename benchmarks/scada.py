"""The IEC 60870-5-104 outstation of `stereopose serve --demo`: how soon a c104 master gets each
zone change, and how exact its time tag is.

The real demo is served (its four videos looped as live cameras, the demo site) with [iec104]
enabled; c104's own Client connects as the master, is answered by a general interrogation, and
keeps every spontaneous message with its time of receipt. For each zone event in the service's
event log (events.sqlite: enter and exit of the energized busbar and the restricted area; the
wall time is the run's wall_start + the event's t), the master's message for that zone's
occupied point with the same value is looked for: its latency is the receipt time minus the
event's wall time (the event's own time, i.e. the frame it was seen in: detection, 3D, the fence's
debounce and the network are all inside it), its tag error the time tag (CP56Time2a) minus the
event's wall time.

    python benchmarks/scada.py [--minutes 5] [--imgsz 320]

Results: benchmarks/results/scada.{md,json}.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save

CA = 1


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def typed_callback(fn, *, ret, **params):
    fn.__annotations__ = {**params, "return": ret}
    return fn


class Master:
    """c104's Client as the master: (ioa, value, time tag, cause, receipt time) of every
    message."""

    def __init__(self, port: int) -> None:
        import c104

        self.c104 = c104
        self.lock = threading.Lock()
        self.got: list[tuple[int, object, float | None, str, float]] = []
        self.client = c104.Client(tick_rate_ms=50, command_timeout_ms=5000)
        self.conn = self.client.add_connection(ip="127.0.0.1", port=port, init=c104.Init.ALL)

        def on_station(client, connection, common_address):
            connection.add_station(common_address=common_address)

        def on_point(client, station, io_address, point_type):
            pt = station.add_point(io_address=io_address, type=point_type)

            def receive(point, previous_info, message):
                at = time.time()
                tag = point.recorded_at
                tag_s = tag.replace(tzinfo=dt.UTC).timestamp() if tag else None
                value = point.value
                value = int(value) if isinstance(value, c104.Int16) else value
                with self.lock:
                    self.got.append((point.io_address, value, tag_s, message.cot.name, at))
                return c104.ResponseState.SUCCESS

            pt.on_receive(
                callable=typed_callback(
                    receive,
                    point=c104.Point,
                    previous_info=c104.Information,
                    message=c104.IncomingMessage,
                    ret=c104.ResponseState,
                )
            )

        self.client.on_new_station(
            callable=typed_callback(
                on_station,
                client=c104.Client,
                connection=c104.Connection,
                common_address=int,
                ret=None,
            )
        )
        self.client.on_new_point(
            callable=typed_callback(
                on_point,
                client=c104.Client,
                station=c104.Station,
                io_address=int,
                point_type=c104.Type,
                ret=None,
            )
        )
        self.client.start()

    def spontaneous(self, ioa: int) -> list[tuple[object, float | None, float]]:
        with self.lock:
            return [
                (v, tag, at) for i, v, tag, cot, at in self.got if i == ioa and cot == "SPONTANEOUS"
            ]

    def interrogated(self) -> set[int]:
        with self.lock:
            return {i for i, _, _, cot, _ in self.got if cot == "INTERROGATED_BY_STATION"}

    def wait_interrogated(self, points: int, timeout_s: float) -> None:
        """Until the connection's first interrogation answered `points` points.

        c104's Client can miss its own start-up task (the unmute and the interrogation it
        schedules on opening a connection): the socket is then open and muted, or still
        awaiting its opening, and nothing comes. A master retries, as this one does."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            wait = time.monotonic() + 3.0
            while time.monotonic() < min(wait, deadline):
                if len(self.interrogated()) >= points:
                    return
                time.sleep(0.1)
            state = self.conn.state.name
            if state == "OPEN_MUTED":
                self.conn.unmute()
                self.conn.interrogation(common_address=CA)
            elif state == "CLOSED_AWAIT_OPEN":
                self.conn.disconnect()
                self.conn.connect()
        raise SystemExit(
            f"still waiting for the interrogation after {timeout_s:.0f} s "
            f"(master {self.conn.state.name}, {len(self.got)} messages)"
        )

    def close(self) -> None:
        self.client.stop()


def _zone_events(db: Path, after: int = 0) -> list[tuple[int, str, str, float, int]]:
    """(id, zone, type, wall time, person) of the enter and exit events after row `after`."""
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return con.execute(
            "SELECT e.id, e.zone, e.type, e.t + r.wall_start, e.person FROM events e JOIN runs r "
            "ON e.run = r.id WHERE e.id > ? AND e.zone != '' AND e.type IN ('enter', 'exit') "
            "ORDER BY e.id",
            (after,),
        ).fetchall()
    except sqlite3.OperationalError:  # not made yet
        return []
    finally:
        con.close()


class LogWatch(threading.Thread):
    """When each zone event's row first appears in the event log (what /api/events reads),
    polled every 20 ms."""

    def __init__(self, db: Path) -> None:
        super().__init__(daemon=True)
        self.db, self.seen, self.stop = db, {}, threading.Event()

    def run(self) -> None:
        last = 0
        while not self.stop.wait(0.02):
            for row in _zone_events(self.db, last):
                self.seen[row[0]] = time.time()
                last = row[0]


def _wait(check, what: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            raise SystemExit(f"still waiting for {what} after {timeout_s:.0f} s")
        time.sleep(0.2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--imgsz", type=int, default=320)
    args = ap.parse_args()
    from stereopose.cli.points import points_of
    from stereopose.pipeline.demo import write_serve_demo_config

    tmp = Path(tempfile.mkdtemp(prefix="stereopose-scada-"))
    port = _free_port()
    config = write_serve_demo_config(tmp / "demo", tmp / "data", _free_port(), imgsz=args.imgsz)
    config.write_text(
        config.read_text() + f"\n[iec104]\nenabled = true\nport = {port}\ncommon_address = {CA}\n"
    )
    _, table = points_of(config)
    zones = {p.name: p.ioa for p in table if p.kind == "zone_occupied"}
    log = tmp / "serve.log"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    with open(log, "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=env,
        )
    master = None
    try:
        import socket

        def listening() -> bool:
            if proc.poll() is not None:
                raise SystemExit(f"serve stopped:\n{log.read_text()}")
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", port)) == 0

        _wait(listening, "the outstation", 120)
        master = Master(port)
        watch = LogWatch(tmp / "data" / "events.sqlite")
        watch.start()
        master.wait_interrogated(len(table.monitored), 60)
        interrogated_ok = master.interrogated() == {p.ioa for p in table.monitored}
        started = time.monotonic()
        print(
            f"served, the master interrogated {len(master.interrogated())} points; "
            f"{args.minutes} min ...",
            flush=True,
        )
        while time.monotonic() - started < args.minutes * 60:
            time.sleep(5)
            if proc.poll() is not None:
                raise SystemExit(f"serve stopped:\n{log.read_text()}")
        time.sleep(3)  # the last events' messages
        watch.stop.set()
        events = _zone_events(tmp / "data" / "events.sqlite")
    finally:
        if master is not None:
            master.close()
        proc.terminate()
        rc = proc.wait(timeout=60)
    latencies, after_log, tag_errors, missing, unchanged = [], [], [], 0, 0
    inside: dict[str, set[int]] = {}
    for row_id, zone, type_, wall, person in events:
        # the point is "someone inside": an enter while another is inside, or an exit leaving
        # someone, changes nothing and sends nothing
        people = inside.setdefault(zone, set())
        was = bool(people)
        (people.add if type_ == "enter" else people.discard)(person)
        if bool(people) == was:
            unchanged += 1
            continue
        want = type_ == "enter"
        got = [
            (tag, at)
            for v, tag, at in master.spontaneous(zones[zone])
            if v is want and tag is not None and abs(tag - wall) < 0.01
        ]
        if not got:
            missing += 1
            continue
        tag, at = got[0]
        latencies.append(at - wall)
        tag_errors.append(abs(tag - wall))
        if row_id in watch.seen:
            after_log.append(at - watch.seen[row_id])
    results = {
        "date": dt.date.today().isoformat(),
        "machine": machine().replace(", one thread", ""),
        "minutes": args.minutes,
        "imgsz": args.imgsz,
        "serve_exit": rc,
        "interrogation_matches_points_table": interrogated_ok,
        "points": len(table.monitored),
        "zone_events": len(events),
        "point_changes": len(events) - unchanged,
        "unchanged": unchanged,
        "matched": len(latencies),
        "unmatched": missing,
    }
    if latencies:
        q = (
            statistics.quantiles(latencies, n=20, method="inclusive")
            if len(latencies) > 1
            else latencies * 19
        )
        results.update(
            latency_s={
                "median": round(statistics.median(latencies), 3),
                "p95": round(q[18], 3),
                "max": round(max(latencies), 3),
                "min": round(min(latencies), 3),
            },
            within_1s=sum(x <= 1.0 for x in latencies),
            after_log_s={
                "median": round(statistics.median(after_log), 3),
                "max": round(max(after_log), 3),
            }
            if after_log
            else None,
            tag_error_ms_max=round(1000 * max(tag_errors), 2),
        )
    print(results)
    save("scada", results, markdown(results))


def markdown(r: dict) -> list[str]:
    md = [
        "# IEC 60870-5-104: zone changes at a c104 master",
        "",
        f"`python benchmarks/scada.py --minutes {r['minutes']:g} --imgsz {r['imgsz']}`, "
        f"{r['date']}, {r['machine']}.",
        "",
        "`stereopose serve` of the real demo (4 looped videos as live cameras, detector at "
        f"{r['imgsz']}) with [iec104] enabled, c104's Client as the master on the same machine. "
        "Latency: the master's receipt of a zone's occupied point minus the event's own wall "
        "time (the frame it was seen in), so detection, 3D, the fence's debounce and the "
        "network are all in it.",
        "",
        f"- general interrogation: {r['points']} points, "
        f"{'the same as' if r['interrogation_matches_points_table'] else 'NOT the same as'} "
        "`stereopose points`",
        f"- zone events (enter, exit) in the log: {r['zone_events']}; of those, "
        f"{r['point_changes']} change a zone's occupied point (the others are an enter while "
        f"someone else is inside, or an exit leaving someone: {r['unchanged']}); found at the "
        f"master with their value and time tag: {r['matched']}; not found: {r['unmatched']}",
    ]
    if "latency_s" in r:
        lat = r["latency_s"]
        md += [
            f"- latency: median {lat['median']} s, p95 {lat['p95']} s, max {lat['max']} s; "
            f"{r['within_1s']} of {r['matched']} within 1 s",
            "- against the row's appearance in the event log (what /api/events answers; polled "
            "every 20 ms, so up to 0.02 s late): "
            + (
                f"median {r['after_log_s']['median']:+.3f} s, max {r['after_log_s']['max']:+.3f} s "
                "(negative: the master had it first)"
                if r.get("after_log_s")
                else "none seen"
            ),
            f"- time tag against the event's wall time: at most {r['tag_error_ms_max']} ms "
            "(CP56Time2a holds milliseconds)",
        ]
    md.append(f"- serve's exit status on SIGTERM: {r['serve_exit']}")
    return md


if __name__ == "__main__":
    main()
