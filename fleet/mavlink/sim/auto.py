"""AUTO: flying the uploaded mission item by item, as ArduCopter's AP_Mission does.

ArduPilot keeps home in item 0, so a mission starts at item 1 (PX4's at 0). Navigation items
are flown one after the other: NAV_TAKEOFF (climb to z), NAV_WAYPOINT (fly there, then wait
param1 seconds), NAV_LOITER_TIME (fly there, wait param1 seconds), NAV_DELAY (wait param1
seconds where it is), NAV_RETURN_TO_LAUNCH and NAV_LAND (land and disarm); any other item
(DO_*, CONDITION_*) is passed over. Each item begun
is announced ("Mission: 2 WP") and with MISSION_CURRENT, each navigation item done (after its
hold time) with MISSION_ITEM_REACHED, a waypoint also with "Reached command #2". At the end the vehicle hovers where it is (or stays landed).

A rover, a boat or a sub needs no NAV_TAKEOFF to start from where it is parked, and passes over
the items its firmware does not fly (NAV_TAKEOFF and NAV_LAND; a sub also NAV_RETURN_TO_LAUNCH).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, Protocol

from fleet.geo import Position
from fleet.mavlink.mission import MissionItem
from fleet.mavlink.sim.targets import TargetRefused
from fleet.mavlink.wire import mavlink

# AP_Mission::Mission_Command::type(): the names ArduPilot's "Mission: N <type>" uses.
NAV_NAMES = {
    mavlink.MAV_CMD_NAV_WAYPOINT: "WP",
    mavlink.MAV_CMD_NAV_TAKEOFF: "Takeoff",
    mavlink.MAV_CMD_NAV_LOITER_TIME: "LoitTime",
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: "RTL",
    mavlink.MAV_CMD_NAV_LAND: "Land",
    mavlink.MAV_CMD_NAV_DELAY: "Delay",
}


class Flight(Protocol):
    """What the mission asks of the vehicle (see ``MavSim``)."""

    @property
    def on_ground(self) -> bool: ...

    @property
    def armed(self) -> bool: ...

    def idle(self) -> bool:
        """No manoeuvre under way: hovering, or landed."""
        ...

    def here(self) -> Position: ...

    def item_target(self, item: MissionItem) -> Position:
        """Where an item points (its frame applied; lat/lng 0: here). Raises TargetRefused."""
        ...

    def climb_to(self, alt: float) -> None:
        """Take off (or climb) to ``alt`` metres above ground."""
        ...

    def go_to(self, target: Position) -> None: ...

    def hover_for(self, seconds: float) -> None:
        """Stay where it is for ``seconds`` of simulated time (``idle`` again after)."""
        ...

    def return_home(self) -> None: ...

    def land_at(self, spot: Position) -> None:
        """Fly to above ``spot`` (at the altitude it is at) and land there."""
        ...


class MissionRunner:
    """Runs the mission returned by ``items`` on ``flight``. ``send`` sends a message from the
    autopilot (it gets pymavlink's MAVLink object), ``text`` a STATUSTEXT at INFO severity;
    ``first_seq`` is where a mission starts (1 on ArduPilot, where item 0 is home);
    ``takes_off``: the vehicle must take off first (a copter); ``passed_over``: navigation
    commands the vehicle does not fly."""

    def __init__(
        self,
        flight: Flight,
        items: Callable[[], Sequence[MissionItem]],
        send: Callable[[Callable[[Any], None]], None],
        text: Callable[[str], None],
        *,
        first_seq: int,
        takes_off: bool = True,
        passed_over: frozenset[int] = frozenset(),
    ) -> None:
        self._flight = flight
        self._items = items
        self._send = send
        self._text = text
        self.first_seq = first_seq
        self._takes_off = takes_off
        self._passed_over = passed_over
        self.current = first_seq
        self.complete = False
        self._started = False  # the current item has been begun
        self._held = False  # the current waypoint's hold time has begun
        self._mission_of: Sequence[MissionItem] | None = None

    def refusal(self, *, armed: bool) -> str | None:
        """Why AUTO cannot be entered now, or None (ArduCopter's ModeAuto::init checks)."""
        items = self._items()
        if len(items) <= self.first_seq:
            return "no mission"
        if armed and self._flight.on_ground and self._takes_off:
            first = items[min(self.current, len(items) - 1)]
            if first.command != mavlink.MAV_CMD_NAV_TAKEOFF:
                return "Auto: Missing Takeoff Cmd"
        return None

    def start(self, seq: int | None = None) -> None:
        """Begin (or resume) the mission: at ``seq`` if given, at the start after it ended."""
        self._check_upload()
        if seq is not None:
            self.current = seq
        elif self.complete:
            self.current = self.first_seq
        self.complete = False
        self._started = False
        self._held = False
        self.send_current()

    def set_current(self, seq: int, *, running: bool) -> bool:
        """MAV_CMD_DO_SET_MISSION_CURRENT / MISSION_SET_CURRENT: jump to item ``seq`` (flown
        at once when ``running``). Returns False for an item that is not there."""
        self._check_upload()
        items = self._items()
        if not 0 <= seq < len(items):
            return False
        self.current = max(seq, self.first_seq)
        self.complete = False
        self._started = False
        self._held = False
        if not running:
            self.send_current()
        # When running, the next tick begins the item and announces it.
        return True

    def send_current(self) -> None:
        items = self._items()
        if not items:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self.complete:
            state = mavlink.MISSION_STATE_COMPLETE
        elif self._started:
            state = mavlink.MISSION_STATE_ACTIVE
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED
        seq, total = self.current, len(items)
        self._send(lambda mav: mav.mission_current_send(seq, total, state))

    def tick(self) -> None:
        """Advance the mission (called while in AUTO and armed)."""
        self._check_upload()
        items = self._items()
        # Items that are not flown take no time: pass over any number of them in one tick.
        for _ in range(len(items) + 1):
            if self.complete:
                return
            if self.current >= len(items):
                self._finish()
                return
            item = items[self.current]
            if not self._started:
                if not self._flight.armed:
                    return  # landed and disarmed: the mission waits
                if not self._begin(item):
                    self._advance()
                    continue
                return
            if not self._done(item):
                return
            if item.command == mavlink.MAV_CMD_NAV_WAYPOINT:
                self._text(f"Reached command #{item.seq}")  # as ArduCopter's verify_nav_wp
            self._reached(item.seq)
            self._advance()

    def _reached(self, seq: int) -> None:
        self._send(lambda mav: mav.mission_item_reached_send(seq))

    def _check_upload(self) -> None:
        items = self._items()
        if items is not self._mission_of:
            # A new mission starts over (ArduPilot also restarts a changed mission).
            self._mission_of = items
            self.current = self.first_seq
            self.complete = False
            self._started = False
            self._held = False

    def _advance(self) -> None:
        self.current += 1
        self._started = False
        self._held = False
        if self.current < len(self._items()):
            self.send_current()

    def _finish(self) -> None:
        self.complete = True
        self.current = max(self.first_seq, len(self._items()) - 1)
        self.send_current()

    def _begin(self, item: MissionItem) -> bool:
        """Start flying an item; False for one that is passed over."""
        name = NAV_NAMES.get(item.command)
        if name is None or item.command in self._passed_over:
            return False
        flight = self._flight
        try:
            if item.command == mavlink.MAV_CMD_NAV_TAKEOFF:
                target = flight.item_target(replace(item, x=0, y=0))
                flight.climb_to(max(target.alt, flight.here().alt))
            elif item.command in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME):
                flight.go_to(flight.item_target(item))
            elif item.command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                flight.return_home()
            elif item.command == mavlink.MAV_CMD_NAV_DELAY:
                # param1: seconds to wait where it is (-1: a time of day, not simulated).
                flight.hover_for(max(0.0, item.param1))
            else:
                flight.land_at(flight.item_target(item))
        except TargetRefused as exc:
            self._text(f"Mission: {item.seq} {name} skipped: {exc}")
            return False
        self._started = True
        self._text(f"Mission: {item.seq} {name}")
        self.send_current()
        return True

    def _done(self, item: MissionItem) -> bool:
        flight = self._flight
        if not flight.idle():
            return False
        if item.command in (mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, mavlink.MAV_CMD_NAV_LAND):
            return flight.on_ground
        if item.command in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME):
            hold_s = max(0.0, item.param1)
            if hold_s > 0 and not self._held:
                self._held = True
                flight.hover_for(hold_s)
                return False
        return True
