"""Work and operation tickets: the standardized actions in the specified position.

ticket    the ticket file (TOML, docs/formats.md#tickets): its steps, roles and isolated zones
monitor   one ticket checked frame by frame: roles bound, steps done in order, at their
          position, in time, the supervisor beside the operator, nobody alone
desk      the site's tickets (planned, active, completed, aborted) and what the frame loop
          asks of them: their events, and entries into isolated zones made info
"""

from stereopose.tickets.desk import TicketDesk, TicketError
from stereopose.tickets.monitor import TicketMonitor
from stereopose.tickets.ticket import Ticket, TicketStep, load_ticket, parse_ticket

__all__ = [
    "Ticket",
    "TicketDesk",
    "TicketError",
    "TicketMonitor",
    "TicketStep",
    "load_ticket",
    "parse_ticket",
]
