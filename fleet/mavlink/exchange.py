"""What the sub-protocols of a MAVLink link share: the vehicle's heartbeat and texts as the
link decodes them, the waiter a request collects its answers in, and ``LinkCore``: what a
sub-protocol (``commanding``, ``parameters``, ``mission_transfer``) needs of the link, which
``fleet.mavlink.link.MavlinkLink`` provides."""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any

from fleet.mavlink.modes import Autopilot, mode_name
from fleet.mavlink.wire import mavlink


@dataclass(frozen=True)
class Heartbeat:
    """The vehicle's last HEARTBEAT, decoded. ``received`` is on the link's monotonic clock."""

    system_id: int
    component_id: int
    mav_type: int
    autopilot: Autopilot
    base_mode: int
    custom_mode: int
    system_status: int
    received: float

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def mode(self) -> str:
        """The flight mode's name, e.g. "GUIDED" (ArduCopter) or "AUTO.LOITER" (PX4), from the
        mode table of the heartbeat's airframe type (ArduRover's "HOLD" is 4)."""
        return mode_name(self.autopilot, self.custom_mode, self.mav_type)


@dataclass(frozen=True)
class StatusText:
    """One STATUSTEXT line from the vehicle (chunks already joined)."""

    severity: int
    text: str
    received: float


@dataclass(frozen=True)
class CommandAck:
    """The COMMAND_ACK that ended a command (its result is ACCEPTED when returned)."""

    command: int
    result: int
    progress: int
    result_param2: int


class Waiter:
    """Collects the messages a pending request is waiting for (filled by the reader thread)."""

    def __init__(self, match: Callable[[Any], bool], *, any_component: bool = False) -> None:
        self.match = match
        self.any_component = any_component  # also the vehicle's other components' messages
        self.messages: queue.SimpleQueue[Any] = queue.SimpleQueue()

    def get(self, timeout_s: float) -> Any | None:
        try:
            return self.messages.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None


class LinkCore:
    """The link as its sub-protocols see it: who we are and who the vehicle is, the limits of
    a request, sending, and waiting for the vehicle's answers (``MavlinkLink`` implements the
    methods)."""

    source_system: int
    target_component: int
    command_timeout_s: float
    command_attempts: int
    heartbeat_period_s: float
    monotonic: Callable[[], float]
    _heartbeat: Heartbeat | None
    _command_lock: threading.Lock  # one command in flight
    _mission_lock: threading.Lock  # one mission transfer at a time
    _param_types: dict[str, int]  # MAV_PARAM_TYPE of each parameter seen

    @property
    def autopilot(self) -> Autopilot:
        raise NotImplementedError

    def send(self, build: Callable[[Any], None]) -> None:
        raise NotImplementedError

    def waiting(
        self, match: Callable[[Any], bool], *, any_component: bool = False
    ) -> AbstractContextManager[Waiter]:
        raise NotImplementedError

    def status_texts(self, since: float = ...) -> list[StatusText]:
        raise NotImplementedError

    def _target(self) -> int:
        raise NotImplementedError

    def _require_link(self) -> Heartbeat:
        raise NotImplementedError

    def _ask(self, waiter: Waiter, send: Callable[[Any], None], timeout: float) -> Any | None:
        """Send a request until ``waiter`` gets its answer, ``command_attempts`` times at most
        (``timeout`` each); the answer, or None."""
        for _attempt in range(self.command_attempts):
            self._require_link()
            self.send(send)
            msg = waiter.get(timeout)
            if msg is not None:
                return msg
        return None
