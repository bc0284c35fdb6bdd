"""One RV worker process hosting several RVs (issue 23): ``manage.py rvworker NAME [NAME ...]``.

A VV that migrates between two RVs of one process keeps its warm V8 context (its next step
reads only the new answer from the journal, and no message goes through the broker); such a
process stopped with SIGTERM mid-mission exits with status 0, and every VV finishes once it is
started again. Run on SQLite and on PostgreSQL (CI's second pass).
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from django.core.management import CommandError, call_command
from django.db import transaction

from fleet.models import GroundStation, Vehicle
from missions.models import Migration, VirtualVehicle, VVStatus
from tests.broker import queued
from tests.factories import (
    AREA_ONE,
    AREA_TWO,
    CustomerFactory,
    GroundStationFactory,
    VehicleFactory,
)
from tests.live import Workers
from tests.polling import wait_until
from tests.vvm_worker.test_distributed import (
    all_ended,
    assert_paper_results,
    load,
    wait_mid_mission,
)
from tests.vvm_worker.test_distributed_faults import (
    TASKS,
    TWO_AREAS,
    counter_program,
    ended,
    outcome,
    visits_logged,
)
from vvm_worker.dispatch import gs_queue, rv_queue
from vvm_worker.hosts import BEACON_KEYFRAME_S, RVHost
from vvm_worker.platform import platform_vvm
from vvm_worker.runtime import StepInput, StepResult
from vvm_worker.services import vv_advance, vv_submit

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True)]

# A task in Heli One's area, then one in Heli Two's: the VV migrates between them.
ACROSS = """
var co2 = VV.sensor.get('CO2');
function at(lng) {
  return {type: 'point', position: new VV.types.LatLngAlt(48.111, lng, 20), tolerance: 2,
          sensors: [co2]};
}
var visits = 0;
VV.task.execute(at(12.861), function (d) { visits += 1; VV.storage.store('one', visits); });
VV.task.execute(at(12.866), function (d) { visits += 1; VV.storage.store('two', visits); });
"""


def _hosted(*, station: bool) -> Iterator[tuple[RVHost, list[StepResult]]]:
    """Heli One and Heli Two hosted by one RV worker's host in this process (instant flights),
    with GS Base too when ``station``, and every step its runtime runs recorded."""
    gs = GroundStationFactory(name="GS Base")
    one = VehicleFactory(name="Heli One", area=AREA_ONE)
    two = VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lng=12.866)
    host = RVHost([one, two], speed=0, station=gs if station else None)
    steps: list[StepResult] = []
    runtime_step = host.vvm.runtime.step

    def step(step: StepInput) -> StepResult:
        result = runtime_step(step)
        steps.append(result)
        return result

    host.vvm.runtime.step = step  # type: ignore[method-assign]
    host.start()
    try:
        yield host, steps
    finally:
        host.stop()


@pytest.fixture
def two_rvs_one_process(broker) -> Iterator[tuple[RVHost, list[StepResult]]]:
    """Heli One and Heli Two in one RV worker's host; GS Base is another process's."""
    yield from _hosted(station=False)


def test_a_vv_migrating_between_two_rvs_of_one_process_resumes_its_warm_context(
    two_rvs_one_process, broker
) -> None:
    host, steps = two_rvs_one_process
    one, two = Vehicle.objects.get(name="Heli One"), Vehicle.objects.get(name="Heli Two")
    assert host.vvm.local_rvs == {one.pk, two.pk}
    assert host.is_vehicle(one.pk) and host.is_vehicle(two.pk)
    CustomerFactory(name="Customer B")
    customer = CustomerFactory(name="Customer A")
    ground = platform_vvm()  # the ground station's side, in another "process" of its own
    vv = vv_submit(customer=customer, name="Across", program=ACROSS, vvm=ground, seed=1)
    vv_advance(vv_id=vv.pk, vvm=ground)  # its first step, routed to Heli One
    vv.refresh_from_db()
    assert vv.host_rv_id == one.pk
    host.advance(vv.pk)  # what the message to rv.<Heli One> makes the worker do

    def ended() -> bool:
        vv.refresh_from_db()
        return vv.is_ended

    wait_until(ended, timeout=60, what="the VV to end")
    assert vv.status == VVStatus.FINISHED, vv.error
    path = list(Migration.objects.filter(vv=vv).values_list("from_name", "to_name"))
    assert path == [("GS Base", "Heli One"), ("Heli One", "Heli Two"), ("Heli Two", "GS Base")]
    # On Heli One the VV came from a ground station: its program ran again from its first
    # line with the one answer of its journal. On Heli Two, in the same process, it resumed
    # where it waited: it read only the new answer.
    assert [(s.replayed, s.answers_read) for s in steps] == [(True, 1), (False, 1)]
    assert {d.key: d.value for d in vv.storage.all()} == {"one": 1, "two": 2}
    # The handover went without a message: nothing waits on Heli Two's queue, while the
    # ground station sent the VV to Heli One's (this test did that worker's part).
    assert queued(broker, rv_queue(two.pk)) == []
    assert ("cpcc.vv_advance", [str(vv.pk)]) in queued(broker, rv_queue(one.pk))


@pytest.fixture
def station_and_two_rvs_one_process(broker) -> Iterator[tuple[RVHost, list[StepResult]]]:
    """GS Base, Heli One and Heli Two in one RV worker's host (``rvworker "Heli One" "Heli Two"
    --station "GS Base"``)."""
    yield from _hosted(station=True)


def test_a_vv_admitted_on_a_station_of_the_rvs_process_keeps_its_warm_context_aboard(
    station_and_two_rvs_one_process, broker
) -> None:
    """The station's work runs on the RVs' host thread: a VV admitted there runs its first
    step in the process's runtime and goes to Heli One, then to Heli Two, and back to the
    station, each time resuming where it waited, without a message."""
    host, steps = station_and_two_rvs_one_process
    station = GroundStation.objects.get(name="GS Base")
    assert host.is_station(station.pk) and not host.is_station(station.pk + 1)
    customer = CustomerFactory(name="Customer A")
    vv = vv_submit(
        customer=customer, name="Across", program=ACROSS, vvm=platform_vvm(), seed=1, admit=False
    )
    host.admit(customer.pk)  # what the admission message on the shared queue makes it do

    def ended() -> bool:
        vv.refresh_from_db()
        return vv.is_ended

    wait_until(ended, timeout=60, what="the VV to end")
    assert vv.status == VVStatus.FINISHED, vv.error
    path = list(Migration.objects.filter(vv=vv).values_list("from_name", "to_name"))
    assert path == [("GS Base", "Heli One"), ("Heli One", "Heli Two"), ("Heli Two", "GS Base")]
    # Its first step, on the station, ran the program from its first line in a new context
    # (no answer yet); aboard Heli One, then Heli Two, it resumed where it waited, reading
    # only the new answer (where a station of another process leaves Heli One to replay).
    assert [(s.replayed, s.answers_read) for s in steps] == [(True, 0), (False, 1), (False, 1)]
    assert {d.key: d.value for d in vv.storage.all()} == {"one": 1, "two": 2}
    # Nothing went through the broker: the station and both RVs are this process's.
    for queue in (gs_queue(station.pk), rv_queue(Vehicle.objects.get(name="Heli One").pk)):
        assert queued(broker, queue) == []


def test_rvworker_names_every_unknown_vehicle_and_the_known_ones() -> None:
    VehicleFactory(name="Heli One")
    VehicleFactory(name="Heli Two")
    with pytest.raises(CommandError) as refused:
        call_command("rvworker", "Heli One", "Heli Three", "Heli Four")
    assert str(refused.value) == (
        "no vehicles named 'Heli Three', 'Heli Four' (vehicles: Heli One, Heli Two)"
    )
    with pytest.raises(CommandError, match="no vehicle named 'Nope' \\(vehicles: Heli One"):
        call_command("rvworker", "Nope")
    with pytest.raises(CommandError, match="named more than once: 'Heli One'"):
        call_command("rvworker", "Heli One", "Heli Two", "Heli One")


def test_rvworker_names_an_unknown_station_and_the_known_ones() -> None:
    VehicleFactory(name="Heli One")
    GroundStationFactory(name="GS Base")
    with pytest.raises(CommandError) as refused:
        call_command("rvworker", "Heli One", "--station", "GS Nowhere")
    assert str(refused.value) == ("no ground station named 'GS Nowhere' (ground stations: GS Base)")


@pytest.mark.slow
def test_a_worker_of_several_rvs_stopped_with_sigterm_mid_mission_exits_0_and_its_vvs_finish(
    workers: Workers, tmp_path: Path, monkeypatch
) -> None:
    """The paper's Figure 3 (each VV flies with Heli One, then with Heli Two) with both RVs in
    one process: stopped by SIGTERM mid-mission, then started again."""
    load("paper-fig3.json", tmp_path, monkeypatch)
    workers.start("rvworker", "Heli One", "Heli Two")
    wait_until(
        lambda: not Vehicle.objects.filter(worker_seen__isnull=True).exists(),
        timeout=60,
        what="both RVs to report",
        details=workers.logs,
    )
    workers.start("gsworker", "GS Base")
    wait_mid_mission(workers)
    status = workers.terminate("Heli One")
    logs = workers.logs()
    assert status == 0, logs
    assert "Fatal Python error" not in logs
    assert not all_ended(), "the mission ended before the stop: it tested nothing"
    workers.start("rvworker", "Heli One", "Heli Two")
    wait_until(
        all_ended, timeout=180, what="the VVs to end after the restart", details=workers.logs
    )
    assert_paper_results()
    for vv in VirtualVehicle.objects.all():
        path = [(m.from_name, m.to_name) for m in Migration.objects.filter(vv=vv)]
        assert ("Heli One", "Heli Two") in path, path
    assert {v.name: v.tasks_done for v in Vehicle.objects.all()} == {"Heli One": 6, "Heli Two": 6}
    assert workers.terminate("Heli One") == 0
    assert workers.terminate("GS Base") == 0


def test_a_worker_of_rvs_and_their_station_stopped_with_sigterm_mid_mission_exits_0_and_resumes(
    workers: Workers, tmp_path: Path, monkeypatch
) -> None:
    """Figure 3 with both RVs and the ground station in one process (``rvworker --station``):
    the station admits the VVs and hands them to its RVs in the process; stopped by SIGTERM
    mid-mission, the process exits 0, and started again it takes up the station's VVs and
    its RVs' and finishes the mission."""
    load("paper-fig3.json", tmp_path, monkeypatch)
    combined = ("rvworker", "Heli One", "Heli Two")
    workers.start(*combined, options=["--station", "GS Base"])
    wait_mid_mission(workers)
    status = workers.terminate("Heli One")
    logs = workers.logs()
    assert status == 0, logs
    assert "Fatal Python error" not in logs
    assert not all_ended(), "the mission ended before the stop: it tested nothing"
    workers.start(*combined, options=["--station", "GS Base"])
    wait_until(
        all_ended, timeout=180, what="the VVs to end after the restart", details=workers.logs
    )
    assert_paper_results()
    for vv in VirtualVehicle.objects.all():
        path = [(m.from_name, m.to_name) for m in Migration.objects.filter(vv=vv)]
        assert path[0] == ("GS Base", "Heli One") and ("Heli One", "Heli Two") in path, path
        assert path[-1][1] == "GS Base", path
    assert {v.name: v.tasks_done for v in Vehicle.objects.all()} == {"Heli One": 6, "Heli Two": 6}
    assert workers.terminate("Heli One") == 0


