"""The distributed platform: a Celery worker per GS and per RV, in processes of their own."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from django.conf import settings
from django.core.management import call_command

from fleet.models import Vehicle, VehicleStatus
from missions.models import JournalEntry, Migration, Task, TaskStatus, VirtualVehicle, VVStatus
from tests.conftest import SCENARIOS
from tests.factories import VehicleFactory
from tests.live import Workers
from tests.polling import wait_until
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vehicle_set_status

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

KEYS = {f"p{n}.{k}" for n in range(4) for k in range(3)}
FIELD = [[48.109, 12.859], [48.109, 12.868], [48.114, 12.868], [48.114, 12.859], [48.109, 12.859]]


def load(data_or_name: dict | str, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(settings, "CPCC_SCENARIO_PASSWORD", "pass-word-1")
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


def wait_mid_mission(workers: Workers) -> None:
    """Until VVs are aboard the RVs and at least two tasks are done (the workers' logs say
    why, if not)."""
    wait_until(
        lambda: (
            Task.objects.filter(status=TaskStatus.DONE).count() >= 2
            and VirtualVehicle.objects.filter(host_rv__isnull=False).exists()
        ),
        timeout=120,
        what="VVs aboard the RVs, tasks done",
        details=workers.logs,
    )


def assert_paper_results() -> None:
    for vv in VirtualVehicle.objects.all():
        assert vv.status == VVStatus.FINISHED, (vv.name, vv.error)
        assert set(vv.storage.values_list("key", flat=True)) == KEYS
        assert vv.tasks.count() == 4 and vv.tasks.filter(status=TaskStatus.DONE).count() == 4
        assert JournalEntry.objects.filter(vv=vv).count() == 4


def busy_rv_of_two(workers, tmp_path: Path, monkeypatch) -> Vehicle:
    """Figure 2 with a second RV over the same field, both workers running: returns the RV
    that carries VVs once a task is done."""
    data = json.loads((SCENARIOS / "paper-fig2.json").read_text())
    data["vehicles"].append(dict(data["vehicles"][0], name="Heli Two", depot=[48.1100, 12.8650, 0]))
    load(data, tmp_path, monkeypatch)
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    wait_until(
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
    return busy


def test_figure_3_through_separate_gs_and_rv_workers(workers, tmp_path, monkeypatch) -> None:
    load("paper-fig3.json", tmp_path, monkeypatch)
    # Both RVs in service before the VVs start: the paper's path presumes it (an RV whose
    # worker has not reported yet counts as away, and its VVs would wait on the GS).
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    wait_until(
        lambda: not Vehicle.objects.filter(worker_seen__isnull=True).exists(),
        timeout=60,
        what="both RV workers to report",
        details=workers.logs,
    )
    workers.start("gsworker", "GS Base")
    wait_until(all_ended, timeout=120, what="the three VVs to end", details=workers.logs)
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
    wait_until(
        lambda: Task.objects.filter(status=TaskStatus.DONE).count() >= 3,
        timeout=120,
        what="three tasks done",
        details=workers.logs,
    )
    workers.kill("Heli One")
    done_before = Task.objects.filter(status=TaskStatus.DONE).count()
    assert done_before < 12 and not all_ended()
    workers.start("rvworker", "Heli One")
    wait_until(
        all_ended, timeout=180, what="the VVs to end after the restart", details=workers.logs
    )
    assert_paper_results()
    assert Vehicle.objects.get(name="Heli One").tasks_done == 12


def test_an_rv_removed_mid_mission_hands_its_vvs_to_the_other(
    workers, tmp_path, monkeypatch
) -> None:
    busy = busy_rv_of_two(workers, tmp_path, monkeypatch)
    vehicle_set_status(vehicle=busy, status=VehicleStatus.REMOVED, vvm=platform_vvm())
    # The workers' clock is this machine's: a task with a later done_s was read after the
    # removal committed, whichever worker committed first, so the removed RV cannot have read it.
    removed_s = time.time()
    wait_until(all_ended, timeout=180, what="the VVs to end", details=workers.logs)
    assert_paper_results()
    later = Task.objects.filter(status=TaskStatus.DONE, done_s__gt=removed_s)
    assert later.exists(), "the removal came after the last task: it tested nothing"
    assert set(later.values_list("vehicle__name", flat=True)) == {"Heli One", "Heli Two"} - {
        busy.name
    }


def test_an_rv_added_mid_mission_takes_over_work_in_its_area(
    workers, tmp_path, monkeypatch
) -> None:
    data = json.loads((SCENARIOS / "paper-fig3.json").read_text())
    heli_two = data["vehicles"].pop(1)
    data["vehicles"][0]["area"] = FIELD  # Heli One alone covers the whole field at first
    # ... slowly, so that a task in Heli Two's area is still waiting for it however long Heli
    # Two's worker takes to start.
    data["vehicles"][0]["max_speed_mps"] = 3.0
    load(data, tmp_path, monkeypatch)
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    wait_until(
        lambda: Task.objects.filter(status=TaskStatus.OPEN, lng__gte=12.864).exists(),
        timeout=120,
        what="a VV asking for a reading in Heli Two's area",
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
    wait_until(all_ended, timeout=180, what="the VVs to end", details=workers.logs)
    assert_paper_results()
    served = Task.objects.filter(vehicle__name="Heli Two", status=TaskStatus.DONE)
    assert served.exists()
    assert all(t.lng >= 12.864 for t in served)


def test_a_vv_submitted_over_rest_by_token_finishes_and_its_results_come_back(
    workers, tmp_path, monkeypatch
) -> None:
    import io
    import zipfile

    from rest_framework.authtoken.models import Token
    from rest_framework.test import APIClient

    from accounts.models import User

    load("paper-fig3.json", tmp_path, monkeypatch)
    VirtualVehicle.objects.all().delete()  # only the one submitted over REST
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    client = APIClient()
    token = Token.objects.create(user=User.objects.get(username="customer-a"))
    client.credentials(HTTP_AUTHORIZATION=f"Token {token.key}")
    program = (SCENARIOS.parent / "vv" / "vv1-paper.js").read_text()
    created = client.post("/api/v1/vvs/", {"name": "over REST", "program": program}, format="json")
    assert created.status_code == 201, created.content
    vv_id = created.json()["id"]
    wait_until(all_ended, timeout=120, what="the VV to end", details=workers.logs)
    detail = client.get(f"/api/v1/vvs/{vv_id}/").json()
    assert detail["status"] == "finished" and detail["tasks_done"] == 4
    storage = client.get(f"/api/v1/vvs/{vv_id}/storage/").json()
    assert {d["key"] for d in storage["results"]} == KEYS
    camera = next(d for d in storage["results"] if d["key"] == "p0.2")
    image = client.get(camera["value"]["image_url"])
    assert image.status_code == 200 and image["Content-Type"] == "image/png"
    archive = client.get(f"/api/v1/vvs/{vv_id}/results.zip")
    assert archive.status_code == 200
    with zipfile.ZipFile(
        io.BytesIO(b"".join(archive.streaming_content if archive.streaming else [archive.content]))
    ) as z:
        names = z.namelist()
        assert {"vv.json", "storage.json", "tasks.json", "log.txt"} <= set(names)
        assert len([n for n in names if n.startswith("images/")]) == 4
        assert set(json.loads(z.read("storage.json"))) == KEYS
    other = APIClient()
    other.force_authenticate(User.objects.get(username="customer-b"))
    for path in ("", "storage/", "results.zip", "tasks/", "log/"):
        assert other.get(f"/api/v1/vvs/{vv_id}/{path}").status_code == 404


def test_the_vvs_of_an_rv_worker_that_never_comes_back_move_on_when_its_lease_expires(
    workers, tmp_path, monkeypatch
) -> None:
    busy = busy_rv_of_two(workers, tmp_path, monkeypatch)
    workers.kill(busy.name)
    killed_at = Task.objects.filter(status=TaskStatus.DONE, vehicle=busy).count()
    wait_until(all_ended, timeout=180, what="the VVs to end on the other RV", details=workers.logs)
    assert_paper_results()
    assert Task.objects.filter(status=TaskStatus.DONE, vehicle=busy).count() == killed_at
    assert Migration.objects.filter(reason="its vehicle's worker stopped reporting").exists()
