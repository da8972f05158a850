"""The control room's API pages are bounded in bytes whatever their rows hold."""

from __future__ import annotations

import json

from stereopose.controlroom.app import MAX_PAGE_BYTES, _within


def test_a_page_stops_at_its_bytes_and_keeps_at_least_one_row():
    rows = [{"id": k, "detail": "x" * 60_000} for k in range(200)]  # 12 MB in all
    kept = _within(rows)
    assert 0 < len(kept) < len(rows) and kept == rows[: len(kept)]
    assert len(json.dumps(kept)) <= MAX_PAGE_BYTES + len(kept)
    assert _within(rows, max_bytes=10) == rows[:1]  # one row larger than a page still goes
    small = [{"id": k} for k in range(100)]
    assert _within(small) == small