@pytest.mark.slow
def test_a_worker_of_several_rvs_stopped_with_sigterm_in_the_middle_of_steps_exits_0(
    broker_url, tmp_path
) -> None:
    """Instant flights and steps that compute for a while, VVs of both RVs and VVs moving
    between them: the stop comes while V8 runs, three times; nothing is done twice."""
    GroundStationFactory(name="GS Base")
    VehicleFactory(name="Heli One", area=AREA_ONE)
    VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lng=12.866)
    customers = [CustomerFactory(name="Customer A"), CustomerFactory(name="Customer B")]
    vvm = platform_vvm()
    counters = [
        vv_submit(customer=c, name=f"Counter {k}", program=counter_program(), vvm=vvm, seed=k)
        for c in customers
        for k in range(2)
    ]
    across = [
        vv_submit(customer=c, name="Across", program=TWO_AREAS, vvm=vvm, seed=7) for c in customers
    ]
    vvs = counters + across
    pool = Workers(tmp_path, broker_url, speed=0)
    try:
        pool.start("gsworker", "GS Base")
        for stop in range(3):
            logged = visits_logged(counters)
            pool.start("rvworker", "Heli One", "Heli Two")
            # With instant flights the worker steps VVs without a pause: once it has gone on
            # since its start, a stop comes in the middle of its work.
            wait_until(
                lambda logged=logged: visits_logged(counters) > logged or ended(*vvs),
                timeout=60,
                what="the worker of Heli One and Heli Two to go on",
                details=pool.logs,
            )
            assert pool.terminate("Heli One") == 0, (stop, pool.logs())
            assert stop > 0 or not ended(*vvs), (
                "the VVs ended before the stop: it tested nothing",
                [(v.name, v.status, v.error) for v in VirtualVehicle.objects.all()],
                pool.logs()[-3000:],
            )
        pool.start("rvworker", "Heli One", "Heli Two")
        wait_until(lambda: ended(*vvs), timeout=180, what="the VVs to end", details=pool.logs)
        assert pool.terminate("Heli One") == 0
        assert pool.terminate("GS Base") == 0
        logs = pool.logs()
    finally:
        pool.stop_all()
    assert "Fatal Python error" not in logs
    for vv in counters:
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error
        storage, log = outcome(vv)
        assert storage["count"] == TASKS
        assert len([line for line in log if line.startswith("visit ")]) == TASKS, log
    for vv in across:
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error
        assert set(vv.storage.values_list("key", flat=True)) == {"p0", "p1"}
        path = list(Migration.objects.filter(vv=vv).values_list("from_name", "to_name"))
        assert ("Heli One", "Heli Two") in path, path


