"""What a user does with their own VVs (the web pages and the REST API): submit N copies at
once, change the program of a queued VV, restart an ended one. Always with a second customer,
who is told "not found"."""

from __future__ import annotations

import pytest
from django.db import transaction

from missions.models import VirtualVehicle, VVStatus
from missions.selectors import VVNotFound
from tests.broker import queued
from vvm_worker.dispatch import SHARED_QUEUE
from vvm_worker.platform import platform_vvm
from vvm_worker.services import (
    MAX_COPIES,
    NotACustomer,
    ProgramRejected,
    VVNotEnded,
    VVNotQueued,
    vv_cancel,
    vv_create_copies_for_user,
    vv_restart_for_user,
    vv_submit,
    vv_update_program_for_user,
)

PROGRAM = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                 tolerance: 2, sensors: [co2]},
                function (d) { VV.storage.store('co2', d[0]); });
"""
BROKEN = "var a = 1;\nvar b = ;\n"  # line 2, column 9


def names(vvs) -> list[str]:
    return [vv.name for vv in vvs]


# --- copies ---------------------------------------------------------------------------------


def test_copies_are_queued_in_one_go_with_numbered_names(user_a, vvm_factory) -> None:
    vvm = vvm_factory()
    vvs, problem = vv_create_copies_for_user(
        user=user_a, name="Survey", program=PROGRAM, copies=3, vvm=vvm
    )
    assert problem is None
    assert names(vvs) == ["Survey", "Survey (2)", "Survey (3)"]
    stored = VirtualVehicle.objects.order_by("submitted_s", "created")
    assert [(vv.name, vv.status, vv.program) for vv in stored] == [
        (name, VVStatus.QUEUED, PROGRAM) for name in names(vvs)
    ]
    assert {vv.customer_id for vv in stored} == {user_a.customer_id}
    assert len({vv.seed for vv in stored}) == 3  # each copy its own Math.random
    # One request for admission for the lot, not one per copy.
    assert vvm.dispatcher.slots == [user_a.customer_id]


def test_copies_are_announced_to_the_workers_once_all_of_them_have_committed(
    user_a, customer_a, broker, django_capture_on_commit_callbacks
) -> None:
    with django_capture_on_commit_callbacks(execute=False) as callbacks:
        vvs, _ = vv_create_copies_for_user(
            user=user_a, name="S", program=PROGRAM, copies=4, vvm=platform_vvm()
        )
        assert len(vvs) == 4
        assert queued(broker, SHARED_QUEUE) == [], "nothing is sent before the commit"
    for callback in callbacks:
        callback()
    assert queued(broker, SHARED_QUEUE) == [("cpcc.admit", [customer_a.pk])]


def test_copies_rolled_back_send_nothing(
    user_a, broker, django_capture_on_commit_callbacks
) -> None:
    def failing_request() -> None:
        with transaction.atomic():
            vv_create_copies_for_user(
                user=user_a, name="T", program=PROGRAM, copies=3, vvm=platform_vvm()
            )
            raise RuntimeError("the request failed after the submission")

    with (
        django_capture_on_commit_callbacks(execute=True) as callbacks,
        pytest.raises(RuntimeError, match="failed after the submission"),
    ):
        failing_request()
    assert callbacks == []
    assert queued(broker, SHARED_QUEUE) == []
    assert not VirtualVehicle.objects.exists()


def test_copies_of_a_program_with_a_syntax_error_are_none(user_a, vvm_factory) -> None:
    vvm = vvm_factory()
    vvs, problem = vv_create_copies_for_user(
        user=user_a, name="bad", program=BROKEN, copies=5, vvm=vvm
    )
    assert vvs == []
    assert (problem.line, problem.column) == (2, 9)
    assert "SyntaxError" in problem.message
    assert not VirtualVehicle.objects.exists()
    assert vvm.dispatcher.slots == []


@pytest.mark.parametrize("copies", [0, -1, MAX_COPIES + 1])
def test_a_number_of_copies_out_of_range_is_refused(user_a, vvm_factory, copies) -> None:
    with pytest.raises(ValueError, match="copies must be between 1 and"):
        vv_create_copies_for_user(
            user=user_a, name="x", program=PROGRAM, copies=copies, vvm=vvm_factory()
        )
    assert not VirtualVehicle.objects.exists()


def test_a_user_of_no_customer_cannot_submit_copies(staff, vvm_factory) -> None:
    with pytest.raises(NotACustomer):
        vv_create_copies_for_user(
            user=staff, name="x", program=PROGRAM, copies=2, vvm=vvm_factory()
        )


# --- editing a queued VV --------------------------------------------------------------------


@pytest.fixture
def queued_a(user_a, vvm_factory) -> VirtualVehicle:
    """Customer A's VV waiting in the queue (no ground station yet admits it)."""
    (vv,), _ = vv_create_copies_for_user(
        user=user_a, name="Draft", program="VV.log('v1');", copies=1, vvm=vvm_factory()
    )
    assert vv.status == VVStatus.QUEUED
    return vv


def test_a_queued_vv_gets_its_new_name_and_program_and_keeps_its_place(
    user_a, queued_a, vvm_factory
) -> None:
    vv = vv_update_program_for_user(
        user=user_a, vv_id=queued_a.pk, name="Final", program=PROGRAM, vvm=vvm_factory()
    )
    assert (vv.name, vv.program, vv.status) == ("Final", PROGRAM, VVStatus.QUEUED)
    stored = VirtualVehicle.objects.get(pk=queued_a.pk)
    assert (stored.name, stored.program) == ("Final", PROGRAM)
    assert (stored.submitted_s, stored.seed) == (queued_a.submitted_s, queued_a.seed)


