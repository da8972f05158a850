"""The step chain's declared hand-over: a rule that reads what another gives (the tickets the
behaviour rule's postures) comes after it, or the chain is refused."""

from __future__ import annotations

import pytest

from stereopose.behaviour.rules import BehaviourMonitor
from stereopose.pipeline.step_rules import (
    BehaviourRule,
    StepChain,
    StepContext,
    TicketRule,
    step_chain,
)
from stereopose.tickets import TicketDesk
from stereopose.types import Event, People3D


class Giving:
    gives = frozenset({"postures"})

    def step(self, ctx: StepContext) -> list[Event]:
        ctx.postures = {}
        return []


class Reading:
    reads = frozenset({"postures"})

    def __init__(self) -> None:
        self.seen: list[object] = []

    def step(self, ctx: StepContext) -> list[Event]:
        self.seen.append(ctx.postures)
        return []


def test_a_rule_reading_what_a_later_one_gives_is_refused():
    with pytest.raises(ValueError, match=r"Reading reads \['postures'\].*must come after"):
        StepChain([Reading(), Giving()])
    reading = Reading()
    chain = StepChain([Giving(), reading])
    chain.step(0.0, 0, People3D.empty(0, 2))
    assert reading.seen == [{}]
    alone = Reading()  # nothing gives postures: read as None
    StepChain([alone]).step(0.0, 0, People3D.empty(0, 2))
    assert alone.seen == [None]


def test_the_tickets_read_the_behaviour_rules_postures_and_come_after_them():
    assert BehaviourRule.gives == TicketRule.reads == frozenset({"postures"})
    with pytest.raises(ValueError, match="TicketRule"):
        StepChain([TicketRule(TicketDesk(())), BehaviourRule(BehaviourMonitor([], (), 25.0, 2.0))])
    chain = step_chain(None, behaviour=BehaviourMonitor([], (), 25.0, 2.0), tickets=TicketDesk(()))
    assert [type(r) for r in chain.rules] == [BehaviourRule, TicketRule]
