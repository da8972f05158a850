"""What an OPC UA client's Acknowledge(EventId, Comment) on a condition names, and whether its
caller may acknowledge (scada.opcua runs it on the incident book): the condition's incident, or
the status code that refuses the call.

A caller may acknowledge when it logged in as a console user (scada.opcua_security.Login) who
still exists with the same role and password and has a role of ACK_ROLES (operator, admin);
anonymous clients never may. The call names a condition the address space shows, with exactly
its two arguments, an EventId of one of the condition's own events, and a condition not yet
acknowledged.
"""

from __future__ import annotations

import logging
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Protocol

from asyncua import ua
from asyncua.crypto.permission_rules import User
from asyncua.ua.status_codes import StatusCodes

from stereopose.errors import StereoposeError
from stereopose.scada.opcua_security import ACK_ROLES, Login

if TYPE_CHECKING:
    from stereopose.alarms import IncidentBook, IncidentRecord
    from stereopose.scada.opcua_space import SiteSpace
    from stereopose.web.users import UserStore

__all__ = ["IncidentSide", "comment_of", "may_acknowledge", "refusal"]

logger = logging.getLogger(__name__)


class IncidentSide(Protocol):
    """The incident book as the server uses it (site.desk.IncidentDesk, given when the server
    is made): whether the frame loop runs it yet, then its book read under its lock, an
    incident acknowledged, the Unix time of t = 0 (None: the changes carry no wall times)."""

    @property
    def running(self) -> bool: ...
    @property
    def lock(self) -> AbstractContextManager: ...
    @property
    def book(self) -> IncidentBook: ...
    @property
    def wall_start(self) -> float | None: ...

    def acknowledge(self, incident_id: int, by: str) -> IncidentRecord: ...


def may_acknowledge(users: UserStore, caller: User | None) -> bool:
    """Whether `caller` (asyncua's user of the calling session) may acknowledge now."""
    if not isinstance(caller, Login) or caller.name is None:  # anonymous: asyncua's user
        return False
    try:
        user = users.get(caller.name)
    except StereoposeError as e:
        logger.error("OPC UA: cannot read the users: %s", e)
        return False
    # removed, or its role or password changed since the login: refused
    return user is not None and user.stamp == caller.stamp and user.role in ACK_ROLES


def refusal(space: SiteSpace, parent: ua.NodeId, args: tuple[ua.Variant, ...]) -> int | None:
    """The status code that refuses an Acknowledge of condition `parent` with `args`, None
    when the call may go to the book (the incident: space.by_node[parent])."""
    incident = space.by_node.get(parent)
    if incident is None:
        return StatusCodes.BadNodeIdUnknown
    cond = space.conditions[incident]
    if len(args) != 2:
        missing = len(args) < 2
        return StatusCodes.BadArgumentsMissing if missing else StatusCodes.BadTooManyArguments
    event_id = args[0].Value if isinstance(args[0], ua.Variant) else None
    if not isinstance(event_id, bytes) or event_id not in cond.event_ids:
        return StatusCodes.BadEventIdUnknown
    if cond.acked:
        return StatusCodes.BadConditionBranchAlreadyAcked
    return None


def comment_of(args: tuple[ua.Variant, ...]) -> str:
    """The call's Comment (its second argument, a LocalizedText), "" when none."""
    comment = args[1].Value if len(args) > 1 and isinstance(args[1], ua.Variant) else None
    return (comment.Text or "") if isinstance(comment, ua.LocalizedText) else ""
