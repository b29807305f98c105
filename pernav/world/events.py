"""What happens to the driver's car in a drive: instructions understood, and the event counters."""

from __future__ import annotations

from dataclasses import dataclass, field

from pernav.world.constants import SIDE


@dataclass
class Heard:
    """An instruction the driver understood: usable from ``active_at`` until ``expires_at``."""

    instruction: int
    heard_at: float
    active_at: float
    expires_at: float

    @property
    def direction(self) -> str | None:
        return SIDE.get(self.instruction)


@dataclass
class Events:
    """Counters of what happened to the driver's car."""

    vehicle_collisions: int = 0
    edge_strikes: int = 0
    traffic_collisions: int = 0  # traffic-traffic (should stay 0)
    harsh_brakes: int = 0
    swerves: int = 0
    forgotten: int = 0  # instructions that faded from memory unused
    discarded: int = 0  # instructions dropped on entering a junction (too late for it)
    misunderstood: int = 0
    ignored: int = 0
    log: list = field(default_factory=list)
