"""What nodes send: keypoints, pictures and health round trips; hostile messages refused."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from stereopose.detection.light import MODES
from stereopose.nodes.wire import (
    LIGHT_MODES,
    Topics,
    WireError,
    decode_health,
    decode_people,
    decode_picture,
    encode_people,
    encode_picture,
    health_message,
)
from stereopose.types import People2D


def _people(n: int, camera: str = "cam01") -> People2D:
    rng = np.random.default_rng(n)
    kp = np.c_[rng.uniform(0, 1000, (n * 17, 2)), rng.uniform(0.1, 1, n * 17)].reshape(n, 17, 3)
    if n:
        kp[0, 3] = (np.nan, np.nan, 0.0)  # a joint not seen
    boxes = rng.uniform(0, 1000, (n, 4))
    return People2D(camera, 7, kp, boxes, rng.uniform(0.3, 1, n))


@pytest.mark.parametrize("n", [0, 1, 3])
def test_people_come_back_as_sent_to_a_tenth_of_a_pixel(n):
    sent = _people(n)
    payload = encode_people("node-a", sent, 1.8e9 + 0.125, (1088, 1920))
    got = decode_people(payload, "cam01")
    assert (got.node, got.camera, got.frame, got.size) == ("node-a", "cam01", 7, (1088, 1920))
    assert got.t == pytest.approx(1.8e9 + 0.125, abs=1e-6)
    kp = got.people.keypoints
    assert kp.shape == (n, 17, 3)
    seen = np.isfinite(sent.keypoints[..., 0])
    assert np.allclose(kp[seen][:, :2], sent.keypoints[seen][:, :2], atol=0.051)
    assert np.allclose(kp[seen][:, 2], sent.keypoints[seen][:, 2], atol=0.0051)
    assert not np.isfinite(kp[~seen][:, :2]).any()
    if n:
        assert np.allclose(got.people.boxes, sent.boxes, atol=0.051)
        assert np.allclose(got.people.scores, sent.scores, atol=0.0006)
    # the size the docs state: about 100 bytes with nobody, about 350 more a person
    assert len(payload) < 120 + 380 * n


def _doc(**change) -> bytes:
    doc = json.loads(encode_people("n", _people(1), 1.8e9, (10, 10)))
    doc.update(change)
    return json.dumps(doc).encode()


@pytest.mark.parametrize(
    ("payload", "why"),
    [
        (b"\xff\xfe", "not JSON"),
        (b"[1, 2]", "not a JSON object"),
        (_doc(v=2), "version"),
        (_doc(camera="cam02"), "on the topic of camera"),
        (_doc(node=""), "no node"),
        (_doc(frame=-1), "frame"),
        (_doc(t="soon"), "t:"),
        (_doc(size=[1]), "size"),
        (_doc(people=[{"k": [1, 2]}]), "people[0].k"),
        (_doc(people=[{"k": [1e999] * 51}]), "finite"),
        (_doc(people=[{"k": [1] * 50 + [2]}]), "confidence"),
        (_doc(people=[{"k": [0] * 51}] * 300), "at most"),
        (b"[" * 150_000 + b"]" * 150_000, "bytes"),
    ],
)
def test_a_hostile_or_broken_keypoints_message_is_refused_with_its_problem(payload, why):
    with pytest.raises(WireError, match=why.replace("[", r"\[").replace("]", r"\]")):
        decode_people(payload, "cam01")


def test_pictures_and_health_round_trip_and_refuse_what_they_are_not():
    jpeg = b"\xff\xd8" + b"x" * 100
    assert decode_picture(encode_picture(12.5, jpeg)) == (12.5, jpeg)
    for bad in (b"", b"12345678" + b"PNG.", encode_picture(math.nan, jpeg)):
        with pytest.raises(WireError):
            decode_picture(bad)
    doc = decode_health(health_message("a", "online", clock=5.0, cameras={}))
    assert doc["clock"] == 5.0
    assert decode_health(health_message("a", "offline"))["state"] == "offline"
    for bad in (b"{}", health_message("a", "online"), health_message("a", "asleep")):
        with pytest.raises(WireError):
            decode_health(bad)
    # each camera's light, one of the light watch's modes (a peer's text is refused)
    night = {"cam01": {"fps": 25.0, "up": True, "light": "night"}, "cam02": {"light": None}}
    doc = decode_health(health_message("a", "online", clock=5.0, cameras=night))
    assert doc["cameras"]["cam01"]["light"] == "night"
    with pytest.raises(WireError, match=r"cameras\.light"):
        decode_health(health_message("a", "online", clock=5.0, cameras={"c": {"light": "x"}}))
    assert LIGHT_MODES == MODES


def test_topics_name_any_camera_and_only_their_own():
    t = Topics.of("stereopose/", "north site")
    assert t.keypoints("cam/1") == "stereopose/north site/keypoints/cam%2F1"
    assert t.parse(t.keypoints("cam/1")) == ("keypoints", "cam/1")
    assert t.parse(t.node("n+1")) == ("nodes", "n+1")
    assert t.parse("stereopose/other/keypoints/cam01") is None
    assert t.parse("stereopose/north site/people") is None
    assert t.parse("stereopose/north site/keypoints/a/b") is None
