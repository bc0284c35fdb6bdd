"""The platform clock: wall time in a live system, simulated time in `simulate`."""

from __future__ import annotations

import time
from typing import Protocol

# `simulate` starts its clock at 0; a VV's logical Date there counts from this instant
# (2025-01-01T00:00:00Z), so two runs of a scenario see the same dates.
SIM_EPOCH_S = 1_735_689_600.0


class Clock(Protocol):
    def now_s(self) -> float:
        """Seconds on the platform clock."""
        ...

    def epoch_ms(self, t_s: float) -> int:
        """A platform-clock time as Unix epoch milliseconds (a VV's logical Date)."""
        ...

    def from_epoch_ms(self, epoch_ms: int) -> float:
        """Unix epoch milliseconds back to platform-clock seconds."""
        ...


class SystemClock:
    """Wall time: the platform clock is the Unix epoch."""

    def now_s(self) -> float:
        return time.time()

    def epoch_ms(self, t_s: float) -> int:
        return round(t_s * 1000)

    def from_epoch_ms(self, epoch_ms: int) -> float:
        return epoch_ms / 1000.0


class SimulatedClock:
    """Discrete-event time, set by the simulation; starts at 0 with the scenario."""

    def __init__(self, start_s: float = 0.0) -> None:
        self.t = start_s

    def now_s(self) -> float:
        return self.t

    def epoch_ms(self, t_s: float) -> int:
        return round((SIM_EPOCH_S + t_s) * 1000)

    def from_epoch_ms(self, epoch_ms: int) -> float:
        return epoch_ms / 1000.0 - SIM_EPOCH_S
