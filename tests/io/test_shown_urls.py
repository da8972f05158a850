"""URLs in messages and summaries never show credentials or a query's token."""

from __future__ import annotations

import logging

from hypothesis import given
from hypothesis import strategies as st

from stereopose.io.sinks.webhook import WebhookSink
from stereopose.io.source import shown_url
from stereopose.types import Event

# a secret that is not a word the shown URL keeps anyway (its scheme, host, port, path)
KEPT = "https rtsp cam.local:554/live/alarms?key=***"
secret = st.text(
    st.characters(codec="ascii", categories=("L", "N")), min_size=6, max_size=12
).filter(lambda s: s not in KEPT)


@given(secret, secret, st.sampled_from(["http", "https", "rtsp"]))
def test_credentials_and_query_are_never_shown(user: str, token: str, scheme: str) -> None:
    for url in (
        f"{scheme}://{user}:{token}@cam.local:554/live",
        f"{scheme}://{token}@cam.local/live",
        f"{scheme}://cam.local/alarms?key={token}",
    ):
        shown = shown_url(url)
        assert token not in shown and "cam.local" in shown


def test_a_plain_url_is_shown_as_it_is() -> None:
    assert shown_url("http://127.0.0.1:8080/alarms") == "http://127.0.0.1:8080/alarms"


def test_the_webhook_never_logs_its_token(caplog) -> None:
    """A receiver that is not there: every message about it leaves the token out."""
    caplog.set_level(logging.DEBUG)
    sink = WebhookSink("http://s3cr3t-token@127.0.0.1:9/alarms?key=s3cr3t-key")
    sink.write_events(
        [Event(t=0.1, frame=1, person=1, zone="z", kind="energized", type="enter", onset_t=0.1)]
    )
    sink.close()
    assert "webhook" in caplog.text
    assert "s3cr3t" not in caplog.text
