"""The mission protocol over a MAVLink link: uploading and downloading a list (a mission,
the fence, the rally points) item by item, with resends when the vehicle goes quiet (a part
of ``MavlinkLink``)."""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

from fleet.mavlink.errors import MissionRejected, MissionTimeout
from fleet.mavlink.exchange import LinkCore, Waiter
from fleet.mavlink.mission import MissionItem
from fleet.mavlink.wire import mavlink


class MissionTransfer(LinkCore):
    """Mission, fence and rally lists to and from the vehicle (see ``fleet.mavlink.link``)."""

    def upload_mission(
        self,
        items: Sequence[MissionItem],
        mission_type: int,
        *,
        timeout_s: float | None = None,
    ) -> None:
        """Upload a list with the mission protocol (the fence with MAV_MISSION_TYPE_FENCE).

        MISSION_COUNT, then the vehicle asks for each item (MISSION_REQUEST_INT, or the older
        MISSION_REQUEST) and gets a MISSION_ITEM_INT, and ends with MISSION_ACK. When the
        vehicle goes quiet the last message is sent again (``command_attempts`` times in a row
        at most). An empty list clears the vehicle's list. Raises MissionRejected with the
        vehicle's MAV_MISSION_RESULT, MissionTimeout when it stalls, LinkLost.
        """
        timeout = self.command_timeout_s if timeout_s is None else timeout_s
        numbered = [item.with_seq(seq) for seq, item in enumerate(items)]

        def send_count() -> None:
            self.send(
                lambda mav: mav.mission_count_send(
                    self._target(), self.target_component, len(numbered), mission_type
                )
            )

        def send_item(item: MissionItem) -> None:
            self.send(
                lambda mav: item.send(mav, self._target(), self.target_component, mission_type)
            )

        def is_answer(msg: Any) -> bool:
            kind = msg.get_type()
            if kind not in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"):
                return False
            return getattr(msg, "mission_type", 0) == mission_type

        with self._mission_lock, self.waiting(is_answer) as waiter:
            resend: Callable[[], None] = send_count
            requested: set[int] = set()
            silent = 0
            self._require_link()
            send_count()
            while True:
                msg = waiter.get(timeout)
                if msg is None:
                    silent += 1
                    if silent >= self.command_attempts:
                        raise MissionTimeout(
                            f"mission upload (type {mission_type}) stalled after "
                            f"{len(requested)} of {len(numbered)} items"
                        )
                    self._require_link()
                    resend()
                    continue
                silent = 0
                if msg.get_type() == "MISSION_ACK":
                    if msg.type != mavlink.MAV_MISSION_ACCEPTED:
                        raise MissionRejected(int(msg.type), mission_type)
                    if len(requested) == len(numbered):
                        return
                    # An ACCEPTED ack before every item was asked for answers an earlier,
                    # abandoned transfer: keep going with this one.
                    continue
                seq = int(msg.seq)
                if not 0 <= seq < len(numbered):
                    continue
                requested.add(seq)
                item = numbered[seq]
                # MISSION_ITEM_INT answers MISSION_REQUEST too: ArduPilot and PX4 accept it,
                # and it keeps the coordinates exact (MISSION_ITEM's are float32 degrees).
                send_item(item)
                resend = functools.partial(send_item, item)

    def download_mission(
        self, mission_type: int, *, timeout_s: float | None = None
    ) -> list[MissionItem]:
        """Read a list back from the vehicle (MISSION_REQUEST_LIST, then each item).

        Returns the items in order. Raises MissionTimeout when the vehicle stops answering,
        LinkLost.
        """
        timeout = self.command_timeout_s if timeout_s is None else timeout_s
        target = self._target

        def is_count(msg: Any) -> bool:
            return bool(msg.get_type() == "MISSION_COUNT" and msg.mission_type == mission_type)

        def is_item(seq: int) -> Callable[[Any], bool]:
            return lambda msg: bool(
                msg.get_type() == "MISSION_ITEM_INT"
                and msg.seq == seq
                and msg.mission_type == mission_type
            )

        def request_item(seq: int) -> Callable[[Any], None]:
            return lambda mav: mav.mission_request_int_send(
                target(), self.target_component, seq, mission_type
            )

        with self._mission_lock:
            with self.waiting(is_count) as waiter:
                count_msg = self._answer(
                    waiter,
                    lambda mav: mav.mission_request_list_send(
                        target(), self.target_component, mission_type
                    ),
                    timeout,
                )
            items: list[MissionItem] = []
            for seq in range(int(count_msg.count)):
                with self.waiting(is_item(seq)) as waiter:
                    msg = self._answer(waiter, request_item(seq), timeout)
                items.append(MissionItem.from_message(msg).with_seq(seq))
            self.send(
                lambda mav: mav.mission_ack_send(
                    target(), self.target_component, mavlink.MAV_MISSION_ACCEPTED, mission_type
                )
            )
            return items

    def _answer(self, waiter: Waiter, send: Callable[[Any], None], timeout: float) -> Any:
        msg = self._ask(waiter, send, timeout)
        if msg is None:
            raise MissionTimeout(
                f"mission download: no answer after {self.command_attempts} attempts"
            )
        return msg
