"""The live map's word that one VV sent another a message (missions/events.py): what it says,
and that only the customer's own maps (and staff's) ever get it."""

from __future__ import annotations

import time
from typing import Any

import pytest
from asgiref.sync import sync_to_async
from django.db import transaction

from missions.events import EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH, event_for, vv_event
from missions.events import message_event as make_event
from missions.models import Message, VirtualVehicle, VVStatus
from tests.factories import GroundStationFactory, VehicleFactory
from tests.missions.test_consumers import _frames_until, _socket
from vvm_worker.live import FeedAnnouncer
from vvm_worker.services import VVM
from vvm_worker.services.messages import message_send

# Names are the customer's words: the event carries them as they are (the page sets text).
SCOUT = "<b>Scout</b> & co"
BASE = 'Base "one"'
VALUE = '{"found": [1, 2]}'


def _vv(customer: Any, name: str, **host: Any) -> VirtualVehicle:
    return VirtualVehicle.objects.create(
        customer=customer,
        name=name,
        program="// talks",
        status=VVStatus.RUNNING,
        submitted_s=time.time(),
        seed=1,
        start_ms=0,
        **host,
    )


def _message(sender: VirtualVehicle, recipient: VirtualVehicle) -> Message:
    return Message.objects.create(
        customer=recipient.customer,
        sender=sender,
        sender_name=sender.name,
        recipient=recipient,
        value=VALUE,
        bytes=len(VALUE),
        sent_s=1_700_000_000.5,
    )


@pytest.fixture
def pair(customer_a) -> tuple[VirtualVehicle, VirtualVehicle]:
    """Customer A's "Scout" aboard Heli One and "Base" waiting on GS Base."""
    station = GroundStationFactory(name="GS Base", lat=48.1132, lng=12.8598)
    heli = VehicleFactory(name="Heli One")
    return _vv(customer_a, SCOUT, host_rv=heli), _vv(customer_a, BASE, host_gs=station)


class Heard:
    """What the services announce to the live map's feed."""

    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    def announce(self, event: dict[str, Any]) -> None:
        self.events.append(event)


@pytest.fixture
def vvm(vvm_factory) -> VVM:
    made: VVM = vvm_factory()
    made.announcer = Heard()
    return made


def test_a_sent_message_is_announced_naming_both_vvs_as_data_and_where_a_waiting_one_is(
    pair, vvm: VVM, django_capture_on_commit_callbacks
) -> None:
    scout, base = pair
    heard = vvm.announcer
    assert isinstance(heard, Heard)
    with django_capture_on_commit_callbacks(execute=True):
        there = message_send(
            customer_id=scout.customer_id, sender=scout, to=BASE, value_json=VALUE, vvm=vvm
        )
        assert heard.events == [], "announced once it commits"
    assert heard.events == [
        {
            "kind": "message",
            "customer": scout.customer_id,
            "vv": str(scout.pk),
            "id": there.pk,
            "name": SCOUT,
            "to_vv": str(base.pk),
            "to_name": BASE,
            "sent_s": there.sent_s,
            "gs_pos": None,  # aboard a vehicle: the map finds it by the vehicle carrying it
            "to_gs_pos": [48.1132, 12.8598],
        }
    ]
    assert "found" not in str(heard.events), "the map shows that a message went, not what"

    with django_capture_on_commit_callbacks(execute=True):
        message_send(
            customer_id=scout.customer_id, sender=base, to=str(scout.pk), value_json="1", vvm=vvm
        )
    back = heard.events[-1]
    assert (back["vv"], back["to_vv"]) == (str(base.pk), str(scout.pk))
    assert (back["gs_pos"], back["to_gs_pos"]) == ([48.1132, 12.8598], None)


def test_a_message_over_the_api_has_no_line_to_draw(
    pair, vvm: VVM, django_capture_on_commit_callbacks
) -> None:
    _, base = pair
    with django_capture_on_commit_callbacks(execute=True):
        message = message_send(
            customer_id=base.customer_id, sender=None, to=base, value_json=VALUE, vvm=vvm
        )
    assert isinstance(vvm.announcer, Heard) and vvm.announcer.events == []
    assert make_event(message) is None


def test_only_the_customers_own_map_and_staff_see_a_message(pair, customer_b) -> None:
    scout, base = pair
    event = make_event(_message(scout, base))
    assert event is not None
    # Nothing in it is a vehicle's or a station's name: the customer gets it whole.
    assert event_for(event, customer_id=scout.customer_id, staff=False) == event
    assert event_for(event, customer_id=customer_b.pk, staff=False) is None
    assert event_for(event, customer_id=None, staff=False) is None
    assert event_for(event, customer_id=None, staff=True) == event


@pytest.fixture
def feed(broker):
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)
    yield broker
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)


@pytest.fixture
async def _close_socket_connections():
    """The sockets read the database in a worker thread: its connection closes after the test."""
    yield
    from channels.db import database_sync_to_async
    from django.db import connections

    await database_sync_to_async(connections.close_all)()


def _is_message(frame: dict[str, Any]) -> bool:
    return any(e.get("kind") == "message" for e in frame.get("events", ()))


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
@pytest.mark.usefixtures("_close_socket_connections")
async def test_a_message_reaches_the_customers_and_staffs_maps_and_no_other_customers(
    client, user_a, user_b, staff, customer_b, pair, feed, vvm_factory
) -> None:
    scout, base = pair
    theirs = await sync_to_async(_vv)(customer_b, "Theirs", host_gs=base.host_gs)
    sockets = {}
    for who in (user_a, user_b, staff):
        await sync_to_async(client.force_login)(who)
        sockets[who.username] = socket = _socket(client)
        assert (await socket.connect())[0]
        assert (await socket.receive_json_from(timeout=5))["type"] == "snapshot"

    vvm = vvm_factory()
    vvm.announcer = FeedAnnouncer()

    def send_and_touch_theirs() -> Message:
        # Then a change of customer B's own, which B's map is sure to get after the message.
        with transaction.atomic():
            message = message_send(
                customer_id=scout.customer_id, sender=scout, to=BASE, value_json=VALUE, vvm=vvm
            )
        with transaction.atomic():
            theirs.status = VVStatus.CANCELLED
            theirs.save()
            vvm.announce_at_commit(lambda: vv_event(theirs))
        return message

    message = await sync_to_async(send_and_touch_theirs)()
    for name in ("customer-a", "operator"):
        frames = await _frames_until(sockets[name], _is_message)
        [event] = [e for e in frames[-1]["events"] if e["kind"] == "message"]
        assert (event["id"], event["name"], event["to_name"]) == (message.pk, SCOUT, BASE)
    frames = await _frames_until(
        sockets["customer-b"],
        lambda f: any(e.get("vv") == str(theirs.pk) for e in f.get("events", ())),
    )
    assert not any(_is_message(f) for f in frames)
    assert SCOUT not in str(frames) and str(scout.pk) not in str(frames)
    for socket in sockets.values():
        await socket.disconnect()
