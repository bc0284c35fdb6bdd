"""Faults of the distributed platform, across real processes: worker processes of their own
(tests/live.py) on a real Redis, sharing the test database (SQLite or PostgreSQL).

An RV worker SIGKILLed in the middle of steps ends its VVs exactly as an undisturbed run; a
ground-station worker killed and Celery messages lost leave no VV behind (the hosts' sweeps
find the work); two ground-station workers admitting one customer's VVs keep to its quota.
Flights are instant (speed 0).
"""

from __future__ import annotations

import socket
import sqlite3
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path

import pytest
from django.db import connection
from kombu.exceptions import ChannelError

from cpcc_site.celery import app
from missions.models import (
    ACTIVE_STATUSES,
    ENDED_STATUSES,
    JournalEntry,
    Migration,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
)
from tests.factories import (
    AREA_ONE,
    AREA_TWO,
    CustomerFactory,
    GroundStationFactory,
    UserFactory,
    VehicleFactory,
)
from tests.live import Workers, program_log
from tests.polling import wait_until
from vvm_worker.dispatch import SHARED_QUEUE, gs_queue, rv_queue
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_create_for_user, vv_submit
from vvm_worker.simulation import Simulation

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

# The whole field of the paper's Figures 2 and 3: both areas.
FIELD = [[48.109, 12.859], [48.109, 12.868], [48.114, 12.868], [48.114, 12.859], [48.109, 12.859]]

# Visits TASKS random points of Heli One's area. Each visit counts in storage, numbers itself
# with a closure, draws random numbers and logs a line; the callback also computes for a
# while (``spin``), so that a step lasts long enough to be cut by a kill.
COUNTER = """
var co2 = VV.sensor.get('CO2');
function counter() { var n = 0; return function () { n += 1; return n; }; }
var next = counter();
function spin(rounds) {
  var x = 0;
  for (var i = 0; i < rounds; ++i) x = (x * 31 + i) % 1000003;
  return x;
}
var points = [];
for (var k = 0; k < TASKS; ++k) {
  points.push(new VV.types.LatLngAlt(48.1095 + 0.004 * Math.random(),
                                     12.8595 + 0.004 * Math.random(), 50));
}
VV.log('start', next(), Math.random());
for (var k = 0; k < points.length; ++k) {
  VV.task.execute({type: 'point', position: points[k], tolerance: 2, sensors: [co2]},
    function (data) {
      var count = (VV.storage.load('count') || 0) + 1;
      VV.storage.store('count', count);
      VV.storage.store('visit ' + k,
                       {n: next(), random: Math.random(), readings: data.length, spin: spin(SPIN)});
      VV.log('visit', k, 'count', count, 'closure', next(), 'random', Math.random());
    });
}
VV.log('done:', VV.storage.load('count'), 'visits, closure at', next());
"""
TASKS = 8
SPIN = 4_000_000  # about 30 ms of V8 per visit, replayed at every later step

# One point in Heli One's area, then one in Heli Two's: the VV migrates from RV to RV.
TWO_AREAS = """
var co2 = VV.sensor.get('CO2');
var points = [new VV.types.LatLngAlt(48.1111, 12.8619, 50),
              new VV.types.LatLngAlt(48.1116, 12.8667, 50)];
for (var n = 0; n < points.length; ++n) {
  VV.task.execute({type: 'point', position: points[n], tolerance: 2, sensors: [co2]},
    function (data) { VV.storage.store('p' + n, data[0].value); });
}
VV.log('done:', VV.storage.list().length, 'readings');
"""

# Three points anywhere on the field.
THREE_POINTS = """
var co2 = VV.sensor.get('CO2');
VV.log('start');
var points = [new VV.types.LatLngAlt(48.1111, 12.8619, 50),
              new VV.types.LatLngAlt(48.1116, 12.8667, 50),
              new VV.types.LatLngAlt(48.1101, 12.8622, 50)];
for (var n = 0; n < points.length; ++n) {
  VV.task.execute({type: 'point', position: points[n], tolerance: 2, sensors: [co2]},
    function (data) { VV.storage.store('p' + n, data[0].value); });
}
VV.log('end');
"""


