"""The live map's feed: the changes announced as they happen, where they go in Redis, and who
may see what.

Changes (a VV's status or host, its tasks, its migrations, the messages between its VVs) are
appended to one Redis stream after their transaction commits; each RV worker appends its
vehicle's state (position, VVs aboard, planned route) to a second stream twice a second and
keeps the latest in a hash for snapshots (a vehicle's state names its ``kind``: aerial, ground,
surface or underwater; altitude below 0 is depth). Every map socket reads both streams itself (blocking
until something comes) and sends its browser one frame per batch with what that user may see
(missions/consumers.py): no message is sent per change and per listener, and a frame leaves at
most one batch interval after the change.

A customer sees its own VVs, their tasks, paths, migrations and messages to one another, and
the vehicles carrying them as anonymous carriers; never a vehicle's or a ground station's name,
nor another customer's anything. Staff see everything.
"""

from __future__ import annotations

import hashlib
from typing import Any

from fleet.kinds import DEFAULT_KIND
from missions.models import HostKind, Message, Migration, Task, VirtualVehicle

EVENTS_STREAM = "cpcc:map:events"
POSITIONS_STREAM = "cpcc:map:positions"
VEHICLES_HASH = "cpcc:map:vehicles"
# About this many recent changes stay in the stream: a socket that falls further behind (or
# a browser that was away) starts again from a snapshot.
STREAM_MAXLEN = 50_000
# Positions are superseded by the next ones: a socket that falls behind skips ahead.
POSITIONS_MAXLEN = 20_000
# A vehicle state older than this is not shown (its worker has stopped).
VEHICLE_STALE_S = 30.0


def vv_event(vv: VirtualVehicle) -> dict[str, Any]:
    host_kind = HostKind.RV if vv.host_rv_id else HostKind.GS if vv.host_gs_id else None
    host = vv.host_rv if vv.host_rv_id else vv.host_gs if vv.host_gs_id else None
    return {
        "kind": "vv",
        "customer": vv.customer_id,
        "vv": str(vv.pk),
        "name": vv.name,
        "status": vv.status,
        "host_kind": host_kind,
        "host": host.name if host is not None else None,
        "vehicle": vv.host_rv_id,
    }


def task_event(task: Task, customer_id: int) -> dict[str, Any]:
    return {
        "kind": "task",
        "customer": customer_id,
        "vv": str(task.vv_id),
        "id": task.pk,
        "q": task.q,
        "index": task.index,
        "lat": task.lat,
        "lng": task.lng,
        "alt": task.alt,
        "status": task.status,
        "requested_s": task.requested_s,
        "done_s": task.done_s,
    }


def migration_event(migration: Migration, customer_id: int) -> dict[str, Any]:
    return {
        "kind": "migration",
        "customer": customer_id,
        "vv": str(migration.vv_id),
        "id": migration.pk,
        "at_s": migration.at_s,
        "from_kind": migration.from_kind,
        "from": migration.from_name,
        "to_kind": migration.to_kind,
        "to": migration.to_name,
        "from_pos": _pair(migration.from_lat, migration.from_lng),
        "to_pos": _pair(migration.to_lat, migration.to_lng),
    }


def message_event(message: Message) -> dict[str, Any] | None:
    """A message from one VV to another (``VV.message.send``): the map draws it as a short-lived
    line between the two. None for a message sent over the API (no sender VV: nothing to draw
    from): the caller announces nothing for it.

    The sender is ``vv`` (so a map following one VV shows what it sends), the recipient
    ``to_vv``; their names are data (the page sets them as text). ``gs_pos`` / ``to_gs_pos``: the
    ground station the VV waits on when the message is sent (stations are on every map), None
    aboard a vehicle (the map finds it by the vehicle carrying it). The value is not in it: the
    map shows that a message went, not what it said."""
    if message.sender_id is None:
        return None
    return {
        "kind": "message",
        "customer": message.customer_id,
        "vv": str(message.sender_id),
        "id": message.pk,
        "name": message.sender_name,
        "to_vv": str(message.recipient_id),
        "to_name": message.recipient.name,
        "sent_s": message.sent_s,
        "gs_pos": _station_pos(message.sender),
        "to_gs_pos": _station_pos(message.recipient),
    }


def _station_pos(vv: VirtualVehicle | None) -> list[float] | None:
    if vv is None or vv.host_rv_id or not vv.host_gs_id:
        return None
    return [vv.host_gs.lat, vv.host_gs.lng]


def _pair(lat: float | None, lng: float | None) -> list[float] | None:
    return None if lat is None or lng is None else [lat, lng]


# What a customer must not learn: which vehicles and ground stations exist.
_HOST_NAMES = ("host", "from", "to", "vehicle")


def event_for(event: dict[str, Any], *, customer_id: int | None, staff: bool) -> dict | None:
    """The event as this user may see it, or None when it is none of their business."""
    if staff:
        return event
    if customer_id is None or event.get("customer") != customer_id:
        return None
    return {k: v for k, v in event.items() if k not in _HOST_NAMES}


def carrier_id(vehicle_id: int, secret: str) -> str:
    """An opaque, stable name for a vehicle as a customer's map shows it."""
    return "c" + hashlib.sha256(f"{secret}:{vehicle_id}".encode()).hexdigest()[:10]


def vehicle_for(
    state: dict[str, Any], *, customer_id: int | None, staff: bool, secret: str
) -> dict[str, Any] | None:
    """A vehicle's live state as this user may see it: everything for staff; for a customer,
    only a vehicle carrying one of its VVs, anonymous, with only its VVs aboard and no route
    (the route would show other customers' tasks). Its ``kind`` (fleet.kinds; a state without
    one is aerial's) is shown to both: the map draws a carrier as a copter, rover, boat or sub,
    which says how it moves, not whose it is or who else it carries."""
    if staff:
        return state
    mine = [vv for vv in state.get("vvs", ()) if vv.get("customer") == customer_id]
    if customer_id is None or not mine:
        return None
    return {
        "id": carrier_id(state["id"], secret),
        "lat": state["lat"],
        "lng": state["lng"],
        "alt": state["alt"],
        "kind": state.get("kind", DEFAULT_KIND),
        "phase": state.get("phase"),
        "t": state.get("t"),
        "vvs": mine,
    }