def test_a_vv_that_waits_for_an_isolate_does_not_hold_up_the_host_thread(
    two_rvs_one_process, broker, monkeypatch
) -> None:
    """A VV without a warm context here needs an isolate: while V8 makes one, the host
    thread goes on with the other VVs and the vehicles' timers (a burst of new VVs used to
    hold up every VV aboard), and the VV goes on once the isolate is there."""
    from vvm_worker.runtime import pool as pool_module

    host, steps = two_rvs_one_process
    customer = CustomerFactory(name="Customer A")
    ground = platform_vvm()
    vv = vv_submit(customer=customer, name="Across", program=ACROSS, vvm=ground, seed=1)
    vv_advance(vv_id=vv.pk, vvm=ground)  # routed to Heli One, in this host's process
    # From here on, isolates are made only when the test says (the station's first step
    # above took one as usual).
    pool = pool_module.IsolatePool(1)  # none prepared yet
    monkeypatch.setattr("vvm_worker.hosts.POOL", pool)
    monkeypatch.setattr("vvm_worker.runtime.context.POOL", pool)
    preparing, made = threading.Event(), threading.Event()
    real = pool_module.prepare

    async def slow() -> pool_module.Prepared:
        preparing.set()
        await asyncio.get_running_loop().run_in_executor(None, made.wait, 60)
        return await real()

    monkeypatch.setattr(pool_module, "prepare", slow)
    advancing = threading.Thread(target=host.advance, args=(vv.pk,))
    advancing.start()
    try:
        assert preparing.wait(30), "no isolate asked for"
        # The host thread is free while the isolate is made.
        assert host.scheduler.submit(lambda: "free").result(10) == "free"
        assert steps == [] and advancing.is_alive()
    finally:
        made.set()
        advancing.join(60)

    def ended() -> bool:
        vv.refresh_from_db()
        return vv.is_ended

    wait_until(ended, timeout=60, what="the VV to end")
    assert vv.status == VVStatus.FINISHED, vv.error
    assert [(s.replayed, s.answers_read) for s in steps] == [(True, 1), (False, 1)]
    assert {d.key: d.value for d in vv.storage.all()} == {"one": 1, "two": 2}


def test_the_map_tick_reads_the_vvs_aboard_after_a_change_here_or_at_a_keyframe(
    two_rvs_one_process, broker
) -> None:
    """An idle worker's map tick reads nothing from the database: it reads the VVs aboard its
    vehicles again once work here changed something (announced it), else every keyframe."""
    host, _ = two_rvs_one_process
    later = host.clock.now_s() + 3600.0  # (the worker's own ticks, before it, read nothing)

    def reads_at(now: float) -> bool:  # asked on the host thread, as the tick asks it
        return host.scheduler.submit(lambda: host._aboard_may_have_changed(now)).result(10)

    def change_here() -> None:
        with transaction.atomic():
            host.vvm.announce(lambda: {"type": "vv", "id": "a change of this process's"})

    assert reads_at(later)  # a keyframe due
    assert not reads_at(later)
    assert not reads_at(later + 1.0)
    host.scheduler.submit(change_here).result(10)  # published after its piece of work
    assert reads_at(later + 1.0)
    assert not reads_at(later + 2.0)
    assert reads_at(later + 1.0 + BEACON_KEYFRAME_S)
