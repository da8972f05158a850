"""The outputs of the frame loop: every one a sink with ``write(frame)`` and ``close()``.

- files: 3D poses JSON lines, joints CSV, per-person TRC (streamed), trajectories, two-way
  smoothed exports;
- events: JSON lines, SQLite log, webhook, callback;
- stats: the run summary and the per-camera statistics (running aggregates).

The overlay videos and the report draw with viz, so their sinks live in pipeline/.
"""

from stereopose.io.sinks.base import FrameResult, Sink, close_all
from stereopose.io.sinks.events import (
    CallbackSink,
    JsonlSink,
    WebhookSink,
    describe,
    query_events,
    read_events,
)
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.io.sinks.files import (
    CsvSink,
    PosesSink,
    TracksSink,
    TrcSink,
    TwoWaySink,
    write_trajectories,
)
from stereopose.io.sinks.stats import CameraStatsSink, SummarySink

__all__ = [
    "CallbackSink",
    "CameraStatsSink",
    "CsvSink",
    "FrameResult",
    "JsonlSink",
    "PosesSink",
    "Sink",
    "SqliteSink",
    "SummarySink",
    "TracksSink",
    "TrcSink",
    "TwoWaySink",
    "WebhookSink",
    "close_all",
    "describe",
    "query_events",
    "read_events",
    "write_trajectories",
]