@pytest.fixture
def workers(broker_url: str, tmp_path: Path, transactional_db: None) -> Iterator[Workers]:
    """Worker processes of this test with instant flights, stopped at its end."""
    pool = Workers(tmp_path, broker_url, speed=0)
    try:
        yield pool
    finally:
        pool.stop_all()


def counter_program(tasks: int = TASKS) -> str:
    return COUNTER.replace("TASKS", str(tasks)).replace("SPIN", str(SPIN))


def ended(*vvs: VirtualVehicle) -> bool:
    ids = [vv.pk for vv in vvs]
    return VirtualVehicle.objects.filter(pk__in=ids, status__in=ENDED_STATUSES).count() == len(ids)


def outcome(vv: VirtualVehicle) -> tuple[dict, list[str]]:
    """What a VV leaves behind for its owner: its storage and its log, in order."""
    storage = dict(vv.storage.values_list("key", "value"))
    log = program_log(vv)
    return storage, log


# --- a: an RV worker killed in the middle of steps ------------------------------------------


def step_under_way() -> bool:
    """Whether a worker is in the middle of a step: inside the one transaction that answers a
    task, steps the VV and routes its next request (it holds SQLite's write lock; on
    PostgreSQL, it has inserted a journal entry that is not committed yet)."""
    if connection.vendor == "sqlite":
        probe = sqlite3.connect(connection.settings_dict["NAME"], timeout=0, isolation_level=None)
        try:
            probe.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError:
            return True  # another connection holds the write lock
        else:
            probe.execute("ROLLBACK")
            return False
        finally:
            probe.close()
    with connection.cursor() as cursor:
        cursor.execute(
            "SELECT 1 FROM pg_locks l JOIN pg_class c ON c.oid = l.relation "
            "WHERE c.relname = %s AND l.mode = 'RowExclusiveLock' AND l.pid <> pg_backend_pid()",
            [JournalEntry._meta.db_table],
        )
        return cursor.fetchone() is not None


def answers(vvs: list[VirtualVehicle]) -> int:
    """The answers committed to these VVs' journals."""
    return JournalEntry.objects.filter(vv__in=[vv.pk for vv in vvs]).count()


def visits_logged(vvs: list[VirtualVehicle]) -> int:
    return sum(vv.log.filter(message__startswith="visit ").count() for vv in vvs)


def test_an_rv_worker_killed_mid_step_three_times_ends_its_vvs_as_an_undisturbed_run(
    workers,
) -> None:
    GroundStationFactory(name="GS Base")
    heli_one = VehicleFactory(name="Heli One", area=AREA_ONE)
    customers = [CustomerFactory(name="Customer A"), CustomerFactory(name="Customer B")]
    seeds = [11, 22]
    program = counter_program()

    # The same programs with the same seeds, undisturbed, in one process (as `simulate` runs).
    reference = Simulation()
    reference.add_vehicle_loop(heli_one)
    expected = [
        vv_submit(customer=c, name="Reference", program=program, vvm=reference.vvm, seed=s)
        for c, s in zip(customers, seeds, strict=True)
    ]
    reference.drain()
    for vv in expected:
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error

    vvm = platform_vvm()
    vvs = [
        vv_submit(customer=c, name="Counter", program=program, vvm=vvm, seed=s)
        for c, s in zip(customers, seeds, strict=True)
    ]
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    kills = attempts = 0
    while kills < 3:
        attempts += 1
        assert attempts <= 10, f"only {kills} of {attempts - 1} kills cut a step"
        assert not ended(*vvs), f"the VVs ended after {kills} kills cut a step"
        wait_until(step_under_way, timeout=60, what="a step under way", details=workers.logs)
        before = answers(vvs)
        workers.kill("Heli One")
        # Dead, the worker commits nothing more: no answer more than while the step was under
        # way shows that the kill came in the middle of it (its answer went with it).
        kills += answers(vvs) == before
        logged = visits_logged(vvs)
        workers.start("rvworker", "Heli One")
        wait_until(
            lambda logged=logged: visits_logged(vvs) > logged or ended(*vvs),
            timeout=60,
            what="Heli One's worker to go on after its restart",
            details=workers.logs,
        )
    wait_until(lambda: ended(*vvs), timeout=120, what="the VVs to end", details=workers.logs)

    for vv, undisturbed in zip(vvs, expected, strict=True):
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error
        assert vv.tasks.filter(status=TaskStatus.DONE).count() == TASKS
        assert vv.journal_length == TASKS
        storage, log = outcome(vv)
        assert storage["count"] == TASKS
        assert len(log) == TASKS + 2 and len(set(log)) == len(log), log  # each line once
        assert (storage, log) == outcome(undisturbed)


