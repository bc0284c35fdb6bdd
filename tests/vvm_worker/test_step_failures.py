"""A step whose effects the database cannot store, or that breaks in the platform, fails its VV
alone: nothing of the step is applied, the VV says why, and the other VVs go on (issue 21)."""

from __future__ import annotations

import dataclasses
import datetime as dt
import logging
import uuid

import pytest
from django.db import InterfaceError
from django.utils import timezone

from cpcc_site.json_depth import MAX_VALUE_DEPTH
from missions.models import LogEntry, StorageDocument, Task, TaskStatus, VirtualVehicle, VVStatus
from tests.factories import VehicleFactory
from vvm_worker import hosts
from vvm_worker.runtime import Effect
from vvm_worker.runtime.v8 import V8Closed
from vvm_worker.services import vv_advance, vv_submit

ONE_TASK = """
VV.storage.store('before', 1);
VV.log('before the task');
var co2 = VV.sensor.get('CO2');
var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                         tolerance: 2, sensors: [co2]});
VV.storage.store('co2', d[0]);
VV.log('after the task');
"""
NO_TASK = "VV.storage.store('done', true);"


@pytest.fixture
def fleet(platform, ground_station):
    one = VehicleFactory(name="Heli One")
    platform.add_vehicle_loop(one)
    return one


def add_effect(runtime, monkeypatch, *, vv_id: uuid.UUID, op: str, **fields) -> None:
    """Make the runtime's first step of the VV also return this effect (as a runtime that let
    it through would)."""
    original = runtime.step

    def step(step_input):
        result = original(step_input)
        if step_input.vv_id != str(vv_id) or len(step_input.journal):
            return result
        seq = result.effects_total
        effect = Effect(seq=seq, op=op, time_ms=step_input.start_ms, **fields)
        return dataclasses.replace(result, effects=(*result.effects, effect), effects_total=seq + 1)

    monkeypatch.setattr(runtime, "step", step)


DEEP = "[" * 5000 + "]" * 5000


@pytest.mark.parametrize(
    ("op", "fields", "said"),
    [
        ("store", {"key": "bad\ud800key", "value_json": "1"}, r'storage key "bad\ud800key"'),
        ("remove", {"key": "nul\x00key"}, 'storage key "nul\\u0000key" has the character U+0000'),
        ("store", {"key": "k" * 129, "value_json": "1"}, "is longer than 128 characters"),
        ("store", {"key": "deep", "value_json": DEEP}, 'under storage key "deep" nests more'),
        ("store", {"key": "v", "value_json": '{"a": "x\\u0000"}'}, "a string in the value"),
        ("store", {"key": "v", "value_json": '["\\udc00"]'}, "lone UTF-16 surrogate"),
        ("store", {"key": "v", "value_json": "{oops"}, "is not valid JSON"),
        ("log", {"message": "a \x00 in it"}, "log line 2 has the character U+0000 (character 3)"),
        ("log", {"message": "cut \ud83d"}, "log line 2 has a lone UTF-16 surrogate (character 5)"),
    ],
)
def test_an_effect_the_database_cannot_store_fails_its_vv_and_applies_nothing_of_the_step(
    platform, fleet, customer_a, customer_b, monkeypatch, op, fields, said
) -> None:
    bad_id = uuid.uuid4()
    add_effect(platform.vvm.runtime, monkeypatch, vv_id=bad_id, op=op, **fields)
    bad = vv_submit(
        customer=customer_a, name="bad", program=ONE_TASK, vvm=platform.vvm, vv_id=bad_id
    )
    good = vv_submit(customer=customer_b, name="good", program=ONE_TASK, vvm=platform.vvm)
    platform.drain()
    bad.refresh_from_db()
    good.refresh_from_db()
    assert bad.status == VVStatus.FAILED
    assert bad.error.startswith("the platform could not apply this step: ")
    assert said in bad.error
    assert bad.error.endswith("(nothing of the step was applied)")
    # Neither the effect nor those before it in the step, nor the task it asked for.
    assert not StorageDocument.objects.filter(vv=bad).exists()
    assert not LogEntry.objects.filter(vv=bad).exists()
    assert not Task.objects.filter(vv=bad).exists()
    assert bad.effects_applied == 0 and bad.storage_bytes == 0
    assert platform.vvm.runtime.context(str(bad.pk)) is None
    assert good.status == VVStatus.FINISHED
    assert sorted(good.storage.values_list("key", flat=True)) == ["before", "co2"]
    assert good.log.count() == 2


