"""The service's warnings on site across site changes (onsite.service.OnSite): built at
start, built again on a thread at a new site, unchanged speakers and signals kept."""

from __future__ import annotations

from modbus_device import IoModule
from rtp_listener import Listener
from stereopose.fence.site import parse_site
from stereopose.onsite.service import OnSite
from waiting import wait_until

BUSBAR = {
    "name": "busbar",
    "kind": "energized",
    "polygon": [[-2.0, -0.5], [-1.5, -0.5], [-1.5, 0.5], [-2.0, 0.5]],
    "z": [1.0, 2.5],
    "margin_m": 0.5,
}


def site(speakers, signals=(), **warnings):
    return parse_site(
        {
            "zones": [BUSBAR],
            "warnings": warnings,
            "speakers": list(speakers),
            "signals": list(signals),
        }
    )


def test_a_new_site_keeps_what_did_not_change_and_closes_what_went():
    a, b = Listener(), Listener()
    module = IoModule().start()
    pa1 = {"name": "pa1", "url": f"rtp://127.0.0.1:{a.port}", "zones": ["busbar"]}
    pa2 = {"name": "pa2", "url": f"rtp://127.0.0.1:{b.port}", "zones": ["busbar"]}
    tower = {"name": "tower", "host": "127.0.0.1", "port": module.port, "coils": {"beacon": 0}}
    tower["zones"] = ["busbar"]
    onsite = OnSite(site([pa1], [tower]))
    try:
        first = onsite.warner
        kept, old_tower = first.speakers["pa1"], first.signals["tower"]
        onsite.set_site(site([pa1, pa2], [{**tower, "coils": {"siren": 1}}]))
        wait_until(lambda: onsite.warner is not first, "the new site's warner")
        now = onsite.warner
        assert now.speakers["pa1"] is kept and set(now.speakers) == {"pa1", "pa2"}
        assert now.signals["tower"] is not old_tower  # its coils changed: opened anew
        wait_until(lambda: not old_tower._thread.is_alive(), "the old signal closed")
        onsite.set_site(parse_site({"zones": [BUSBAR]}))  # no warnings any more
        wait_until(lambda: onsite.warner is None, "nothing on site")
        assert onsite.now() == {"warnings": [], "calls": [], "silenced": []}
        assert not kept._thread.is_alive()
    finally:
        onsite.close()
        module.stop()


def test_the_outputs_figures_count_what_they_did_and_dropped():
    ear = Listener()
    pa = {"name": "pa", "url": f"rtp://127.0.0.1:{ear.port}", "zones": ["busbar"]}
    onsite = OnSite(site([pa]))
    try:
        for _ in range(300):
            onsite.controls.test("pa", by="ada")  # more than a step takes: the oldest dropped
        figures = onsite.figures()
        assert figures["acts_dropped"] >= 44 and figures["calls_dropped"] == 0
        assert set(figures["speakers"]["pa"]) >= {"packets", "messages", "send_errors"}
        assert figures["signals"] == {}
    finally:
        onsite.close()
