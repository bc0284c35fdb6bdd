"""The VVM services: loader, mapper, migrator and steps, on discrete-event time."""

from __future__ import annotations

import pytest

from fleet.models import VehicleStatus
from missions.models import JournalEntry, Migration, Task, TaskStatus, VirtualVehicle, VVStatus
from tests.factories import AREA_ONE, AREA_TWO, VehicleFactory
from vvm_worker.services import (
    ProgramRejected,
    task_complete,
    vehicle_set_status,
    vv_advance,
    vv_submit,
)

ONE_TASK = """
var co2 = VV.sensor.get('CO2');
var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(%s, %s, 50), tolerance: 2,
                         sensors: [co2]});
VV.storage.store('co2', d[0]);
"""


def program(lat: float = 48.1111, lng: float = 12.8619) -> str:
    return ONE_TASK % (lat, lng)


@pytest.fixture
def fleet(platform, ground_station):
    one = VehicleFactory(name="Heli One")
    platform.add_vehicle_loop(one)
    return one


def test_a_syntax_error_is_refused_at_submission_with_line_and_column(
    customer_a, vvm_factory
) -> None:
    with pytest.raises(ProgramRejected, match=r"line 2, column 9: SyntaxError: Unexpected token"):
        vv_submit(
            customer=customer_a, name="bad", program="var a = 1;\nvar b = ;", vvm=vvm_factory()
        )
    assert not VirtualVehicle.objects.exists()


def test_a_new_vv_is_loaded_on_a_ground_station(customer_a, ground_station, vvm_factory) -> None:
    vvm = vvm_factory()
    vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=vvm)
    assert vv.status == VVStatus.RUNNING
    assert vv.host_gs == ground_station
    assert vvm.dispatcher.arrived == [vv.pk]
    assert vv.catalog and "Battery" not in [e["name"] for e in vv.catalog]


def test_a_vv_flies_to_the_rv_that_serves_its_task_and_comes_back(
    platform, fleet, customer_a
) -> None:
    vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    assert vv.host_gs is not None and vv.host_rv is None
    moves = [(m.from_name, m.to_name) for m in Migration.objects.filter(vv=vv)]
    assert moves == [("GS Base", "Heli One"), ("Heli One", "GS Base")]
    reading = vv.storage.get(key="co2").value
    assert reading["sensor"] == "CO2" and reading["unit"] == "ppm"
    assert 300 < reading["value"] < 2000
    assert "Heli One" not in str(reading)  # readings never name the vehicle
    task = vv.tasks.get()
    assert task.status == TaskStatus.DONE and task.vehicle == fleet
    assert task.done_s > task.requested_s


def test_the_parallel_vv_quota_queues_extra_vvs(platform, fleet, customer_a) -> None:
    customer_a.max_parallel_vvs = 1
    customer_a.save()
    first = vv_submit(customer=customer_a, name="first", program=program(), vvm=platform.vvm)
    second = vv_submit(
        customer=customer_a, name="second", program=program(48.112), vvm=platform.vvm
    )
    assert second.status == VVStatus.QUEUED
    platform.drain()
    first.refresh_from_db()
    second.refresh_from_db()
    assert first.status == second.status == VVStatus.FINISHED
    assert second.started_s >= first.finished_s