# --- b: a ground-station worker killed, Celery messages lost --------------------------------


def waiting(queue: str) -> int:
    """Messages waiting in a Celery queue on the broker (none while nobody declared it)."""
    with app.connection_for_write() as connection:
        try:
            declared = connection.default_channel.queue_declare(queue=queue, passive=True)
        except ChannelError:  # kombu: "no queue ..." (404)
            return 0
        return declared.message_count


def lose(queue: str) -> int:
    """Drop the messages waiting in a queue, as a broker that lost them would; how many."""
    with app.connection_for_write() as connection:
        return connection.default_channel.queue_purge(queue) or 0


def node(kind: str, pk: int) -> str:
    """The Celery node name of a host's worker (vvm_worker/management/commands)."""
    return f"{kind}{pk}@{socket.gethostname()}"


def set_consuming(name: str, queue: str, consume: bool) -> None:
    """Tell a running worker to stop (or go on) taking messages from a queue; it goes on
    with everything else. Asked again until it answers (it may still be starting)."""
    command = app.control.add_consumer if consume else app.control.cancel_consumer

    def answered() -> bool:
        return bool(command(queue, destination=[name], reply=True, timeout=1.0, limit=1))

    wait_until(answered, timeout=30, what=f"{name} to answer about {queue}")


def test_a_killed_gs_worker_and_lost_messages_leave_no_vv_behind(workers) -> None:
    gs = GroundStationFactory(name="GS Base")
    heli_one = VehicleFactory(name="Heli One", area=AREA_ONE)
    heli_two = VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lat=48.11, depot_lng=12.865)
    customer = CustomerFactory(name="Customer A", max_parallel_vvs=1)
    queues = [gs_queue(gs.pk), rv_queue(heli_one.pk), rv_queue(heli_two.pk), SHARED_QUEUE]
    for queue in queues:  # what earlier tests left on the broker is not this test's to lose
        lose(queue)
    workers.start("gsworker", "GS Base")
    gs_worker = node("gs", gs.pk)
    set_consuming(gs_worker, gs_queue(gs.pk), False)

    # First is admitted on GS Base, and the word that it is there is lost: the ground
    # station's sweep takes it up. With no RV online, it waits there; Second and Third queue.
    vvm = platform_vvm()
    first, second, third = (
        vv_submit(customer=customer, name=name, program=TWO_AREAS, vvm=vvm)
        for name in ("First", "Second", "Third")
    )
    assert [v.status for v in (first, second, third)] == ["running", "queued", "queued"]
    assert lose(gs_queue(gs.pk)) > 0
    wait_until(
        lambda: VirtualVehicle.objects.filter(
            pk=first.pk, host_gs=gs, pending__isnull=False
        ).exists(),
        what="GS Base's sweep to take First up (it then waits for an RV)",
        details=workers.logs,
    )

    # The ground station's worker dies. The RVs come online and send it word to route First
    # again: nobody takes it, and it is lost too.
    workers.kill("GS Base")
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    wait_until(lambda: waiting(gs_queue(gs.pk)) > 0, what="word for GS Base", details=workers.logs)
    assert lose(gs_queue(gs.pk)) > 0

    # The ground station's worker comes back and takes First up; the word that moves First
    # from Heli One to Heli Two is lost.
    set_consuming(node("rv", heli_two.pk), rv_queue(heli_two.pk), False)
    workers.start("gsworker", "GS Base")
    running = dict(workers.processes)
    wait_until(
        lambda: (
            VirtualVehicle.objects.filter(
                pk=first.pk, host_rv=heli_two, status=VVStatus.MIGRATING
            ).exists()
            and waiting(rv_queue(heli_two.pk)) > 0
        ),
        what="First migrating to Heli Two",
        details=workers.logs,
    )
    set_consuming(gs_worker, SHARED_QUEUE, False)  # and so is the word to admit Second
    assert lose(rv_queue(heli_two.pk)) > 0
    set_consuming(node("rv", heli_two.pk), rv_queue(heli_two.pk), True)

    # Heli Two's sweep finds First, which ends; GS Base's sweep admits Second.
    wait_until(
        lambda: ended(first) and waiting(SHARED_QUEUE) > 0,
        timeout=60,
        what="First to end",
        details=workers.logs,
    )
    assert lose(SHARED_QUEUE) > 0
    set_consuming(gs_worker, SHARED_QUEUE, True)
    wait_until(lambda: ended(first, second, third), what="the VVs to end", details=workers.logs)

    for vv in (first, second, third):
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error
        assert dict(vv.storage.values_list("key", "value")).keys() == {"p0", "p1"}
        assert program_log(vv) == ["done: 2 readings"]
        path = [(m.from_name, m.to_name) for m in Migration.objects.filter(vv=vv).order_by("id")]
        assert path == [("GS Base", "Heli One"), ("Heli One", "Heli Two"), ("Heli Two", "GS Base")]
    # No worker was restarted after the last messages were lost: their sweeps found the work.
    assert workers.processes == running
    assert all(p.poll() is None for p in running.values())


