"""Acknowledgements asked of sites: `ask` stores the command, `send` publishes it on the
site's `commands/ack` and again every `resend_s` until the site answers on `commands/done`,
so an acknowledgement made while a site is cut off reaches it when the link is back."""

from __future__ import annotations

import json
import logging
import threading
import time
from typing import TYPE_CHECKING

from stereopose.controlroom.store import ControlStore, StoreError
from stereopose.site.wire import COMMAND_ACK, ack_body, site_topic

if TYPE_CHECKING:
    import paho.mqtt.client as paho

logger = logging.getLogger(__name__)


class AckCommands:
    """The commands not answered yet (any thread asks; the ingest's thread sends and takes
    the answers). counts: the ingest's figures (commands_sent, commands_done, malformed,
    store_errors); shared: several workers share the store (and the sites' answers)."""

    def __init__(
        self,
        store: ControlStore,
        client: paho.Client,
        prefix: str,
        name: str,
        counts: dict[str, int],
        *,
        resend_s: float = 5.0,
        shared: bool = False,
    ) -> None:
        self.store, self.client, self.prefix, self.name = store, client, prefix, name
        self.counts, self.resend_s, self.shared = counts, float(resend_s), shared
        self._lock = threading.Lock()
        # command -> [site, incident, by, last sent (monotonic; 0: not yet)]
        self._commands: dict[int, list] = {
            c: [s, i, b, 0.0] for c, s, i, b in store.pending_commands()
        }
        self._pending_checked = time.monotonic()

    def ask(self, site: str, incident: int, by: str) -> int:
        """Ask `site` to acknowledge its `incident` as `by`; the command's id. StoreError
        when it cannot be stored."""
        command = self.store.add_command(site, incident, by, time.time())
        with self._lock:
            self._commands[command] = [site, incident, by, 0.0]
        return command

    def send_all_again(self) -> None:
        """A new connection: every unanswered command goes again at once."""
        with self._lock:
            for c in self._commands.values():
                c[3] = 0.0

    def send(self) -> None:
        """The commands due (never sent, or sent `resend_s` ago) published."""
        now = time.monotonic()
        if self.shared and now - self._pending_checked > self.resend_s:
            self._pending_checked = now  # answered through another worker: not sent again
            try:
                open_ = {c for c, *_ in self.store.pending_commands()}
            except StoreError:
                open_ = None
            if open_ is not None:
                with self._lock:
                    for c in [c for c in self._commands if c not in open_]:
                        del self._commands[c]
        with self._lock:
            due = [(c, v) for c, v in self._commands.items() if now - v[3] >= self.resend_s]
            for _, v in due:
                v[3] = now
        for command, (site, incident, by, _) in due:
            body = ack_body(command, incident, by, self.name)
            self.client.publish(site_topic(self.prefix, site, COMMAND_ACK), body, qos=1)
            self.counts["commands_sent"] += 1

    def done(self, site: str, payload: bytes) -> None:
        """A site's answer on `commands/done`: its command finished in the store."""
        try:
            answer = json.loads(payload)
            command, result = int(answer["command"]), str(answer["result"])[:32]
        except (ValueError, TypeError, KeyError, UnicodeDecodeError, OverflowError):
            self.counts["malformed"] += 1
            return
        with self._lock:
            mine = self._commands.get(command)
            if mine is not None and mine[0] != site:  # not this site's command: kept
                return
            self._commands.pop(command, None)
        if mine is None:
            if self.shared:  # another worker's: answered in the shared store
                self._finish(command, result, site=site)
            return
        self._finish(command, result)
        self.counts["commands_done"] += 1
        if result != "acknowledged":
            logger.info(
                "control room: site %s answered the acknowledgement of incident %s: %s",
                site,
                mine[1],
                result,
            )

    def _finish(self, command: int, result: str, site: str | None = None) -> None:
        try:
            if site is None:
                self.store.finish_command(command, result, time.time())
            else:
                self.store.finish_command(command, result, time.time(), site=site)
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
