"""The service's signal handling leaves the process's SIGINT and SIGTERM as it found them,
whatever order the frame loop's Ctrl-C handler and the closing's quiet one are undone in."""

from __future__ import annotations

import signal
import threading

from stereopose.pipeline.interrupt import Interrupt
from stereopose.site.parts import quiet_signals, stop_signals


def test_the_handlers_come_back_as_they_were_after_interleaved_undos() -> None:
    before = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM))
    with stop_signals():
        quiet = quiet_signals()
        with Interrupt(threading.Event()).installed():
            quiet.__enter__()  # the closing starts while the loop's handler is installed
        # the loop's handler undone first, the quiet one after: it puts back the loop's
        quiet.__exit__(None, None, None)
        assert signal.getsignal(signal.SIGINT) is not before[0]  # stale until the end
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
