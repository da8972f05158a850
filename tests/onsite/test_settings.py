"""The site file's warnings on site: [warnings], [[speakers]], [[signals]] (onsite.settings)."""

from __future__ import annotations

import pytest

from stereopose.errors import ConfigError
from stereopose.fence.site import format_site, load_site, parse_site, site_doc

ZONE = {"name": "busbar", "kind": "energized", "polygon": [[0, 0], [1, 0], [1, 1]], "z": [1, 2]}
WORK = {"name": "work", "kind": "work_area", "polygon": [[0, 0], [3, 0], [3, 3]], "z": [0, 2]}


def site(**extra) -> dict:
    return {"zones": [dict(ZONE), dict(WORK)], **extra}


SPEAKER = {"name": "pa1", "url": "rtp://239.10.0.1:5004", "zones": ["busbar"]}
SIGNAL = {
    "name": "tower",
    "host": "127.0.0.1",
    "coils": {"beacon": 0, "siren": 1},
    "zones": ["busbar"],
}


def test_a_full_section_reads_and_writes_back_the_same():
    data = site(
        warnings={
            "language": "zh", "repeat_s": 3, "priorities": [1], "templates": {"enter": "危险"}
        },
        speakers=[{**SPEAKER, "codec": "pcma", "ttl": 2, "position": [1, 2]}, {
            "name": "pa2", "url": "rtp://127.0.0.1:6000", "zones": ["busbar", "work"],
            "health_url": "http://127.0.0.1:8080/health",
        }],
        signals=[{**SIGNAL, "port": 5020, "unit": 3, "priorities": ["critical", 2]}],
    )  # fmt: skip
    s = parse_site(data)
    w = s.warnings
    assert w.language == "zh" and w.repeat_s == 3.0 and w.priorities == (1,)
    assert w.speakers[0].multicast and w.speakers[0].codec == "pcma" and w.speakers[0].ttl == 2
    assert not w.speakers[1].multicast and w.speakers[1].zones == ("busbar", "work")
    assert w.signals[0].coils == (("beacon", 0), ("siren", 1)) and w.signals[0].priorities == (1, 2)
    again = parse_site(site_doc(s))
    assert again.warnings == w and format_site(again) == format_site(s)
    assert parse_site(site()).warnings is None  # none said: no warnings


def test_a_zone_can_stay_silent_on_site(tmp_path):
    path = tmp_path / "site.toml"
    path.write_text(format_site(parse_site({"zones": [{**ZONE, "on_site": False}]})))
    assert load_site(path).zones[0].on_site is False
    with pytest.raises(ConfigError, match="on_site: expected true or false"):
        parse_site({"zones": [{**ZONE, "on_site": "no"}]})


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"speakers": [{**SPEAKER, "zones": ["nowhere"]}]}, "speaker 'pa1': zones: unknown zone"),
        (
            {"speakers": [{**SPEAKER, "url": "http://10.0.0.1/"}]},
            "speaker 'pa1': url: expected rtp",
        ),
        ({"speakers": [{**SPEAKER, "url": "rtp://239.1.1.1:99999"}]}, "speaker 'pa1': url"),
        ({"speakers": [{**SPEAKER, "url": "rtp://pa.local:5004"}]}, "must be an IP address"),
        ({"speakers": [{**SPEAKER, "codec": "opus"}]}, "speaker 'pa1': codec"),
        ({"speakers": [{**SPEAKER, "volume": 3}]}, "speaker 'pa1': unknown key"),
        ({"speakers": [SPEAKER, SPEAKER]}, "used twice"),
        ({"signals": [{**SIGNAL, "coils": {"beacon": -1}}]}, r"signal 'tower': coils.beacon"),
        ({"signals": [{**SIGNAL, "coils": {}}]}, "signal 'tower': coils"),
        ({"signals": [{**SIGNAL, "port": 0}]}, "signal 'tower': port"),
        ({"signals": [{**SIGNAL, "host": "a b"}]}, "signal 'tower': host"),
        ({"signals": [{**SIGNAL, "priorities": [7]}]}, "signal 'tower': priorities"),
        ({"warnings": {"language": "fr"}}, r"\[warnings\] language"),
        ({"warnings": {"repeat_s": 0}}, r"\[warnings\] repeat_s"),
        ({"warnings": {"templates": {"bye": "x"}}}, "unknown message"),
        ({"warnings": {"recordings": {"nowhere.enter": "a.wav"}}}, "is not a message"),
        ({"warnings": []}, r"\[warnings\] must be a table"),
    ],
)
def test_a_bad_entry_names_its_key(change, message):
    with pytest.raises(ConfigError, match=message):
        parse_site(site(**change))


def test_a_template_with_an_unknown_placeholder_is_refused_at_start():
    from stereopose.onsite.settings import check_template

    assert [name for _, name in check_template("Stop. {zone}, {distance}.", "t")] == [
        "zone",
        "distance",
        None,
    ]
    for bad in ("Stop {who}", "Stop {zone:>5}", "Stop {zone"):
        with pytest.raises(ConfigError, match=r"\[warnings\] templates.approach"):
            check_template(bad, "[warnings] templates.approach")
        with pytest.raises(ConfigError, match=r"\[warnings\] templates.approach"):
            parse_site(site(warnings={"templates": {"approach": bad}}))