def test_a_task_no_rv_can_serve_is_rejected_and_the_program_goes_on(
    platform, fleet, customer_a
) -> None:
    source = """
    var gps = VV.sensor.get('GPS');
    try {
      VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(10, 10, 50), tolerance: 2, sensors: [gps]});
    } catch (e) { VV.storage.store('rejected', [e.name, e.message]); }
    VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50), tolerance: 2, sensors: [gps]});
    VV.storage.store('done', true);
    """
    vv = vv_submit(customer=customer_a, name="VV", program=source, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    name, message = vv.storage.get(key="rejected").value
    assert name == "TaskRejectedError"
    assert "outside every operation area" in message
    statuses = list(vv.tasks.order_by("q").values_list("status", flat=True))
    assert statuses == [TaskStatus.REJECTED, TaskStatus.DONE]


def test_a_rejected_task_after_a_flight_sends_the_vv_back_to_a_ground_station(
    platform, fleet, customer_a
) -> None:
    source = (
        program()
        + "VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 500), tolerance: 2, sensors: [co2]});"
    )
    vv = vv_submit(customer=customer_a, name="VV", program=source, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FAILED
    assert "TaskRejectedError" in vv.error and "altitude" in vv.error
    moves = [(m.from_name, m.to_name, m.reason) for m in Migration.objects.filter(vv=vv)]
    assert moves[-1] == ("Heli One", "GS Base", "no vehicle can serve its task")


def test_a_failing_vv_does_not_disturb_another_customers_vv(
    platform, fleet, customer_a, customer_b
) -> None:
    source = program() + "\nundefinedFunction();\n"
    bad = vv_submit(customer=customer_a, name="bad", program=source, vvm=platform.vvm)
    good = vv_submit(customer=customer_b, name="good", program=program(48.112), vvm=platform.vvm)
    platform.drain()
    bad.refresh_from_db()
    good.refresh_from_db()
    assert bad.status == VVStatus.FAILED
    assert "ReferenceError: undefinedFunction is not defined" in bad.error
    assert bad.error_line == source.splitlines().index("undefinedFunction();") + 1
    assert bad.storage.filter(key="co2").exists()  # its work before the error is kept
    assert good.status == VVStatus.FINISHED


def test_a_vv_over_its_cpu_quota_is_killed_and_others_finish(
    platform, fleet, customer_a, customer_b
) -> None:
    customer_a.cpu_ms_per_step = 100
    customer_a.save()
    hog = vv_submit(customer=customer_a, name="hog", program="while (true) {}", vvm=platform.vvm)
    good = vv_submit(customer=customer_b, name="good", program=program(), vvm=platform.vvm)
    platform.drain()
    hog.refresh_from_db()
    good.refresh_from_db()
    assert hog.status == VVStatus.KILLED
    assert "CPU time" in hog.error
    assert good.status == VVStatus.FINISHED


def vv_at_its_first_task(customer, platform) -> tuple[VirtualVehicle, Task]:
    """A VV of two tasks, run until the first is on an RV's list: the VV and that task."""
    vv = vv_submit(
        customer=customer, name="VV", program=program() + program(48.112), vvm=platform.vvm
    )
    platform.drain(until=Task.objects.filter(vv=vv).exists)
    return vv, Task.objects.get(vv=vv)


def test_an_answer_sent_with_the_vvs_lock_to_a_request_it_no_longer_waits_for_is_undone(
    fleet, customer_a, platform
) -> None:
    # The RV's loop names the task's request (q): the answer goes to the database with the
    # VV's lock. A task open for another request than the one the VV waits for (made so by
    # hand) is left as it was, and so is the VV.
    vv, task = vv_at_its_first_task(customer_a, platform)
    before = VirtualVehicle.objects.get(pk=vv.pk)
    stale = Task.objects.create(
        vv=vv, q=task.q + 1, lat=task.lat, lng=task.lng, alt=task.alt,
        tolerance_m=task.tolerance_m, sensors=task.sensors, requested_s=task.requested_s,
        vehicle_id=task.vehicle_id,
    )  # fmt: skip
    assert not task_complete(
        task_id=stale.pk, readings=[{"value": 1}], vvm=platform.vvm,
        vehicle_id=stale.vehicle_id, vv_id=vv.pk, q=stale.q,
    )  # fmt: skip
    stale.refresh_from_db()
    assert (stale.status, stale.readings, stale.done_s) == (TaskStatus.OPEN, None, None)
    after = VirtualVehicle.objects.get(pk=vv.pk)
    assert (after.journal_length, after.pending) == (before.journal_length, before.pending)
    # The task it waits for, named with its request, is answered as before.
    stale.delete()
    assert task_complete(
        task_id=task.pk, readings=[{"value": 2}], vvm=platform.vvm,
        vehicle_id=task.vehicle_id, vv_id=vv.pk, q=task.q,
    )  # fmt: skip
    assert Task.objects.get(pk=task.pk).status == TaskStatus.DONE


def test_completing_a_task_twice_changes_nothing_the_second_time(
    fleet, customer_a, platform
) -> None:
    vv, task = vv_at_its_first_task(customer_a, platform)
    assert task_complete(task_id=task.pk, readings=[{"value": 1}], vvm=platform.vvm)
    journal = list(JournalEntry.objects.filter(vv=vv).values_list("entry", flat=True))
    assert not task_complete(task_id=task.pk, readings=[{"value": 2}], vvm=platform.vvm)
    assert list(JournalEntry.objects.filter(vv=vv).values_list("entry", flat=True)) == journal
    assert len(journal) == 1
    assert journal[0]["data"] == [{"value": 1}]
    assert VirtualVehicle.objects.get(pk=vv.pk).journal_length == 1


def test_a_vv_migrates_to_the_rv_of_its_next_area(platform, fleet, customer_a) -> None:
    two = VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lng=12.8675)
    platform.add_vehicle_loop(two)
    vv = vv_submit(
        customer=customer_a,
        name="VV",
        program=program() + program(48.1116, 12.8667),
        vvm=platform.vvm,
    )
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    moves = [(m.from_name, m.to_name) for m in Migration.objects.filter(vv=vv)]
    assert moves == [("GS Base", "Heli One"), ("Heli One", "Heli Two"), ("Heli Two", "GS Base")]
    assert [t.vehicle.name for t in vv.tasks.order_by("q")] == ["Heli One", "Heli Two"]


def test_an_rv_in_maintenance_hands_its_vvs_to_another_that_can_serve_them(
    platform, fleet, customer_a
) -> None:
    spare = VehicleFactory(name="Spare", depot_lat=48.1139, depot_lng=12.8591)
    platform.add_vehicle_loop(spare)
    vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=platform.vvm)
    # Run until the VV is aboard Heli One, then take Heli One out of service.
    platform.drain(until=VirtualVehicle.objects.filter(pk=vv.pk, host_rv=fleet).exists)
    assert vv.tasks.get().status == TaskStatus.OPEN
    vehicle_set_status(vehicle=fleet, status=VehicleStatus.MAINTENANCE, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    assert vv.tasks.get().vehicle == spare
    assert [m.to_name for m in Migration.objects.filter(vv=vv)] == ["Heli One", "Spare", "GS Base"]


def test_a_vv_waits_on_a_ground_station_while_its_only_rv_is_in_maintenance(
    platform, fleet, customer_a
) -> None:
    vehicle_set_status(vehicle=fleet, status=VehicleStatus.MAINTENANCE, vvm=platform.vvm)
    vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.RUNNING and vv.host_gs is not None and vv.pending is not None
    vehicle_set_status(vehicle=fleet, status=VehicleStatus.ACTIVE, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED


def test_without_ground_station_a_vv_stays_queued_until_one_is_added(platform, customer_a) -> None:
    from vvm_worker.services import ground_station_create

    platform.add_vehicle_loop(VehicleFactory(name="Heli One"))
    vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.QUEUED and vv.host_gs is None
    late = ground_station_create(
        config={"name": "Late GS", "lat": 48.11, "lng": 12.86, "alt": 0}, vvm=platform.vvm
    )
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert vv.host_gs == late and vv.storage.filter(key="co2").exists()


def test_a_vv_asking_again_and_again_for_rejected_tasks_ends_at_its_tasks_quota(
    platform, fleet, customer_a, customer_b
) -> None:
    customer_a.max_tasks_per_vv = 120
    customer_a.save()
    source = """
    var gps = VV.sensor.get('GPS');
    var far = {type: 'point', position: new VV.types.LatLngAlt(10, 10, 50), tolerance: 2, sensors: [gps]};
    var rejected = 0;
    while (true) { try { VV.task.execute(far); } catch (e) { rejected++; } }
    """
    stubborn = vv_submit(customer=customer_a, name="stubborn", program=source, vvm=platform.vvm)
    good = vv_submit(customer=customer_b, name="good", program=program(), vvm=platform.vvm)
    platform.drain()
    stubborn.refresh_from_db()
    good.refresh_from_db()
    assert stubborn.status == VVStatus.KILLED
    assert "quota: tasks per VV" in stubborn.error
    assert stubborn.tasks.filter(status=TaskStatus.REJECTED).count() == 120
    assert good.status == VVStatus.FINISHED


def test_cancelling_a_vv_in_flight_sends_it_home_and_keeps_its_storage(
    platform, fleet, customer_a
) -> None:
    from vvm_worker.services import vv_cancel

    vv = vv_submit(
        customer=customer_a, name="VV", program=program() + program(48.112), vvm=platform.vvm
    )
    platform.drain(until=lambda: VirtualVehicle.objects.get(pk=vv.pk).storage.exists())
    assert vv_cancel(vv_id=vv.pk, vvm=platform.vvm)
    assert not vv_cancel(vv_id=vv.pk, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.CANCELLED and vv.host_gs is not None
    assert vv.storage.filter(key="co2").exists()
    assert set(vv.tasks.values_list("status", flat=True)) == {TaskStatus.DONE, TaskStatus.CANCELLED}
    assert Migration.objects.filter(vv=vv).last().reason == "cancelled"


def test_late_messages_about_deleted_vvs_or_customers_are_ignored(vvm_factory, customer_a) -> None:
    import uuid

    from vvm_worker.services import vv_admit_queued, vv_advance

    waiting = vv_submit(customer=customer_a, name="VV", program=program(), vvm=vvm_factory())
    vvm = vvm_factory()
    vv_advance(vv_id=uuid.uuid4(), vvm=vvm)
    assert vv_admit_queued(customer_id=987654, vvm=vvm) == []
    dispatched = vvm.dispatcher
    assert (dispatched.arrived, dispatched.vehicles, dispatched.slots) == ([], [], [])
    assert list(VirtualVehicle.objects.values_list("pk", "status", "updated")) == [
        (waiting.pk, VVStatus.QUEUED, waiting.updated)
    ]
    assert not Task.objects.exists() and not Migration.objects.exists()


def test_the_mapper_sees_an_rv_added_or_an_area_changed_at_once(
    platform, fleet, customer_a
) -> None:
    # The mapper keeps the fleet's areas between decisions: a change must reach the next one.
    there = program(48.1116, 12.8667)  # in AREA_TWO only

    def run_one(name: str) -> VirtualVehicle:
        vv = vv_submit(customer=customer_a, name=name, program=there, vvm=platform.vvm)
        platform.drain()
        vv.refresh_from_db()
        return vv

    first = run_one("before")
    assert first.status == VVStatus.FAILED and "outside every operation area" in first.error
    two = VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lng=12.8675)
    platform.add_vehicle_loop(two)
    second = run_one("added")
    assert second.status == VVStatus.FINISHED
    assert second.tasks.get().vehicle == two
    two.area = [list(p) for p in AREA_ONE]  # the provider moves Heli Two's area away
    two.save()
    fleet.area = [list(p) for p in AREA_TWO]  # and Heli One's over the point
    fleet.save()
    third = run_one("moved")
    assert third.status == VVStatus.FINISHED
    assert third.tasks.get().vehicle == fleet


# --- what a submission may not be: names that are not plain text, a full queue -------------


@pytest.mark.parametrize(
    ("name", "what"),
    [
        ("\x1b[31mred", "a control character (U+001B) at character 1"),
        ("two\nlines", "a control character (U+000A) at character 4"),
        ("c1 \x85 next line", "a control character (U+0085) at character 4"),
        ("abc\u202egpj.exe", "U+202E RIGHT-TO-LEFT OVERRIDE) at character 4"),
        ("\u2066isolated\u2069", "U+2066 LEFT-TO-RIGHT ISOLATE) at character 1"),
        ("mark\u200f", "U+200F RIGHT-TO-LEFT MARK) at character 5"),
    ],
)
def test_a_name_with_a_control_or_bidi_character_is_refused(
    customer_a, user_a, vvm_factory, name, what
) -> None:
    from django.core.exceptions import ValidationError

    from vvm_worker.services import vv_create_copies_for_user

    with pytest.raises(ValidationError) as refused:
        vv_submit(customer=customer_a, name=name, program=program(), vvm=vvm_factory())
    assert what in refused.value.message_dict["name"][0]
    with pytest.raises(ValidationError):
        vv_create_copies_for_user(
            user=user_a, name=name, program=program(), copies=2, vvm=vvm_factory()
        )
    assert not VirtualVehicle.objects.exists()
    # Letters of any script, and marks that are not controls, are fine.
    fine = vv_submit(
        customer=customer_a, name="Über 東京 — ok", program=program(), vvm=vvm_factory()
    )
    assert fine.name == "Über 東京 — ok"


def test_a_queued_vv_cannot_be_renamed_to_a_name_with_a_bidi_override(
    customer_a, user_a, vvm_factory
) -> None:
    from django.core.exceptions import ValidationError

    from vvm_worker.services import vv_update_program_for_user

    vv = vv_submit(customer=customer_a, name="plain", program=program(), vvm=vvm_factory())
    assert vv.status == VVStatus.QUEUED  # no ground station: it waits
    with pytest.raises(ValidationError, match="U\\+202D"):
        vv_update_program_for_user(
            user=user_a, vv_id=vv.pk, name="x\u202dy", program=program(), vvm=vvm_factory()
        )
    vv.refresh_from_db()
    assert vv.name == "plain"


def test_submissions_beyond_the_queue_quota_are_refused_for_that_customer_only(
    customer_a, customer_b, user_a, vvm_factory
) -> None:
    from vvm_worker.services import (
        VVQueueFull,
        vv_cancel,
        vv_create_copies_for_user,
        vv_restart_for_user,
    )

    vvm = vvm_factory()
    customer_a.max_queued_vvs = 3
    customer_a.save()
    # No ground station: every VV stays queued.
    queued = [
        vv_submit(customer=customer_a, name=f"A{n}", program=program(), vvm=vvm) for n in range(3)
    ]
    with pytest.raises(VVQueueFull) as full:
        vv_submit(customer=customer_a, name="A3", program=program(), vvm=vvm)
    message = str(full.value)
    assert "Customer A has 3 VV(s) waiting in the queue and may have at most 3" in message
    assert "max_queued_vvs" in message and "cancel some" in message
    # Scenario submissions count the same.
    from vvm_worker.scenario import VVSpec
    from vvm_worker.services.scenarios import scenario_submit_vv

    with pytest.raises(VVQueueFull):
        scenario_submit_vv(
            spec=VVSpec(customer="Customer A", name="S", source=program(), program_path=None),
            instance_name="S",
            customer=customer_a,
            vvm=vvm,
        )
    # Customer B's queue is its own.
    vv_submit(customer=customer_b, name="B0", program=program(), vvm=vvm)
    assert VirtualVehicle.objects.filter(customer=customer_a).count() == 3
    # Copies go in all together or not at all, and the message counts them.
    vv_cancel(vv_id=queued[0].pk, vvm=vvm)
    with pytest.raises(VVQueueFull, match="so 2 more cannot be submitted"):
        vv_create_copies_for_user(user=user_a, name="C", program=program(), copies=2, vvm=vvm)
    assert not VirtualVehicle.objects.filter(name__startswith="C").exists()
    (copy,), problem = vv_create_copies_for_user(
        user=user_a, name="C", program=program(), copies=1, vvm=vvm
    )
    assert problem is None and copy.status == VVStatus.QUEUED
    # A restart queues a new VV: it counts too.
    with pytest.raises(VVQueueFull):
        vv_restart_for_user(user=user_a, vv_id=queued[0].pk, vvm=vvm)
    # VVs that started or ended leave room: only those waiting count.
    VirtualVehicle.objects.filter(pk=queued[1].pk).update(status=VVStatus.RUNNING)
    assert vv_restart_for_user(user=user_a, vv_id=queued[0].pk, vvm=vvm).status == VVStatus.QUEUED


def test_a_scenario_with_a_vv_name_the_submission_refuses_says_where_before_loading(
    db,
) -> None:
    import json

    from accounts.models import Customer
    from tests.conftest import SCENARIOS
    from vvm_worker.scenario import ScenarioError, parse_scenario
    from vvm_worker.services.scenarios import scenario_apply

    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    data["vvs"][1]["name"] = "\x1b[2Jwipe"
    scenario = parse_scenario(data, base_dir=SCENARIOS)
    with pytest.raises(ScenarioError, match=r"vvs\[1\]\.name: The name has a control character"):
        scenario_apply(scenario=scenario, logins=False)
    assert not Customer.objects.exists()


class Heard:
    """An announcer that keeps what it hears (events as the live map would get them)."""

    def __init__(self) -> None:
        self.events: list[dict] = []

    def announce(self, event: dict) -> None:
        self.events.append(event)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


def test_the_map_hears_each_new_task_and_migration_with_its_row_id(
    customer_a, ground_station, vvm_factory, django_capture_on_commit_callbacks
) -> None:
    """On PostgreSQL a step's new rows are written without waiting (their ids come back by
    the end of the unit of work): the events that name them are built only then."""
    VehicleFactory(name="Heli One")
    vvm = vvm_factory()
    vvm.announcer = heard = Heard()
    with django_capture_on_commit_callbacks(execute=True):
        vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=vvm)
    with django_capture_on_commit_callbacks(execute=True):
        vv_advance(vv_id=vv.pk, vvm=vvm)
    tasks = [e for e in heard.events if e["kind"] == "task"]
    moves = [e for e in heard.events if e["kind"] == "migration"]
    assert [t["id"] for t in tasks] == list(Task.objects.filter(vv=vv).values_list("pk", flat=True))
    assert [m["id"] for m in moves] == list(
        Migration.objects.filter(vv=vv).values_list("pk", flat=True)
    )
    assert tasks and moves and all(e["id"] is not None for e in tasks + moves)


def test_an_rv_workers_estimates_wait_for_the_map_tick_and_the_last_one_is_written(
    vvm_factory, customer_a
) -> None:
    # A busy RV plans many times a second: what it expects is written at the host's map tick
    # (its latest word for each VV), not by a statement of its own at every plan.
    from vvm_worker.executor import DatabaseStore

    vehicle = VehicleFactory(name="Heli One")
    vvm = vvm_factory()
    vv = vv_submit(customer=customer_a, name="eta", program=program(), vvm=vvm)
    store = DatabaseStore(vehicle_id=vehicle.pk, vvm=vvm, ticks=True)
    store.estimated({vv.pk: 100.0})
    store.estimated({vv.pk: 140.0})
    vv.refresh_from_db()
    assert vv.next_task_eta_s is None
    store.write_waiting()
    vv.refresh_from_db()
    assert vv.next_task_eta_s == 140.0
    # Without ticks nor deferred reports, each estimate that moves is written at once.
    at_once = DatabaseStore(vehicle_id=vehicle.pk, vvm=vvm)
    at_once.estimated({vv.pk: 200.0})
    vv.refresh_from_db()
    assert vv.next_task_eta_s == 200.0


def test_simulate_writes_the_whole_fleets_estimates_in_one_statement_when_it_ticks(
    vvm_factory, customer_a
) -> None:
    # In simulate (deferred reports) the estimates wait too: its drain writes those of every
    # RV at once, one statement for the fleet, not one a VV at every plan.
    from django.db import connection
    from django.test.utils import CaptureQueriesContext

    from vvm_worker.executor import DatabaseStore, write_estimates

    vvm = vvm_factory()
    vvs = [vv_submit(customer=customer_a, name=n, program=program(), vvm=vvm) for n in "abc"]
    stores = [
        DatabaseStore(vehicle_id=VehicleFactory(name=n).pk, vvm=vvm, defer_reports=True)
        for n in ("Heli One", "Heli Two")
    ]
    stores[0].estimated({vvs[0].pk: 100.0, vvs[1].pk: 105.0})
    stores[1].estimated({vvs[2].pk: 120.0})
    stores[0].estimated({vvs[0].pk: 90.0, vvs[1].pk: 105.5})  # (within the slack: kept)
    assert set(VirtualVehicle.objects.values_list("next_task_eta_s", flat=True)) == {None}
    with CaptureQueriesContext(connection) as statements:
        write_estimates(stores)
    assert len(statements) == 1
    etas = dict(VirtualVehicle.objects.values_list("pk", "next_task_eta_s"))
    assert etas == {vvs[0].pk: 90.0, vvs[1].pk: 105.0, vvs[2].pk: 120.0}
    with CaptureQueriesContext(connection) as statements:
        write_estimates(stores)  # nothing waits
    assert len(statements) == 0


def test_more_estimates_than_one_statement_takes_are_all_written(customer_a) -> None:
    # (A simulation of a thousand VVs: on SQLite a statement takes a few hundred.)
    from vvm_worker.services.waiting import vvs_record_next_task_eta

    vvs = VirtualVehicle.objects.bulk_create(
        VirtualVehicle(
            customer=customer_a, name=f"VV {n}", program="", seed=n, start_ms=0, submitted_s=0.0
        )
        for n in range(1000)
    )
    etas = {vv.pk: 100.0 + n for n, vv in enumerate(vvs)}
    assert vvs_record_next_task_eta(etas=etas) == {}
    assert dict(VirtualVehicle.objects.values_list("pk", "next_task_eta_s")) == etas


@pytest.mark.django_db(transaction=True, serialized_rollback=True)  # another connection
def test_an_estimate_whose_vv_another_worker_holds_waits_for_the_next_tick(
    vvm_factory, customer_a
) -> None:
    # The map tick writes every estimate of an RV in one statement that waits for no row: on
    # PostgreSQL a VV that another transaction holds (answered elsewhere right now) gets its
    # estimate at the next tick, the newest one if the plan changed meanwhile; the others at
    # once. (SQLite has no row locks: its one writer writes them all.)
    import threading

    from django.db import connection, transaction

    from vvm_worker.executor import DatabaseStore

    vehicle = VehicleFactory(name="Heli One")
    vvm = vvm_factory()
    held, free = (vv_submit(customer=customer_a, name=n, program=program(), vvm=vvm) for n in "ab")
    store = DatabaseStore(vehicle_id=vehicle.pk, vvm=vvm, ticks=True)
    store.estimated({held.pk: 100.0, free.pk: 110.0})
    postgres = connection.vendor == "postgresql"
    holding, release, done = threading.Event(), threading.Event(), threading.Event()

    def hold() -> None:
        try:
            with transaction.atomic():
                VirtualVehicle.objects.select_for_update(no_key=True).get(pk=held.pk)
                holding.set()
                release.wait(30)
        finally:
            connection.close()
            done.set()

    if postgres:
        threading.Thread(target=hold).start()
        assert holding.wait(30)
    try:
        store.write_waiting()  # waits for no held row
        etas = dict(VirtualVehicle.objects.values_list("pk", "next_task_eta_s"))
        assert etas == {held.pk: None if postgres else 100.0, free.pk: 110.0}
    finally:
        release.set()
        if postgres:
            assert done.wait(30)
    store.estimated({held.pk: 130.0, free.pk: 110.0})
    store.write_waiting()
    etas = dict(VirtualVehicle.objects.values_list("pk", "next_task_eta_s"))
    assert etas == {held.pk: 130.0, free.pk: 110.0}


def test_a_task_one_rv_covers_goes_to_it_without_reading_any_rvs_open_tasks(
    customer_a, ground_station, vvm_factory
) -> None:
    # Open tasks and plans rank RVs whose areas overlap; where one RV covers the task (the
    # common case), there is nothing to rank and nothing of that is read.
    from django.db import connection
    from django.test.utils import CaptureQueriesContext

    one = VehicleFactory(name="Heli One")
    VehicleFactory(name="Heli Two", area=AREA_TWO)
    vvm = vvm_factory()
    vv = vv_submit(customer=customer_a, name="VV", program=program(), vvm=vvm)
    with CaptureQueriesContext(connection) as queries:
        vv_advance(vv_id=vv.pk, vvm=vvm)
    assert VirtualVehicle.objects.get(pk=vv.pk).host_rv == one
    task_lists = [q["sql"] for q in queries if 'FROM "missions_task"' in q["sql"]]
    assert task_lists == []


def test_a_worker_of_several_rvs_reads_their_statuses_with_the_vvs_lock_once_a_unit_of_work(
    vvm_factory,
) -> None:
    # The loops of a worker of several RVs do not know their RVs' statuses (an operator may
    # change them any time): a unit of work reads them once, sent ahead with its first
    # statements, however often it routes; a status committed before it starts is seen.
    from django.db import connection, transaction
    from django.test.utils import CaptureQueriesContext

    from cpcc_site.prepared import pipelined
    from fleet.geo import Position
    from vvm_worker.runtime import TaskRequest
    from vvm_worker.services.base import LocalRV
    from vvm_worker.services.routing import fleet_caps, rv_statuses_read_ahead

    one, two = VehicleFactory(name="Heli One"), VehicleFactory(name="Heli Two", area=AREA_TWO)
    vehicle_set_status(vehicle=two, status=VehicleStatus.MAINTENANCE, vvm=vvm_factory())

    class Loops:  # what the worker's loops say of their RVs: where they are, not their status
        def live(self, vehicle_id: int, *, route: bool = True) -> LocalRV:
            return LocalRV(status=None, position=Position(48.111, 12.86, 0), route=())

    vvm = vvm_factory()
    vvm.local_rvs, vvm.local_fleet = {one.pk, two.pk}, Loops()  # type: ignore[assignment]
    with (
        CaptureQueriesContext(connection) as queries,
        transaction.atomic(),
        pipelined(),
        rv_statuses_read_ahead(vvm=vvm),
    ):
        first = fleet_caps(vvm)
        again = fleet_caps(vvm, [TaskRequest(48.1111, 12.8619, 50, 2, ("CO2",))])
    assert {c.id: c.active for c in first} == {one.pk: True, two.pk: False}
    assert [c.id for c in again] == [one.pk]
    statuses = [q for q in queries if '"fleet_vehicle"."status" AS "status"' in q["sql"]]
    assert len(statuses) == 1