# --- c: two ground-station workers admit one customer's VVs --------------------------------


def test_two_gs_workers_run_one_vv_at_a_time_for_a_customer_allowed_one(workers) -> None:
    GroundStationFactory(name="GS Base")
    GroundStationFactory(name="GS North", lat=48.1145, lng=12.8640)
    VehicleFactory(name="Heli One", area=FIELD)
    customer = CustomerFactory(name="Customer A", max_parallel_vvs=1)
    user = UserFactory(username="customer-a", customer=customer)
    workers.start("gsworker", "GS Base")
    workers.start("gsworker", "GS North")
    workers.start("rvworker", "Heli One")

    # Submitted as over the REST API: each submission asks the ground stations, whichever
    # takes the message, to admit the customer's queued VVs.
    vvs = []
    for name in ("One", "Two", "Three"):
        vv, problem = vv_create_for_user(
            user=user, name=name, program=THREE_POINTS, vvm=platform_vvm()
        )
        assert problem is None and vv is not None
        vvs.append(vv)
    peak = 0

    def all_ended() -> bool:  # and how many ran at once, each time it looks
        nonlocal peak
        running = VirtualVehicle.objects.filter(customer=customer, status__in=ACTIVE_STATUSES)
        peak = max(peak, running.count())
        return ended(*vvs)

    wait_until(all_ended, what="the VVs to end", details=workers.logs)
    assert peak <= 1, f"{peak} VVs of a customer allowed one ran at once"

    ran = []
    for vv in vvs:
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error
        assert vv.tasks.filter(status=TaskStatus.DONE).count() == 3
        assert program_log(vv) == ["start", "end"]
        ran.append((vv.started_s, vv.finished_s, vv.name))
    # Oldest first, and each one admitted only once the one before had ended.
    ran.sort()
    assert [name for _, _, name in ran] == ["One", "Two", "Three"]
    for (_, finished, _), (started, _, _) in pairwise(ran):
        assert started >= finished
    assert all(p.poll() is None for p in workers.processes.values())