def test_an_edit_with_a_syntax_error_is_refused_with_where_it_is(
    user_a, queued_a, vvm_factory
) -> None:
    with pytest.raises(ProgramRejected) as refused:
        vv_update_program_for_user(
            user=user_a, vv_id=queued_a.pk, name="Final", program=BROKEN, vvm=vvm_factory()
        )
    assert (refused.value.problem.line, refused.value.problem.column) == (2, 9)
    stored = VirtualVehicle.objects.get(pk=queued_a.pk)
    assert (stored.name, stored.program) == ("Draft", "VV.log('v1');")


def test_another_customers_queued_vv_cannot_be_edited(user_b, queued_a, vvm_factory) -> None:
    with pytest.raises(VVNotFound):
        vv_update_program_for_user(
            user=user_b, vv_id=queued_a.pk, name="Mine", program=PROGRAM, vvm=vvm_factory()
        )
    assert VirtualVehicle.objects.get(pk=queued_a.pk).name == "Draft"


def test_a_vv_that_has_started_or_ended_cannot_be_edited(
    user_a, customer_a, ground_station, vvm_factory
) -> None:
    running = vv_submit(customer=customer_a, name="Run", program=PROGRAM, vvm=vvm_factory())
    assert running.status == VVStatus.RUNNING
    ended = vv_submit(customer=customer_a, name="End", program=PROGRAM, vvm=vvm_factory())
    vv_cancel(vv_id=ended.pk, vvm=vvm_factory())
    for vv in (running, ended):
        with pytest.raises(VVNotQueued):
            vv_update_program_for_user(
                user=user_a, vv_id=vv.pk, name="Changed", program="VV.log(1);", vvm=vvm_factory()
            )
        assert VirtualVehicle.objects.get(pk=vv.pk).program == PROGRAM


# --- restarting an ended VV -----------------------------------------------------------------


def test_a_restarted_vv_flies_again_as_a_new_vv_and_the_old_one_stays(
    platform, user_a, customer_a, ground_station
) -> None:
    from tests.factories import VehicleFactory

    platform.add_vehicle_loop(VehicleFactory(name="Heli One"))
    first = vv_submit(customer=customer_a, name="Survey", program=PROGRAM, vvm=platform.vvm)
    platform.drain()
    first.refresh_from_db()
    assert first.status == VVStatus.FINISHED

    again = vv_restart_for_user(user=user_a, vv_id=first.pk, vvm=platform.vvm)
    assert again.pk != first.pk
    assert (again.name, again.program, again.customer_id) == ("Survey", PROGRAM, customer_a.pk)
    assert again.status == VVStatus.QUEUED and not again.storage.exists()
    platform.drain()
    again.refresh_from_db()
    assert again.status == VVStatus.FINISHED
    assert again.storage.get(key="co2").value["sensor"] == "CO2"
    first.refresh_from_db()
    assert first.status == VVStatus.FINISHED and first.storage.count() == 1


def test_only_an_ended_vv_can_be_restarted(user_a, queued_a, vvm_factory) -> None:
    with pytest.raises(VVNotEnded):
        vv_restart_for_user(user=user_a, vv_id=queued_a.pk, vvm=vvm_factory())
    assert VirtualVehicle.objects.count() == 1


@pytest.mark.parametrize("status", [VVStatus.FAILED, VVStatus.KILLED, VVStatus.CANCELLED])
def test_failed_killed_and_cancelled_vvs_can_be_restarted(
    user_a, queued_a, vvm_factory, status
) -> None:
    VirtualVehicle.objects.filter(pk=queued_a.pk).update(status=status)
    vvm = vvm_factory()
    again = vv_restart_for_user(user=user_a, vv_id=queued_a.pk, vvm=vvm)
    assert again.status == VVStatus.QUEUED and again.program == queued_a.program
    assert vvm.dispatcher.slots == [user_a.customer_id]


def test_another_customers_vv_cannot_be_restarted(user_b, queued_a, vvm_factory) -> None:
    VirtualVehicle.objects.filter(pk=queued_a.pk).update(status=VVStatus.FINISHED)
    with pytest.raises(VVNotFound):
        vv_restart_for_user(user=user_b, vv_id=queued_a.pk, vvm=vvm_factory())
    assert VirtualVehicle.objects.count() == 1


def test_staff_restart_a_vv_for_its_customer(staff, queued_a, vvm_factory) -> None:
    VirtualVehicle.objects.filter(pk=queued_a.pk).update(status=VVStatus.CANCELLED)
    again = vv_restart_for_user(user=staff, vv_id=queued_a.pk, vvm=vvm_factory())
    assert again.customer_id == queued_a.customer_id


def test_a_vv_whose_program_never_parsed_is_not_restarted(
    user_a, customer_a, ground_station, vvm_factory
) -> None:
    # A scenario's VV with a syntax error is accepted and ends failed when it is loaded.
    vv = vv_submit(
        customer=customer_a,
        name="Broken",
        program=BROKEN,
        vvm=vvm_factory(),
        refuse_syntax_errors=False,
        admit=False,
    )
    VirtualVehicle.objects.filter(pk=vv.pk).update(status=VVStatus.FAILED)
    with pytest.raises(ProgramRejected) as refused:
        vv_restart_for_user(user=user_a, vv_id=vv.pk, vvm=vvm_factory())
    assert refused.value.problem.line == 2
    assert VirtualVehicle.objects.count() == 1
