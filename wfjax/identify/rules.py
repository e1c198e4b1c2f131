"""Decisions: the flag rule and the maintenance rule sets (Trafikverket, FRA, user-defined).

A rule set has reading levels (on the wheel's highest detector reading, as the detector
alarms act) and optionally a length level (on the identified flat: acted on when
P(l > level) >= ``probability``).
"""

from __future__ import annotations

import dataclasses

__all__ = ["RuleSet", "TRAFIKVERKET", "FRA", "KIP", "flagged", "decide", "user_rule"]

KIP = 4448.2216  # N per kip


@dataclasses.dataclass(frozen=True)
class RuleSet:
    """Reading levels ``((level [N], action), ...)``, checked on the highest reading, and a
    length level [m] with its action and probability."""

    name: str
    readings: tuple = ()
    length: float | None = None
    length_action: str = "remove wheel"
    probability: float = 0.5


TRAFIKVERKET = RuleSet("Trafikverket", ((350e3, "stop train"),), 0.060, "remove wheel")
FRA = RuleSet("FRA", ((90 * KIP, "replace wheel (in service, 90 kips)"),
                      (80 * KIP, "replace wheel in shop (80 kips)")))


def user_rule(reading: float | None = None, length: float | None = None,
              probability: float = 0.5) -> RuleSet | None:
    """A user-defined :class:`RuleSet` (reading [N], length [m]); None when neither given."""
    if reading is None and length is None:
        return None
    return RuleSet("user", () if reading is None else ((float(reading), "act (reading)"),),
                   length, "act (length)", probability)


def flagged(p_long: float, probability: float = 0.9) -> bool:
    """The flag rule: flagged when P(l >= the flag length) >= ``probability``."""
    return bool(p_long >= probability)


def decide(rule: RuleSet, max_reading: float, p_longer) -> str:
    """The action of ``rule`` for a wheel whose highest reading is ``max_reading`` [N] and
    whose P(l > length) is ``p_longer(length)``: the first reading level exceeded (levels
    from the highest), then the length rule, else ``"ok"``."""
    actions = [a for level, a in sorted(rule.readings, reverse=True) if max_reading > level][:1]
    if rule.length is not None and p_longer(rule.length) >= rule.probability:
        actions.append(rule.length_action)
    return "; ".join(actions) or "ok"
