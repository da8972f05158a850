"""Behaviour: each person's posture and the behaviour rules of the site file (person down,
lone worker, work position, immobile, overreach), which raise events beside the zones'.

The monitor that applies the rules is behaviour.rules.BehaviourMonitor (imported from there:
it needs the zones' geometry, and fence.site reads the rules' definitions from here).
"""

from stereopose.behaviour.definitions import (
    ALARM_TYPES,
    BEHAVIOUR_KIND,
    RULE_TYPES,
    ImmobileRule,
    LoneWorkerRule,
    OverreachRule,
    PersonDownRule,
    Rule,
    WorkPositionRule,
    format_rules,
    parse_rules,
)
from stereopose.behaviour.posture import (
    FLAGS,
    POSTURES,
    UNKNOWN,
    Posture,
    PostureSettings,
    PostureTracker,
    classify,
)

__all__ = [
    "ALARM_TYPES",
    "BEHAVIOUR_KIND",
    "FLAGS",
    "POSTURES",
    "RULE_TYPES",
    "UNKNOWN",
    "ImmobileRule",
    "LoneWorkerRule",
    "OverreachRule",
    "PersonDownRule",
    "Posture",
    "PostureSettings",
    "PostureTracker",
    "Rule",
    "WorkPositionRule",
    "classify",
    "format_rules",
    "parse_rules",
]
