"""The vehicle's side of the mission protocol, for the simulated copter.

It keeps the lists it receives per mission type (missions, fences, rally points), checks
fence lists as a vehicle would on upload, asks again for an item that does not come, and sends
the lists back on request.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fleet.mavlink.mission import MissionItem, validate_fence
from fleet.mavlink.sim.transport import reply_to
from fleet.mavlink.wire import mavlink

logger = logging.getLogger("cpcc.mavsim")

_MISSION_RETRY_S = 1.0  # re-request a mission item after this long (ArduPilot waits ~1 s too)
_MISSION_RETRIES = 5


@dataclass
class _Upload:
    """A mission upload in progress: who sends it, how many items, what arrived."""

    mission_type: int
    count: int
    partner: tuple[int, int]
    items: list[MissionItem]
    requested_at: float
    retries: int = 0


class MissionServer:
    """Answers MISSION_* messages. ``send`` sends a message (it gets pymavlink's MAVLink
    object), ``wall`` is the wall clock in seconds, ``name`` goes into the log."""

    def __init__(
        self, send: Callable[[Callable[[Any], None]], None], wall: Callable[[], float], name: str
    ) -> None:
        self._send = send
        self._wall = wall
        self.name = name
        self.missions: dict[int, list[MissionItem]] = {}
        self._upload: _Upload | None = None

    def handle(self, msg: Any) -> bool:
        """Handle a message if it belongs to the mission protocol; returns whether it did."""
        handler = {
            "MISSION_COUNT": self._on_mission_count,
            "MISSION_ITEM_INT": self._on_mission_item,
            "MISSION_ITEM": self._on_mission_item,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "MISSION_REQUEST_INT": self._on_mission_request,
            "MISSION_REQUEST": self._on_mission_request,
            "MISSION_CLEAR_ALL": self._on_mission_clear_all,
        }.get(msg.get_type())
        if handler is None:
            return False
        handler(msg)
        return True

    def tick(self) -> None:
        """Ask again for an item that has not come within a second (give up after five)."""
        self._check_upload()

    def _on_mission_count(self, msg: Any) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        partner = reply_to(msg)
        if msg.count == 0:
            self.missions[mission_type] = []
            self._upload = None
            self._mission_ack(partner, mavlink.MAV_MISSION_ACCEPTED, mission_type)
            return
        # A new MISSION_COUNT restarts the transfer (the GCS may have re-sent it).
        self._upload = _Upload(mission_type, int(msg.count), partner, [], self._wall())
        self._request_item(self._upload)

    def _request_item(self, upload: _Upload) -> None:
        seq = len(upload.items)
        system, component = upload.partner
        upload.requested_at = self._wall()
        self._send(
            lambda mav: mav.mission_request_int_send(system, component, seq, upload.mission_type)
        )

    def _on_mission_item(self, msg: Any) -> None:
        upload = self._upload
        mission_type = int(getattr(msg, "mission_type", 0))
        if upload is None or mission_type != upload.mission_type:
            return
        if msg.seq != len(upload.items):
            self._request_item(upload)  # out of order or repeated: ask for the one we need
            return
        upload.items.append(MissionItem.from_message(msg))
        upload.retries = 0
        if len(upload.items) < upload.count:
            self._request_item(upload)
            return
        self._upload = None
        result = int(mavlink.MAV_MISSION_ACCEPTED)
        if mission_type == mavlink.MAV_MISSION_TYPE_FENCE:
            result = validate_fence(upload.items)
        if result == mavlink.MAV_MISSION_ACCEPTED:
            self.missions[mission_type] = upload.items
            logger.info(
                "mavsim %s: %d items of mission type %d", self.name, len(upload.items), mission_type
            )
        self._mission_ack(upload.partner, result, mission_type)

    def _check_upload(self) -> None:
        upload = self._upload
        if upload is None or self._wall() - upload.requested_at < _MISSION_RETRY_S:
            return
        upload.retries += 1
        if upload.retries > _MISSION_RETRIES:
            self._upload = None
            self._mission_ack(
                upload.partner, mavlink.MAV_MISSION_OPERATION_CANCELLED, upload.mission_type
            )
            return
        self._request_item(upload)

    def _mission_ack(self, partner: tuple[int, int], result: int, mission_type: int) -> None:
        system, component = partner
        self._send(lambda mav: mav.mission_ack_send(system, component, result, mission_type))

    def _on_mission_request_list(self, msg: Any) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        count = len(self.missions.get(mission_type, []))
        system, component = reply_to(msg)
        self._send(lambda mav: mav.mission_count_send(system, component, count, mission_type))

    def _on_mission_request(self, msg: Any) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        items = self.missions.get(mission_type, [])
        system, component = reply_to(msg)
        if not 0 <= msg.seq < len(items):
            self._mission_ack(
                (system, component), mavlink.MAV_MISSION_INVALID_SEQUENCE, mission_type
            )
            return
        item = items[msg.seq]
        if msg.get_type() == "MISSION_REQUEST":
            # The float variant answers the old request (degrees, float32).
            self._send(
                lambda mav: mav.mission_item_send(
                    system,
                    component,
                    item.seq,
                    item.frame,
                    item.command,
                    item.current,
                    item.autocontinue,
                    item.param1,
                    item.param2,
                    item.param3,
                    item.param4,
                    item.lat,
                    item.lng,
                    item.z,
                    mission_type,
                )
            )
            return
        self._send(lambda mav: item.send(mav, system, component, mission_type))

    def _on_mission_clear_all(self, msg: Any) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        self.missions.pop(mission_type, None)
        self._mission_ack(reply_to(msg), mavlink.MAV_MISSION_ACCEPTED, mission_type)
