"""The distributed platform's dispatcher: messages reach the broker (the test run's real Redis)
only once the transaction that made the work commits, and never for a rolled-back change."""

from __future__ import annotations

import pytest
from django.db import connection, transaction
from django.db.models.functions import Now
from django.test.utils import CaptureQueriesContext

from fleet.models import Vehicle
from missions.models import VirtualVehicle
from tests.broker import queued
from tests.factories import VehicleFactory
from vvm_worker.dispatch import SHARED_QUEUE, gs_queue, rv_queue
from vvm_worker.hosts import GSHost
from vvm_worker.platform import platform_vvm
from vvm_worker.services import (
    vv_admit_queued,
    vv_advance,
    vv_cancel,
    vv_create_for_user,
    vv_submit,
)

PROGRAM = "VV.log('hello');"


def test_a_submission_is_announced_to_the_workers_after_it_commits(
    user_a, customer_a, broker, django_capture_on_commit_callbacks
) -> None:
    with django_capture_on_commit_callbacks(execute=False) as callbacks:
        vv, problem = vv_create_for_user(
            user=user_a, name="VV", program=PROGRAM, vvm=platform_vvm()
        )
        assert vv is not None and problem is None
        assert queued(broker, SHARED_QUEUE) == [], "nothing is sent before the commit"
    for callback in callbacks:
        callback()
    assert queued(broker, SHARED_QUEUE) == [("cpcc.admit", [customer_a.pk])]


def test_a_rolled_back_submission_sends_nothing(
    user_a, broker, django_capture_on_commit_callbacks
) -> None:
    def failing_request() -> None:
        with transaction.atomic():
            vv_create_for_user(user=user_a, name="VV", program=PROGRAM, vvm=platform_vvm())
            raise RuntimeError("the request failed after the submission")

    with (
        django_capture_on_commit_callbacks(execute=True) as callbacks,
        pytest.raises(RuntimeError, match="failed after the submission"),
    ):
        failing_request()
    assert callbacks == []
    assert queued(broker, SHARED_QUEUE) == []
    assert not VirtualVehicle.objects.exists()


def test_a_vv_is_sent_to_the_queue_of_the_host_it_is_on(
    customer_a, ground_station, broker, django_capture_on_commit_callbacks
) -> None:
    with django_capture_on_commit_callbacks(execute=True):
        vv = vv_submit(customer=customer_a, name="VV", program=PROGRAM, vvm=platform_vvm())
    assert vv.host_gs == ground_station
    assert queued(broker, gs_queue(ground_station.pk)) == [("cpcc.vv_advance", [str(vv.pk)])]


def test_a_vv_routed_to_an_rv_is_sent_to_its_queue_without_reading_where_it_went(
    customer_a, ground_station, broker, django_capture_on_commit_callbacks
) -> None:
    """The transaction that moved the VV says where to: the message after its commit costs
    no read of the VV."""
    heli = VehicleFactory(name="Heli One")  # its worker (another process) holds its lease
    Vehicle.objects.filter(pk=heli.pk).update(worker_seen=Now())
    vvm = platform_vvm()
    program = (
        "var co2 = VV.sensor.get('CO2');\n"
        "VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),"
        " tolerance: 2, sensors: [co2]});"
    )
    with django_capture_on_commit_callbacks(execute=True):
        vv = vv_submit(customer=customer_a, name="VV", program=program, vvm=vvm)
    with django_capture_on_commit_callbacks(execute=False) as after_commit:
        vv_advance(vv_id=vv.pk, vvm=vvm)  # its first step, on the station
    with CaptureQueriesContext(connection) as reads:
        for callback in after_commit:
            callback()
    vv.refresh_from_db()
    assert vv.host_rv == heli and vv.status == "migrating"
    assert queued(broker, rv_queue(heli.pk)) == [("cpcc.vv_advance", [str(vv.pk)])]
    assert reads.captured_queries == []


@pytest.mark.django_db(transaction=True, serialized_rollback=True)  # real commits
def test_a_ground_stations_worker_advances_the_vvs_it_admits_itself_without_a_message(
    customer_a, ground_station, broker
) -> None:
    """A VV that the station's own work leaves on it (here: admitted) is advanced by that
    worker within the same piece of work, with no message to itself on the broker."""
    customer_a.max_parallel_vvs = 1
    customer_a.save()
    first = vv_submit(customer=customer_a, name="First", program=PROGRAM, vvm=platform_vvm())
    second = vv_submit(customer=customer_a, name="Second", program=PROGRAM, vvm=platform_vvm())
    vv_cancel(vv_id=first.pk, vvm=platform_vvm())  # its place is free
    assert second.status == "queued"
    host = GSHost(ground_station)
    host.start()  # its thread, then what waits for the station
    try:
        host.admit(customer_a.pk)  # as the message of the cancel asks (on the host thread)
        second.refresh_from_db()
        assert second.status == "finished"
        assert list(second.log.values_list("message", flat=True)) == ["hello"]
        sent = queued(broker, gs_queue(ground_station.pk))
        assert ("cpcc.vv_advance", [str(second.pk)]) not in sent
    finally:
        host.stop()


def test_a_vv_that_ends_asks_for_admission_only_when_its_customer_has_one_queued(
    customer_a, ground_station, broker, django_capture_on_commit_callbacks
) -> None:
    """A VV that ends frees a slot: a message asks any station to admit the customer's queued
    VVs, unless none is queued once the end is committed (most VVs end so: no message, no
    admission for nothing)."""
    vvm = platform_vvm()
    customer_a.max_parallel_vvs = 1
    customer_a.save()
    with django_capture_on_commit_callbacks(execute=True):
        first = vv_submit(customer=customer_a, name="First", program=PROGRAM, vvm=vvm)
        waiting = vv_submit(customer=customer_a, name="Waiting", program=PROGRAM, vvm=vvm)
    assert waiting.status == "queued"
    broker.delete(SHARED_QUEUE)
    with django_capture_on_commit_callbacks(execute=True):
        vv_advance(vv_id=first.pk, vvm=vvm)  # its only step: it finishes
    assert VirtualVehicle.objects.get(pk=first.pk).status == "finished"
    assert queued(broker, SHARED_QUEUE) == [("cpcc.admit", [customer_a.pk])]

    broker.delete(SHARED_QUEUE)
    with django_capture_on_commit_callbacks(execute=True):
        vv_admit_queued(customer_id=customer_a.pk, vvm=vvm)
        vv_advance(vv_id=waiting.pk, vvm=vvm)  # the last one ends: nothing queued behind it
    assert VirtualVehicle.objects.get(pk=waiting.pk).status == "finished"
    assert queued(broker, SHARED_QUEUE) == []
