"""Strangers' code on the platform: quotas, rejections, crashes, the catalog per customer."""

from __future__ import annotations

import pytest

from accounts.models import Customer
from missions.models import LogEntry, Task, TaskStatus, VirtualVehicle, VVStatus
from tests.factories import CustomerFactory, VehicleFactory
from vvm_worker.runtime import Runtime
from vvm_worker.services import task_complete, vv_advance, vv_submit
from vvm_worker.services import vvs as vv_services

GOOD = """
var co2 = VV.sensor.get('CO2');
for (var n = 0; n < 2; n++) {
  VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111 + n * 0.0002, 12.8619, 50),
                   tolerance: 2, sensors: [co2]}, function (d) { VV.storage.store('p' + n, d[0].value); });
}
"""


@pytest.fixture
def fleet(platform, ground_station):
    heli = VehicleFactory(name="Heli One")
    platform.add_vehicle_loop(heli)
    return heli


def tight(name: str, **quotas) -> Customer:
    customer = CustomerFactory(name=name)
    for key, value in quotas.items():
        setattr(customer, key, value)
    customer.save()
    return customer


@pytest.mark.django_db
def test_bombs_are_killed_naming_their_quota_while_a_good_vv_finishes(
    platform, fleet, customer_b
) -> None:
    bombs = {
        "loop": ("cpu", tight("Looper", cpu_ms_per_step=200), GOOD + "while (true) {}"),
        "heap": (
            "heap",
            tight("Hoarder", heap_bytes=32 * 1024 * 1024),
            "var a = []; while (true) { a.push(new Array(100000).fill(Math.random())); }",
        ),
        "storage": (
            "storage",
            tight("Filler", storage_bytes=10_000),
            "for (var i = 0; ; i++) VV.storage.store('k' + i, 'x'.repeat(500));",
        ),
    }
    vvs = {
        name: vv_submit(customer=customer, name=name, program=source, vvm=platform.vvm)
        for name, (_, customer, source) in bombs.items()
    }
    good = vv_submit(customer=customer_b, name="good", program=GOOD, vvm=platform.vvm)
    platform.drain()
    words = {
        "cpu": "quota: CPU time per step",
        "heap": "quota: V8 heap",
        "storage": "quota: storage bytes",
    }
    for name, (quota, _, _) in bombs.items():
        vv = VirtualVehicle.objects.get(pk=vvs[name].pk)
        assert vv.status == VVStatus.KILLED, (name, vv.error)
        assert words[quota] in vv.error
    good.refresh_from_db()
    assert good.status == VVStatus.FINISHED
    assert set(good.storage.values_list("key", flat=True)) == {"p0", "p1"}
    # The looping VV had done its tasks before it looped: its readings are kept.
    assert VirtualVehicle.objects.get(pk=vvs["loop"].pk).storage.count() == 2


