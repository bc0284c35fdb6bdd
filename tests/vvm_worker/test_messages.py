"""Messages between VVs (``VV.message.send`` / ``receive``) on discrete-event time: order,
exactly once, timeouts, the same error for another customer's VV as for none, and a receiver
that waits costs nothing."""

from __future__ import annotations

import pytest

from missions.models import JournalEntry, Message, Migration, VirtualVehicle, VVStatus
from tests.factories import AREA_TWO, VehicleFactory
from vvm_worker.hosts import stalled
from vvm_worker.services import vv_submit

# Two VVs, each in its own RV's cell, exchange ROUNDS messages each way: a reading in its cell,
# a message to the other with the round and what it read, then the other's message of that
# round. What each received is in its storage, in order.
EXCHANGE = """
var peer = %(peer)s;
var co2 = VV.sensor.get('CO2');
var got = [];
for (var i = 0; i < %(rounds)d; i++) {
  var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(%(lat)s, %(lng)s + i * 0.0001, 50),
                           tolerance: 2, sensors: [co2]});
  VV.message.send(peer, {round: i, from: VV.name, co2: d[0].value});
  var m = VV.message.receive(600);
  got.push(m === null ? null : [m.from, m.value.round, m.id === null ? null : m.id.length]);
}
VV.storage.store('got', got);
"""

ROUNDS = 10


def exchange(*, peer: str, lat: float, lng: float, rounds: int = ROUNDS) -> str:
    return EXCHANGE % {"peer": repr(peer), "rounds": rounds, "lat": lat, "lng": lng}


@pytest.fixture
def two_cells(platform, ground_station):
    one = VehicleFactory(name="Heli One")
    two = VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lng=12.8675)
    platform.add_vehicle_loop(one)
    platform.add_vehicle_loop(two)
    return one, two


def stored(vv: VirtualVehicle, key: str):
    return vv.storage.get(key=key).value


def test_two_vvs_on_rvs_in_different_cells_exchange_ten_messages_each_way_in_order(
    platform, two_cells, customer_a
) -> None:
    west = vv_submit(
        customer=customer_a,
        name="west",
        program=exchange(peer="east", lat=48.1111, lng=12.8610),
        vvm=platform.vvm,
    )
    east = vv_submit(
        customer=customer_a,
        name="east",
        program=exchange(peer="west", lat=48.1116, lng=12.8667),
        vvm=platform.vvm,
    )
    platform.drain()
    for vv, peer in ((west, "east"), (east, "west")):
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error
        assert stored(vv, "got") == [[peer, i, 36] for i in range(ROUNDS)]
        # Every message sent once and received once, and the answers are in the journal.
        assert Message.objects.filter(sender=vv).count() == ROUNDS
        assert Message.objects.filter(recipient=vv, received_s__isnull=True).count() == 0
        kinds = [e["k"] for e in JournalEntry.objects.filter(vv=vv).values_list("entry", flat=True)]
        assert kinds.count("msg") == ROUNDS and kinds.count("ret") == ROUNDS
    # Each served in its own cell: its tasks on its own RV.
    assert {t.vehicle.name for t in west.tasks.all()} == {"Heli One"}
    assert {t.vehicle.name for t in east.tasks.all()} == {"Heli Two"}


def test_receive_returns_null_when_its_timeout_passes(platform, two_cells, customer_a) -> None:
    vv = vv_submit(
        customer=customer_a,
        name="alone",
        program="""
var t0 = Date.now();
var m = VV.message.receive(30);
VV.storage.store('m', m);
VV.storage.store('waited', Date.now() - t0);
""",
        vvm=platform.vvm,
    )
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert stored(vv, "m") is None
    assert stored(vv, "waited") == 30_000  # its clock is the platform's: the timeout exactly