def test_a_write_the_database_refuses_after_the_checks_fails_its_vv_and_keeps_its_answer(
    platform, fleet, customer_a, customer_b, monkeypatch
) -> None:
    # A step's storage writes go without waiting for their answers (checked first, they
    # cannot be refused but by a platform bug): one refused all the same, here because the
    # platform got its size wrong, fails the VV as a step that cannot be applied does. The
    # RV's answer to its task is kept; nothing of the step is.
    from vvm_worker.services import steps

    bad_id = uuid.uuid4()
    checked = steps._storable

    def wrong_size(vv, effects, vvm):
        final, lines = checked(vv, effects, vvm)
        if vv.pk == bad_id and vv.journal_length:  # its step on the RV, after the answer
            for document in final.values():
                if document is not None:
                    document.size_bytes = -1
        return final, lines

    monkeypatch.setattr(steps, "_storable", wrong_size)
    bad = vv_submit(
        customer=customer_a, name="bad", program=ONE_TASK, vvm=platform.vvm, vv_id=bad_id
    )
    good = vv_submit(customer=customer_b, name="good", program=ONE_TASK, vvm=platform.vvm)
    platform.drain()
    bad.refresh_from_db()
    good.refresh_from_db()
    assert bad.status == VVStatus.FAILED
    assert bad.error == "the platform could not run or apply this VV's step (IntegrityError)"
    assert bad.tasks.get().status == TaskStatus.DONE
    assert sorted(bad.storage.values_list("key", flat=True)) == ["before"]
    assert good.status == VVStatus.FINISHED


def test_a_value_at_the_depth_limit_is_stored_and_sizes_count_utf8_bytes(
    platform, fleet, customer_a, customer_b, monkeypatch
) -> None:
    vv_id = uuid.uuid4()
    nested = "[" * MAX_VALUE_DEPTH + "]" * MAX_VALUE_DEPTH
    add_effect(
        platform.vvm.runtime, monkeypatch, vv_id=vv_id, op="store", key="deep", value_json=nested
    )
    program = "VV.storage.store('clé', 'naïve €');"
    vv = vv_submit(customer=customer_a, name="VV", program=program, vvm=platform.vvm, vv_id=vv_id)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    assert vv.storage.get(key="deep").size_bytes == len("deep") + 2 * MAX_VALUE_DEPTH
    document = vv.storage.get(key="clé")
    assert document.value == "naïve €"
    assert document.size_bytes == len("clé".encode()) + len('"naïve €"'.encode())  # 4 + 12


def test_a_step_that_raises_fails_its_vv_once_frees_its_slot_and_the_others_go_on(
    platform, fleet, customer_a, customer_b, monkeypatch, caplog
) -> None:
    customer_a.max_parallel_vvs = 1
    customer_a.save()
    bad_id = uuid.uuid4()
    original = platform.vvm.runtime.step
    broken = []

    def step(step_input):
        if step_input.vv_id == str(bad_id) and len(step_input.journal):  # resumed on the RV
            broken.append(step_input.vv_id)
            raise RuntimeError("internal detail the customer must not see")
        return original(step_input)

    monkeypatch.setattr(platform.vvm.runtime, "step", step)
    bad = vv_submit(
        customer=customer_a, name="bad", program=ONE_TASK, vvm=platform.vvm, vv_id=bad_id
    )
    queued = vv_submit(customer=customer_a, name="next", program=NO_TASK, vvm=platform.vvm)
    good = vv_submit(customer=customer_b, name="good", program=ONE_TASK, vvm=platform.vvm)
    assert queued.status == VVStatus.QUEUED
    platform.drain()
    bad.refresh_from_db()
    assert bad.status == VVStatus.FAILED
    assert bad.error == "the platform could not run or apply this VV's step (RuntimeError)"
    assert broken == [str(bad_id)]  # not retried
    # The broken step is rolled back (its task stays answered), what came before stays.
    assert sorted(bad.storage.values_list("key", flat=True)) == ["before"]
    assert list(bad.log.values_list("message", flat=True)) == ["before the task"]
    assert bad.tasks.get().status == TaskStatus.DONE
    assert bad.host_rv is None and bad.host_gs is not None  # back on a ground station
    record = next(r for r in caplog.records if r.getMessage() == "vv step broke: the VV fails")
    assert (record.vv, record.customer) == (str(bad.pk), customer_a.slug)
    assert "internal detail" in str(record.exc_info[1])
    queued.refresh_from_db()
    good.refresh_from_db()
    assert queued.status == VVStatus.FINISHED  # its slot was freed
    assert good.status == VVStatus.FINISHED