@pytest.mark.django_db
def test_tasks_outside_every_area_or_above_every_ceiling_are_rejected_and_the_program_goes_on(
    platform, fleet, customer_a
) -> None:
    source = """
    var gps = VV.sensor.get('GPS');
    var asked = [[48.5, 12.5, 50], [48.1111, 12.8619, 500], [48.1111, 12.8619, 50]];
    var outcomes = [];
    for (var i = 0; i < asked.length; i++) {
      try {
        var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(asked[i][0], asked[i][1], asked[i][2]),
                                 tolerance: 2, sensors: [gps]});
        outcomes.push('done ' + d[0].sensor);
      } catch (e) {
        if (!(e instanceof TaskRejectedError)) throw e;
        outcomes.push(e.name + ': ' + e.message);
      }
    }
    VV.storage.store('outcomes', outcomes);
    """
    vv = vv_submit(customer=customer_a, name="VV", program=source, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    outside, ceiling, done = vv.storage.get(key="outcomes").value
    assert outside.startswith("TaskRejectedError: ") and "outside every operation area" in outside
    assert (
        ceiling.startswith("TaskRejectedError: ")
        and "altitude" in ceiling
        and "0 to 120 m" in ceiling
    )
    assert done == "done GPS"


@pytest.mark.django_db
def test_the_battery_sensor_is_for_privileged_customers_only(platform, ground_station) -> None:
    heli = VehicleFactory(name="Heli One", sensors=["GPS", "Battery"], battery_s=1800)
    platform.add_vehicle_loop(heli)
    source = """
    var battery = VV.sensor.get('Battery');
    var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                             tolerance: 2, sensors: [battery]});
    VV.storage.store('battery', d[0]);
    """
    ordinary = vv_submit(customer=tight("Ordinary"), name="VV", program=source, vvm=platform.vvm)
    privileged = vv_submit(
        customer=tight("Operator", privileged=True), name="VV", program=source, vvm=platform.vvm
    )
    platform.drain()
    ordinary.refresh_from_db()
    privileged.refresh_from_db()
    assert ordinary.status == VVStatus.FAILED
    assert 'unknown sensor "Battery"' in ordinary.error and ordinary.error_line == 2
    assert privileged.status == VVStatus.FINISHED
    reading = privileged.storage.get(key="battery").value
    assert reading["unit"] == "%" and 0 < reading["value"] <= 100


CALLBACKS = """
var gps = VV.sensor.get('GPS');
for (var n = 0; n < 3; n++) {
  VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111 + n * 0.0002, 12.8619, 50),
                   tolerance: 2, sensors: [gps]}, function (d) {
    VV.storage.store('calls', (VV.storage.load('calls') || 0) + 1);
    VV.log('callback', n);
  });
}
"""


class Crash(BaseException):
    """A worker killed mid-step: no Exception (the platform fails a VV whose step raises one)."""


def run_until_task(platform, vv, q: int) -> Task:
    platform.drain(until=lambda: Task.objects.filter(vv=vv, q=q, vehicle__isnull=False).exists())
    return Task.objects.get(vv=vv, q=q)


@pytest.mark.django_db
def test_a_crash_between_a_tasks_answer_and_the_checkpoint_loses_and_repeats_nothing(
    platform, fleet, customer_a, monkeypatch
) -> None:
    vv = vv_submit(customer=customer_a, name="VV", program=CALLBACKS, vvm=platform.vvm)
    task = run_until_task(platform, vv, q=1)
    # The worker dies after the answer is written, while it resumes the VV: the answer and
    # the step are one transaction (one unit of work), so neither is committed.
    original = Runtime.step

    def crash(self, step):
        raise Crash("worker killed")

    monkeypatch.setattr(Runtime, "step", crash)
    with pytest.raises(Crash):
        task_complete(task_id=task.pk, readings=[{"sensor": "GPS", "value": 1}], vvm=platform.vvm)
    vv.refresh_from_db()
    task.refresh_from_db()
    assert vv.journal_length == 1 and vv.pending is not None  # the answer went with the step
    assert task.status == TaskStatus.OPEN and task.readings is None  # to be read again
    assert vv.storage.get(key="calls").value == 1  # the callback's effects did not survive
    # The worker comes back: it resumes the VV from its checkpoint.
    monkeypatch.setattr(Runtime, "step", original)
    platform.vvm.runtime.forget(str(vv.pk))
    vv_advance(vv_id=vv.pk, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    assert vv.storage.get(key="calls").value == 3
    lines = list(LogEntry.objects.filter(vv=vv).values_list("message", flat=True))
    assert lines == ["callback 0", "callback 1", "callback 2"]


@pytest.mark.django_db
def test_a_crash_after_the_effects_but_before_the_commit_applies_them_once(
    platform, fleet, customer_a, monkeypatch
) -> None:
    vv = vv_submit(customer=customer_a, name="VV", program=CALLBACKS, vvm=platform.vvm)
    task = run_until_task(platform, vv, q=1)
    original = vv_services.new_tasks_of

    def crash(*args, **kwargs):
        raise Crash("database connection lost")

    monkeypatch.setattr(vv_services, "new_tasks_of", crash)
    with pytest.raises(Crash):
        task_complete(task_id=task.pk, readings=[{"sensor": "GPS", "value": 1}], vvm=platform.vvm)
    vv.refresh_from_db()
    assert vv.storage.get(key="calls").value == 1  # rolled back with the step
    assert LogEntry.objects.filter(vv=vv).count() == 1
    monkeypatch.setattr(vv_services, "new_tasks_of", original)
    vv_advance(vv_id=vv.pk, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    assert vv.storage.get(key="calls").value == 3
    assert list(LogEntry.objects.filter(vv=vv).values_list("message", flat=True)) == [
        "callback 0",
        "callback 1",
        "callback 2",
    ]
    assert Task.objects.filter(vv=vv, status=TaskStatus.DONE).count() == 3


@pytest.mark.django_db
def test_a_crash_before_the_answer_is_committed_flies_the_task_again(
    platform, fleet, customer_a, monkeypatch
) -> None:
    vv = vv_submit(customer=customer_a, name="VV", program=CALLBACKS, vvm=platform.vvm)
    task = run_until_task(platform, vv, q=0)

    def crash(*args, **kwargs):
        raise Crash("worker killed while writing the answer")

    monkeypatch.setattr(vv_services, "journal_append", crash)
    with pytest.raises(Crash):
        task_complete(task_id=task.pk, readings=[{"sensor": "GPS", "value": 1}], vvm=platform.vvm)
    monkeypatch.undo()
    task.refresh_from_db()
    assert task.status == TaskStatus.OPEN and task.readings is None
    vv.refresh_from_db()
    assert vv.journal_length == 0 and vv.pending is not None
    # The vehicle's loop serves the still open task again.
    platform.rigs[fleet.pk].loop.wake()
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    assert vv.storage.get(key="calls").value == 3
    assert LogEntry.objects.filter(vv=vv).count() == 3


@pytest.mark.django_db
def test_journal_limits_warn_then_stop_the_vv(platform, fleet, customer_a, settings) -> None:
    settings.CPCC_JOURNAL_WARN_ENTRIES = 2
    settings.CPCC_JOURNAL_MAX_ENTRIES = 3
    source = GOOD.replace("n < 2", "n < 10")
    vv = vv_submit(customer=customer_a, name="VV", program=source, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.KILLED
    assert "quota: journal" in vv.error and "more than the 3 allowed" in vv.error
    warning = LogEntry.objects.get(vv=vv, level="warning")
    assert "the journal holds 2 answers" in warning.message
    assert vv.journal_length == 4


@pytest.mark.django_db
def test_a_call_the_customer_may_not_use_kills_the_vv_naming_the_quota(
    platform, fleet, customer_b
) -> None:
    restricted = tight("Restricted", allowed_api_calls=["sensor.get", "task.execute"])
    source = GOOD  # it stores its readings: storage.store is not allowed
    vv = vv_submit(customer=restricted, name="VV", program=source, vvm=platform.vvm)
    good = vv_submit(customer=customer_b, name="good", program=GOOD, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    good.refresh_from_db()
    assert vv.status == VVStatus.KILLED
    assert "storage.store is not allowed" in vv.error and "quota: allowed API calls" in vv.error
    assert vv.storage.count() == 0
    assert good.status == VVStatus.FINISHED
