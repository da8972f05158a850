"""Reading ahead (io.readahead): the same items in their order, errors in their place, a
bounded queue, and a thread that ends when closed."""

from __future__ import annotations

import itertools
import threading

import pytest

from stereopose.io.readahead import ReadAhead
from waiting import wait_until


def test_the_items_come_in_their_order_each_once():
    assert list(ReadAhead(range(100), depth=3)) == list(range(100))
    assert list(ReadAhead([], depth=1)) == []


def test_an_error_is_raised_after_the_items_before_it():
    def items():
        yield 1
        yield 2
        raise ValueError("corrupt frame 3")

    ahead = ReadAhead(items())
    assert next(ahead) == 1 and next(ahead) == 2
    with pytest.raises(ValueError, match="corrupt frame 3"):
        next(ahead)
    with pytest.raises(StopIteration):
        next(ahead)


def test_at_most_depth_items_wait_and_close_ends_an_endless_reader():
    made = itertools.count()
    produced = []

    def endless():
        for k in made:
            produced.append(k)
            yield k

    ahead = ReadAhead(endless(), depth=2, name="test-read-ahead")
    assert next(ahead) == 0
    # the queue holds 2, and the reader holds one more it cannot put
    wait_until(lambda: len(produced) == 4, "the reader filled its queue")
    assert len(produced) == 4
    ahead.close()
    assert not ahead.alive
    assert "test-read-ahead" not in {t.name for t in threading.enumerate()}
    with pytest.raises(StopIteration):
        next(ahead)


def test_the_depth_is_checked():
    with pytest.raises(ValueError, match="depth"):
        ReadAhead([1], depth=0)