def test_a_message_sent_before_receive_is_there_at_once_and_a_later_one_is_next(
    platform, two_cells, customer_a
) -> None:
    receiver = vv_submit(
        customer=customer_a,
        name="receiver",
        program="""
var a = VV.message.receive(600);
var b = VV.message.receive(600);
VV.storage.store('values', [a.value, b.value, a.from, a.id]);
""",
        vvm=platform.vvm,
    )
    vv_submit(
        customer=customer_a,
        name="sender",
        program=f"VV.message.send('receiver', 'first'); VV.message.send('{receiver.pk}', 'second');",
        vvm=platform.vvm,
    )
    platform.drain()
    receiver.refresh_from_db()
    sender = VirtualVehicle.objects.get(name="sender")
    assert receiver.status == VVStatus.FINISHED, receiver.error
    assert stored(receiver, "values") == ["first", "second", "sender", str(sender.pk)]


def test_a_send_to_another_customers_vv_and_to_no_vv_raise_the_same_error(
    platform, two_cells, customer_a, customer_b
) -> None:
    vv_submit(
        customer=customer_b, name="theirs", program="VV.message.receive(60);", vvm=platform.vvm
    )
    theirs = VirtualVehicle.objects.get(name="theirs")
    probe = """
var out = [];
[%s].forEach(function (to) {
  try { VV.message.send(to, 1); out.push('sent'); }
  catch (e) { out.push([e.name, e instanceof MessageError, e.message.replace(to, 'X')]); }
});
VV.storage.store('out', out);
"""
    vv = vv_submit(
        customer=customer_a,
        name="probe",
        program=probe % ", ".join(repr(t) for t in ["theirs", "nobody", str(theirs.pk)]),
        vvm=platform.vvm,
    )
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    out = stored(vv, "out")
    assert out[0] == out[1] == out[2]
    assert out[0][:2] == ["MessageError", True]
    assert out[0][2] == 'VV.message.send(to, value): no VV "X" of yours to send to'
    assert not Message.objects.filter(recipient=theirs).exists()


def test_a_receiver_that_waits_is_parked_on_a_ground_station_and_nothing_of_it_runs(
    platform, two_cells, customer_a
) -> None:
    listener = vv_submit(
        customer=customer_a,
        name="listener",
        program="""
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50), tolerance: 2,
                 sensors: [co2]});
var m = VV.message.receive(3600);
VV.storage.store('m', m.value);
""",
        vvm=platform.vvm,
    )
    # Once its task is done, it waits for a message on the ground station.
    platform.drain(
        until=lambda: VirtualVehicle.objects.filter(
            pk=listener.pk, pending__kind="message", status=VVStatus.RUNNING, host_gs__isnull=False
        ).exists()
    )
    listener.refresh_from_db()
    assert listener.status == VVStatus.RUNNING
    steps = listener.steps
    moves = [(m.from_name, m.to_name, m.reason) for m in Migration.objects.filter(vv=listener)]
    assert moves[-1] == ("Heli One", "GS Base", "waiting for a message")
    # Time passes, other VVs run: no step of the listener (its program is not run) until a
    # message comes.
    other = vv_submit(
        customer=customer_a,
        name="other",
        program=exchange(peer="other", lat=48.1116, lng=12.8667, rounds=2),
        vvm=platform.vvm,
    )
    platform.drain(
        until=lambda: VirtualVehicle.objects.filter(pk=other.pk, status=VVStatus.FINISHED).exists()
    )
    listener.refresh_from_db()
    assert listener.steps == steps
    # Nor does a ground station's sweep look at it before its timeout.
    gs = listener.host_gs
    assert (
        not stalled(host_gs_id=gs.pk, waiting_s=0, now_s=platform.clock.t)
        .filter(pk=listener.pk)
        .exists()
    )
    assert stalled(host_gs_id=gs.pk, now_s=platform.clock.t + 3600).filter(pk=listener.pk).exists()
    vv_submit(
        customer=customer_a,
        name="caller",
        program="VV.message.send('listener', 'wake up');",
        vvm=platform.vvm,
    )
    platform.drain()
    listener.refresh_from_db()
    assert listener.status == VVStatus.FINISHED, listener.error
    assert stored(listener, "m") == "wake up"
    assert listener.steps == steps + 1