@pytest.mark.parametrize("outage", [InterfaceError("connection already closed"), V8Closed()])
def test_a_database_outage_or_a_stopping_process_leaves_the_step_to_be_done_again(
    customer_a, ground_station, vvm_factory, monkeypatch, outage
) -> None:
    vvm = vvm_factory()
    vv = vv_submit(customer=customer_a, name="VV", program=NO_TASK, vvm=vvm)
    original = vvm.runtime.step

    def step(step_input):
        original(step_input)
        raise outage

    monkeypatch.setattr(vvm.runtime, "step", step)
    with pytest.raises(type(outage)):
        vv_advance(vv_id=vv.pk, vvm=vvm)
    vv.refresh_from_db()
    assert vv.status == VVStatus.RUNNING and vv.error == "" and vv.steps == 0
    assert not vv.storage.exists()
    monkeypatch.setattr(vvm.runtime, "step", original)
    vv_advance(vv_id=vv.pk, vvm=vvm)
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED and vv.storage.get(key="done").value is True


@pytest.fixture
def station(ground_station, vvm_factory, monkeypatch):
    """A ground station's host whose sweep uses a VVM of the test's (no Celery, no feed)."""
    vvm = vvm_factory()
    vvm.lease_s = 60.0
    monkeypatch.setattr(hosts, "platform_vvm", lambda **kwargs: vvm)
    return hosts.GSHost(ground_station)


def submit_stalled(vvm, **fields) -> VirtualVehicle:
    """A VV admitted to the ground station whose message was lost a minute ago."""
    vvm.clock.t += 1.0  # submitted in this order
    vv = vv_submit(vvm=vvm, **fields)
    VirtualVehicle.objects.filter(pk=vv.pk).update(updated=timezone.now() - dt.timedelta(minutes=1))
    return vv


def test_the_ground_stations_sweep_goes_on_past_a_vv_whose_advance_fails(
    station, customer_a, customer_b, monkeypatch, caplog
) -> None:
    vvm = station.vvm
    customer_b.max_parallel_vvs = 1
    customer_b.save()
    broken = submit_stalled(vvm, customer=customer_a, name="broken", program=NO_TASK)
    other = submit_stalled(vvm, customer=customer_b, name="other", program=NO_TASK)
    queued = vv_submit(vvm=vvm, customer=customer_b, name="queued", program=NO_TASK)
    assert queued.status == VVStatus.QUEUED
    original = hosts.vv_advance

    def advance(*, vv_id, vvm):
        if vv_id == broken.pk:
            raise RuntimeError("a bug outside the step")
        original(vv_id=vv_id, vvm=vvm)

    monkeypatch.setattr(hosts, "vv_advance", advance)
    with caplog.at_level(logging.ERROR, logger="cpcc.hosts"):
        station.sweep_once(vvm)
    other.refresh_from_db()
    queued.refresh_from_db()
    broken.refresh_from_db()
    assert other.status == VVStatus.FINISHED
    assert queued.status == VVStatus.RUNNING  # admissions ran after the failure
    assert broken.status == VVStatus.RUNNING  # looked at again by the next sweep
    (record,) = [r for r in caplog.records if r.getMessage() == "vv advance failed"]
    assert (record.vv, record.customer, record.ground_station) == (
        str(broken.pk),
        customer_a.slug,
        "GS Base",
    )


def test_the_sweep_admits_other_customers_past_an_admission_that_fails(
    station, customer_a, customer_b, monkeypatch, caplog
) -> None:
    vvm = station.vvm
    # Queued, for the sweep to admit (as if the message that would have was lost).
    waiting_a = vv_submit(vvm=vvm, customer=customer_a, name="a", program=NO_TASK, admit=False)
    waiting_b = vv_submit(vvm=vvm, customer=customer_b, name="b", program=NO_TASK, admit=False)
    original = hosts.vv_admit_queued

    def admit(*, customer_id, vvm):
        if customer_id == customer_a.pk:
            raise RuntimeError("a bug in admission")
        return original(customer_id=customer_id, vvm=vvm)

    monkeypatch.setattr(hosts, "vv_admit_queued", admit)
    with caplog.at_level(logging.ERROR, logger="cpcc.hosts"):
        station.sweep_once(vvm)
    waiting_a.refresh_from_db()
    waiting_b.refresh_from_db()
    assert waiting_a.status == VVStatus.QUEUED and waiting_b.status == VVStatus.RUNNING
    (record,) = [r for r in caplog.records if r.getMessage() == "admission failed"]
    assert record.customer == customer_a.slug
