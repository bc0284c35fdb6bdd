"""The distributed platform: a Celery worker per GS and per RV, in processes of their own."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from django.core.management import call_command

from fleet.models import Vehicle, VehicleStatus
from missions.models import JournalEntry, Migration, Task, TaskStatus, VirtualVehicle, VVStatus
from tests.conftest import SCENARIOS
from tests.factories import VehicleFactory
from tests.live import wait_for
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vehicle_set_status

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

KEYS = {f"p{n}.{k}" for n in range(4) for k in range(3)}
FIELD = [[48.109, 12.859], [48.109, 12.868], [48.114, 12.868], [48.114, 12.859], [48.109, 12.859]]


def load(data_or_name: dict | str, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("CPCC_SCENARIO_PASSWORD", "pass-word-1")
    if isinstance(data_or_name, str):
        call_command("loadscenario", str(SCENARIOS / data_or_name))
        return
    path = tmp_path / "scenario.json"
    for vv in data_or_name["vvs"]:
        vv["program"] = str(SCENARIOS / vv["program"])
    path.write_text(json.dumps(data_or_name))
    call_command("loadscenario", str(path))


def all_ended() -> bool:
    return not VirtualVehicle.objects.exclude(
        status__in=[VVStatus.FINISHED, VVStatus.FAILED, VVStatus.KILLED, VVStatus.CANCELLED]
    ).exists()


def assert_paper_results() -> None:
    for vv in VirtualVehicle.objects.all():
        assert vv.status == VVStatus.FINISHED, (vv.name, vv.error)
        assert set(vv.storage.values_list("key", flat=True)) == KEYS
        assert vv.tasks.count() == 4 and vv.tasks.filter(status=TaskStatus.DONE).count() == 4
        assert JournalEntry.objects.filter(vv=vv).count() == 4


def test_figure_3_through_separate_gs_and_rv_workers(workers, tmp_path, monkeypatch) -> None:
    load("paper-fig3.json", tmp_path, monkeypatch)
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    wait_for(all_ended, timeout=120, what="the three VVs to end", details=workers.logs)
    assert_paper_results()
    for vv in VirtualVehicle.objects.all():
        path = [(m.from_name, m.to_name) for m in Migration.objects.filter(vv=vv)]
        assert path == [("GS Base", "Heli One"), ("Heli One", "Heli Two"), ("Heli Two", "GS Base")]
    assert {v.name: v.tasks_done for v in Vehicle.objects.all()} == {"Heli One": 6, "Heli Two": 6}


def test_an_rv_worker_killed_mid_mission_loses_nothing_when_it_comes_back(
    workers, tmp_path, monkeypatch
) -> None:
    load("paper-fig2.json", tmp_path, monkeypatch)
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    wait_for(
        lambda: Task.objects.filter(status=TaskStatus.DONE).count() >= 3,
        timeout=120,
        what="three tasks done",
        details=workers.logs,
    )
    workers.kill("Heli One")
    done_before = Task.objects.filter(status=TaskStatus.DONE).count()
    assert done_before < 12 and not all_ended()
    workers.start("rvworker", "Heli One")
    wait_for(all_ended, timeout=180, what="the VVs to end after the restart", details=workers.logs)
    assert_paper_results()
    assert Vehicle.objects.get(name="Heli One").tasks_done == 12


def test_an_rv_removed_mid_mission_hands_its_vvs_to_the_other(
    workers, tmp_path, monkeypatch
) -> None:
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    other = dict(data["vehicles"][0], name="Heli Two", depot=[48.1100, 12.8650, 0])
    data["vehicles"].append(other)
    load(data, tmp_path, monkeypatch)
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    wait_for(
        lambda: (
            VirtualVehicle.objects.filter(host_rv__isnull=False).exists()
            and Task.objects.filter(status=TaskStatus.DONE).exists()
        ),
        timeout=120,
        what="a VV aboard an RV and a task done",
        details=workers.logs,
    )
    busy = Vehicle.objects.filter(vvs__isnull=False).distinct().first()
    assert busy is not None
    vehicle_set_status(vehicle=busy, status=VehicleStatus.REMOVED, vvm=platform_vvm())
    removed_at = Task.objects.filter(status=TaskStatus.DONE).count()
    wait_for(all_ended, timeout=180, what="the VVs to end", details=workers.logs)
    assert_paper_results()
    later = Task.objects.filter(status=TaskStatus.DONE).order_by("done_s")[removed_at:]
    assert later
    assert busy.name not in {t.vehicle.name for t in later}


def test_an_rv_added_mid_mission_takes_over_work_in_its_area(
    workers, tmp_path, monkeypatch
) -> None:
    data = json.loads((SCENARIOS / "paper-fig3.json").read_text())
    heli_two = data["vehicles"].pop(1)
    data["vehicles"][0]["area"] = FIELD  # Heli One alone covers the whole field at first
    load(data, tmp_path, monkeypatch)
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    wait_for(
        lambda: Task.objects.filter(status=TaskStatus.DONE).count() >= 2,
        timeout=120,
        what="two tasks done",
        details=workers.logs,
    )
    # The provider adds Heli Two and starts its worker.
    VehicleFactory(
        name="Heli Two",
        area=heli_two["area"],
        depot_lat=heli_two["depot"][0],
        depot_lng=heli_two["depot"][1],
    )
    workers.start("rvworker", "Heli Two")
    wait_for(all_ended, timeout=180, what="the VVs to end", details=workers.logs)
    assert_paper_results()
    served = Task.objects.filter(vehicle__name="Heli Two", status=TaskStatus.DONE)
    assert served.exists()
    assert all(t.lng >= 12.864 for t in served)
