"""Several VVs submitted at once (vvm_worker/services/submissions.py): all of them or none, the
queue quota counted for the whole list, each refused item named. Always with a second
customer, whose queue is its own."""

from __future__ import annotations

import pytest

from missions.models import VirtualVehicle, VVStatus
from tests.broker import queued
from vvm_worker.dispatch import SHARED_QUEUE
from vvm_worker.platform import platform_vvm
from vvm_worker.services import (
    MAX_SUBMISSIONS,
    NotACustomer,
    Submission,
    SubmissionsRefused,
    VVQueueFull,
    vv_submit,
    vvs_submit_many_for_user,
)

PROGRAM = "var gps = VV.sensor.get('GPS');\nVV.log('hello');\n"
BROKEN = "var a = 1;\nvar b = ;\n"  # line 2, column 9


def batch(*names: str, program: str = PROGRAM) -> list[Submission]:
    return [Submission(name=name, program=f"{program}// {name}\n") for name in names]


def test_each_submission_becomes_a_queued_vv_in_order(user_a, user_b, vvm_factory) -> None:
    vvm = vvm_factory()
    vvs = vvs_submit_many_for_user(user=user_a, submissions=batch("a", "b", "c"), vvm=vvm)
    assert [vv.name for vv in vvs] == ["a", "b", "c"]
    stored = {vv.pk: vv for vv in VirtualVehicle.objects.all()}
    assert set(stored) == {vv.pk for vv in vvs}
    for vv in vvs:
        assert stored[vv.pk].status == VVStatus.QUEUED
        assert stored[vv.pk].customer_id == user_a.customer_id
        assert stored[vv.pk].program == f"{PROGRAM}// {vv.name}\n"
    assert len({vv.seed for vv in vvs}) == 3  # each its own Math.random
    # One request for admission for the lot, not one per VV.
    assert vvm.dispatcher.slots == [user_a.customer_id]
    # Customer B's own submissions are its own.
    (other,) = vvs_submit_many_for_user(user=user_b, submissions=batch("b1"), vvm=vvm)
    assert other.customer_id == user_b.customer_id


def test_the_workers_hear_of_the_lot_once_it_is_committed(
    user_a, customer_a, broker, django_capture_on_commit_callbacks
) -> None:
    with django_capture_on_commit_callbacks(execute=False) as callbacks:
        vvs_submit_many_for_user(user=user_a, submissions=batch("a", "b"), vvm=platform_vvm())
        assert queued(broker, SHARED_QUEUE) == [], "nothing is sent before the commit"
    for callback in callbacks:
        callback()
    assert queued(broker, SHARED_QUEUE) == [("cpcc.admit", [customer_a.pk])]


def test_refused_items_are_each_named_and_nothing_is_created(user_a, vvm_factory) -> None:
    vvm = vvm_factory()
    submissions = [
        *batch("fine"),
        Submission(name="broken", program=BROKEN),
        Submission(name="\x1b[31mred", program=PROGRAM),
        Submission(name="\u202eboth", program=BROKEN),
    ]
    with pytest.raises(SubmissionsRefused) as refused:
        vvs_submit_many_for_user(user=user_a, submissions=submissions, vvm=vvm)
    assert sorted(refused.value.names) == [2, 3]
    assert "a control character (U+001B) at character 1" in refused.value.names[2]
    assert sorted(refused.value.programs) == [1, 3]
    problem = refused.value.programs[1]
    assert (problem.line, problem.column) == (2, 9) and "SyntaxError" in problem.message
    assert not VirtualVehicle.objects.exists()
    assert vvm.dispatcher.slots == []


def test_the_queue_quota_counts_the_whole_list(user_a, customer_a, user_b, vvm_factory) -> None:
    vvm = vvm_factory()
    customer_a.max_queued_vvs = 3
    customer_a.save()
    vv_submit(customer=customer_a, name="waiting", program=PROGRAM, vvm=vvm, admit=False)
    with pytest.raises(VVQueueFull) as full:
        vvs_submit_many_for_user(user=user_a, submissions=batch("a", "b", "c"), vvm=vvm)
    assert (full.value.queued, full.value.adding) == (1, 3)
    assert "has 1 VV(s) waiting in the queue and may have at most 3" in str(full.value)
    assert "3 more cannot be submitted now" in str(full.value)
    assert VirtualVehicle.objects.filter(customer=customer_a).count() == 1
    # What fits goes in; customer B's queue is its own.
    assert len(vvs_submit_many_for_user(user=user_a, submissions=batch("a", "b"), vvm=vvm)) == 2
    assert len(vvs_submit_many_for_user(user=user_b, submissions=batch("a", "b"), vvm=vvm)) == 2


def test_a_failure_midway_leaves_nothing_behind(user_a, vvm_factory, monkeypatch) -> None:
    vvm = vvm_factory()
    written = []

    def fail_after_the_insert(*, customer_id: int) -> None:
        written.append(VirtualVehicle.objects.filter(customer_id=customer_id).count())
        raise RuntimeError("the database went away")

    monkeypatch.setattr(
        vvm.dispatcher,
        "customer_slot_freed",
        lambda customer_id: fail_after_the_insert(customer_id=customer_id),
    )
    with pytest.raises(RuntimeError, match="went away"):
        vvs_submit_many_for_user(user=user_a, submissions=batch("a", "b", "c"), vvm=vvm)
    assert written == [3]  # all three were written in the transaction, then rolled back
    assert not VirtualVehicle.objects.exists()


@pytest.mark.parametrize("count", [0, MAX_SUBMISSIONS + 1])
def test_an_empty_or_too_long_list_is_refused(user_a, vvm_factory, count: int) -> None:
    submissions = batch(*(f"vv {n}" for n in range(count)))
    with pytest.raises(ValueError, match=f"holds 1 to {MAX_SUBMISSIONS} VVs, not {count}"):
        vvs_submit_many_for_user(user=user_a, submissions=submissions, vvm=vvm_factory())
    assert not VirtualVehicle.objects.exists()


def test_a_user_of_no_customer_cannot_submit(staff, vvm_factory) -> None:
    with pytest.raises(NotACustomer):
        vvs_submit_many_for_user(user=staff, submissions=batch("x"), vvm=vvm_factory())
