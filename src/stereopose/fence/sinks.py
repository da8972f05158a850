"""Event sinks now live in ``stereopose.io.sinks.events``; their names stay importable here."""

from stereopose.io.sinks.events import (
    COLUMNS,
    SCHEMA,
    CallbackSink,
    JsonlSink,
    SqliteSink,
    WebhookSink,
    describe,
    query_events,
    read_events,
)

__all__ = [
    "COLUMNS",
    "SCHEMA",
    "CallbackSink",
    "JsonlSink",
    "SqliteSink",
    "WebhookSink",
    "describe",
    "query_events",
    "read_events",
]
