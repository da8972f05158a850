"""A zone's breakers and earthing switches read from the utility's RTU over IEC 60870-5-104:
a c104 master (Client) per RTU (host, port) that puts its points' values onto a PowerBoard
(zones.power_state), on c104's thread, never in the frame loop's way.

A general interrogation when the link opens and every `interrogation_s` after, spontaneous
changes as they come, reconnection by itself when the link drops (c104's, every few seconds); a
link whose start-up c104 missed (left muted, or awaiting its opening, over a period) is unmuted
or reconnected (figures `iec104_unmuted`, `iec104_reconnected`). A lost link makes its points
unknown at once; a point with invalid quality (or a double point indeterminate) is unknown
(scada.iec104_board, shared with the TLS master). Points are M_SP_TB_1 / M_DP_TB_1
(`time_tag = false`: M_SP_NA_1 / M_DP_NA_1), as the RTU sends them.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import MutableMapping
from typing import TYPE_CHECKING, Any

from stereopose.errors import ConfigError
from stereopose.scada.iec104_board import RtuPoints
from stereopose.scada.iec104_settings import typed_callback
from stereopose.zones.power import Iec104Point
from stereopose.zones.power_state import PowerBoard

if TYPE_CHECKING:
    import c104

__all__ = ["Iec104Master"]

logger = logging.getLogger(__name__)


class Iec104Master:
    """A c104 master of one RTU (see the module)."""

    def __init__(
        self,
        host: str,
        port: int,
        points: list[Iec104Point],
        board: PowerBoard,
        figures: MutableMapping[str, int],
    ) -> None:
        import c104

        self.c104, self.figures = c104, figures
        self.host, self.port = host, int(port)
        self.rtu = RtuPoints(host, self.port, points, board, figures)
        self.interrogation_s = self.rtu.interrogation_s
        self.client = c104.Client(tick_rate_ms=50, command_timeout_ms=5000)
        connection = self.client.add_connection(
            ip=host, port=self.port, init=c104.Init.INTERROGATION
        )
        if connection is None:
            raise ConfigError(f"zone state: cannot reach an IEC 104 RTU at {host}:{port}")
        self.connection = connection
        self.connection.on_state_change(
            callable=typed_callback(
                lambda connection, state: self._on_state(connection, state),
                connection=c104.Connection,
                state=c104.ConnectionState,
                ret=None,
            )
        )
        on_receive = typed_callback(
            lambda point, previous_info, message: self._on_receive(point, previous_info, message),
            point=c104.Point,
            previous_info=c104.Information,
            message=c104.IncomingMessage,
            ret=c104.ResponseState,
        )
        self.stations: dict[int, Any] = {}
        for p in points:
            ca = p.common_address
            station = self.stations.get(ca) or connection.add_station(common_address=ca)
            if station is None:
                raise ConfigError(f"zone state: IEC 104 {host}:{port}: no station {ca}")
            self.stations[ca] = station
            kind = {
                (False, True): c104.Type.M_SP_TB_1,
                (False, False): c104.Type.M_SP_NA_1,
                (True, True): c104.Type.M_DP_TB_1,
                (True, False): c104.Type.M_DP_NA_1,
            }[(p.double, p.time_tag)]
            point = station.add_point(io_address=p.ioa, type=kind)
            if point is None:
                raise ConfigError(f"zone state: IEC 104 {host}:{port}: no point {p.ioa}")
            point.on_receive(callable=on_receive)
        self._open = False
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._interrogate, name="zone-state-iec104", daemon=True
        )

    def __repr__(self) -> str:
        return f"IEC 104 master of {self.host}:{self.port}"

    def start(self) -> None:
        self.client.start()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self.client.stop()
        self._thread.join(timeout=5.0)

    def _interrogate(self) -> None:
        """A general interrogation every interrogation_s while the link is open.

        c104's Client can miss its own start-up of a connection: the socket then stays open
        and muted (no STARTDT: the RTU sends nothing), or stays awaiting its opening. A link
        seen so at two looks in a row is started again: unmuted, or reconnected (counted)."""
        c104, stuck = self.c104, None
        while not self._stop.wait(self.interrogation_s):
            state = self.connection.state
            if state in (c104.ConnectionState.OPEN_MUTED, c104.ConnectionState.CLOSED_AWAIT_OPEN):
                if stuck == state:
                    self._restart(state)
                    state = None
                stuck = state
                continue
            stuck = None
            if state != c104.ConnectionState.OPEN:
                continue
            for ca in self.stations:
                try:
                    self.connection.interrogation(common_address=ca, wait_for_response=False)
                except Exception as e:  # a refused command: the next period tries again
                    logger.debug("IEC 104 %s:%d: interrogation: %s", self.host, self.port, e)

    def _restart(self, state: c104.ConnectionState) -> None:
        muted = state == self.c104.ConnectionState.OPEN_MUTED
        self.figures["iec104_unmuted" if muted else "iec104_reconnected"] += 1
        logger.info(
            "IEC 104 %s:%d: link %s over a period, %s",
            self.host,
            self.port,
            "muted" if muted else "still opening",
            "STARTDT again" if muted else "connecting again",
        )
        try:
            if muted:
                self.connection.unmute()
            else:
                self.connection.disconnect()
                self.connection.connect()
        except Exception as e:  # the next period tries again
            logger.debug("IEC 104 %s:%d: restarting the link: %s", self.host, self.port, e)

    def _on_state(
        self, connection: c104.Connection, state: c104.ConnectionState
    ) -> None:  # c104's thread
        c104 = self.c104
        if state in (c104.ConnectionState.OPEN, c104.ConnectionState.OPEN_MUTED):
            self._open = True
            return
        if not self._open:  # not yet open (connecting): its points have no value yet anyway
            return
        self._open = False
        self.rtu.lost()

    def _on_receive(
        self, point: c104.Point, previous_info: c104.Information, message: c104.IncomingMessage
    ) -> c104.ResponseState:  # c104's thread
        c104 = self.c104
        try:
            station, quality = point.station, point.quality
            if station is None or quality is None:  # a point of no station, or no quality
                raise ValueError(f"point {point.io_address} has no station or quality")
            ca, ioa = station.common_address, point.io_address
            value = point.value
            good = bool(quality.is_good())
            if isinstance(value, c104.Double):
                dpi = {c104.Double.OFF: 1, c104.Double.ON: 2, c104.Double.INTERMEDIATE: 0}
                self.rtu.double(ca, ioa, dpi.get(value, 3), good)
            else:
                self.rtu.single(ca, ioa, bool(value), good)
        except Exception as e:  # a message this master cannot read: counted, never raised
            self.rtu.refused()
            logger.debug("IEC 104 %s:%d: a message not read: %s", self.host, self.port, e)
        return c104.ResponseState.NONE
