"""The zone-state master over IEC 104 secured by TLS (scada.iec104_tls), against a real c104
outstation with c104's transport security (mutual TLS): the zone follows its breaker and
earthing switch; an RTU whose certificate the master does not trust and a master the RTU does
not know never give a value; a cut link makes the points unknown; bad TLS settings are
errors naming the file."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from brokers import free_port, make_certificate
from stereopose.errors import ConfigError
from stereopose.fence import load_site
from stereopose.site.zone_sources import start_sources
from stereopose.zones.power_state import PowerBoard
from waiting import wait_until

c104 = pytest.importorskip("c104")

PANEL = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
POSITION = {"open": "OFF", "closed": "ON"}


class TlsRtu:
    """A c104 outstation over TLS with a breaker (2001) and an earthing switch (2002) that
    admits only the master's certificate."""

    def __init__(self, folder: Path, master_cert: Path) -> None:
        self.cert, self.key = make_certificate(folder, "rtu")
        tls = c104.TransportSecurity(validate=True, only_known=True)
        tls.set_certificate(cert=str(self.cert), key=str(self.key))
        tls.set_ca_certificate(cert=str(master_cert))
        tls.add_allowed_remote_certificate(cert=str(master_cert))
        self.port = free_port()
        self.server = c104.Server(
            ip="127.0.0.1", port=self.port, tick_rate_ms=50, transport_security=tls
        )
        station = self.server.add_station(common_address=7)
        self.points = {
            ioa: station.add_point(io_address=ioa, type=c104.Type.M_DP_TB_1) for ioa in (2001, 2002)
        }
        self.set(2001, "closed", send=False)
        self.set(2002, "open", send=False)
        self.server.start()

    def set(self, ioa: int, position: str, send: bool = True) -> None:
        self.points[ioa].value = getattr(c104.Double, POSITION[position])
        if send:
            self.points[ioa].transmit(cause=c104.Cot.SPONTANEOUS)

    def stop(self) -> None:
        self.server.stop()


def _site(folder: Path, port: int, tls: str) -> Path:
    link = f'host = "127.0.0.1", port = {port}, common_address = 7, type = "double"{tls}'
    path = folder / "site.toml"
    path.write_text(
        f"""
[[zones]]
name = "bay2_panel"
kind = "energized"
polygon = {PANEL}
z = [0.0, 2.5]
[zones.state]
dead_when = "qf == 'open' and qe == 'closed'"
[zones.state.points]
qf = {{ iec104 = {{ {link}, ioa = 2001 }} }}
qe = {{ iec104 = {{ {link}, ioa = 2002 }} }}
"""
    )
    return path


TLS = ', tls_ca = "rtu.pem", tls_certificate = "master.pem", tls_key = "master-key.pem"'


def _values(board: PowerBoard, site) -> dict:
    return {p.name: board.read(p.label).value for p in site.zones[0].power.points}


def test_a_zone_state_over_iec104_with_tls(tmp_path: Path) -> None:
    master_cert, _ = make_certificate(tmp_path, "master")
    rtu = TlsRtu(tmp_path, master_cert)
    site = load_site(_site(tmp_path, rtu.port, TLS))
    board = PowerBoard()
    sources = start_sources(site.zones, board, base=tmp_path)
    try:
        wait_until(
            lambda: _values(board, site) == {"qf": "closed", "qe": "open"},
            "the interrogation over TLS",
            timeout_s=30,
        )
        rtu.set(2001, "open")
        rtu.set(2002, "closed")
        wait_until(
            lambda: _values(board, site) == {"qf": "open", "qe": "closed"},
            "the spontaneous changes over TLS",
        )
        rtu.stop()
        wait_until(lambda: _values(board, site) == {"qf": None, "qe": None}, "unknown when cut")
        assert sources.figures["iec104_link_lost"] == 1
        assert sources.figures["iec104_received"] >= 4
    finally:
        sources.stop()
        rtu.stop()


def test_no_value_from_an_rtu_not_trusted_nor_for_a_master_not_known(tmp_path: Path) -> None:
    master_cert, _ = make_certificate(tmp_path, "master")
    rtu = TlsRtu(tmp_path, master_cert)
    stranger = tmp_path / "stranger"
    stranger.mkdir()
    make_certificate(stranger, "master")  # a certificate the RTU does not know
    shutil.copy(rtu.cert, stranger / "rtu.pem")
    impostor = tmp_path / "impostor"
    impostor.mkdir()
    make_certificate(impostor, "rtu")  # the master trusts another RTU's certificate
    for name in ("master.pem", "master-key.pem"):
        shutil.copy(tmp_path / name, impostor / name)
    runs = []
    try:
        for folder in (stranger, impostor):  # each handshake refused, counted, tried again
            site = load_site(_site(folder, rtu.port, TLS))
            board = PowerBoard()
            sources = start_sources(site.zones, board, base=folder)
            runs.append(sources)
            wait_until(lambda s=sources: s.figures["iec104_tls_refused"] >= 2, "refusals")
            assert _values(board, site) == {"qf": None, "qe": None}
            assert sources.figures["iec104_received"] == 0
    finally:
        for sources in runs:
            sources.stop()
        rtu.stop()


def test_bad_tls_settings_are_errors_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="tls_ca, tls_certificate, tls_key together"):
        load_site(_site(tmp_path, 2404, ', tls_ca = "rtu.pem"'))
    site = load_site(_site(tmp_path, 2404, TLS))
    with pytest.raises(ConfigError, match=r"rtu\.pem"):
        start_sources(site.zones, PowerBoard(), base=tmp_path)
