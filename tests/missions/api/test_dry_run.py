"""POST /api/v1/vvs/dry-run/: a program tried against a simulated copy of the fleet, before
anything flies. No worker runs here: the copy is the dry run's own."""

from __future__ import annotations

from pathlib import Path

import pytest
from django.conf import settings

from fleet.models import VehicleStatus
from missions.models import JournalEntry, LogEntry, StorageDocument, Task, VirtualVehicle
from tests.factories import AREA_TWO, VehicleFactory
from vvm_worker.dry_run_places import DryRunPlaces
from vvm_worker.services import dry_run

DRY_RUN = "/api/v1/vvs/dry-run/"

# Two points in Heli One's area (the paper's Figure 3), then one 70 km away.
OUT_OF_AREA = """var co2 = VV.sensor.get('CO2');
var cam = VV.sensor.get('Camera 640x480');
var good = [new VV.types.LatLngAlt(48.1111, 12.8619, 30), new VV.types.LatLngAlt(48.1121, 12.8617, 30)];
for (var n = 0; n < good.length; n++) VV.task.execute({type: 'point', position: good[n], sensors: [co2, cam]}, function (d) { VV.storage.store('p' + n, d); });
VV.log('two done');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(47.5, 11.9, 30), sensors: [co2]});
VV.log('never here');
"""

# Asks for three tasks in a loop.
THREE_TASKS = """var gps = VV.sensor.get('GPS');
for (var i = 0; i < 3; i++) {
  VV.task.execute({position: new VV.types.LatLngAlt(48.111 + i / 1000, 12.861, 30), sensors: [gps]});
}
"""


@pytest.fixture(autouse=True)
def places(monkeypatch) -> DryRunPlaces:
    """This test's own places (what earlier tests' dry runs cost is not counted here)."""
    fresh = DryRunPlaces(dry_run.MAX_RUNNING)
    monkeypatch.setattr(dry_run, "_places", fresh)
    return fresh


@pytest.fixture
def fleet(ground_station, heli_one):
    """GS Base and Heli One (the paper's sensors over AREA_ONE) in service."""
    return heli_one


def _counts() -> dict[str, int]:
    return {
        model.__name__: model.objects.count()
        for model in (VirtualVehicle, Task, StorageDocument, JournalEntry, LogEntry)
    }


def _files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file()] if folder.exists() else []


def _column(program: str, line: int, text: str) -> int:
    return program.splitlines()[line - 1].index(text) + 1


def test_the_dry_run_finds_an_out_of_area_point_before_anything_flies(api_a, fleet) -> None:
    before = _counts()
    response = api_a.post(DRY_RUN, {"name": "survey", "program": OUT_OF_AREA}, format="json")
    assert response.status_code == 200, response.content
    report = response.json()
    tasks = report["tasks"]
    assert [t["position"] for t in tasks] == [
        [48.1111, 12.8619, 30],
        [48.1121, 12.8617, 30],
        [47.5, 11.9, 30],
    ]
    assert [t["servable"] for t in tasks] == [True, True, False]
    assert [t["status"] for t in tasks] == ["done", "done", "rejected"]
    # Each task names the call that asks for it: the loop's for the first two.
    assert [(t["line"], t["column"]) for t in tasks] == [
        (4, _column(OUT_OF_AREA, 4, "execute")),
        (4, _column(OUT_OF_AREA, 4, "execute")),
        (6, _column(OUT_OF_AREA, 6, "execute")),
    ]
    (unservable,) = report["unservable"]
    assert unservable == tasks[2]
    assert "outside every operation area" in unservable["message"]
    assert tasks[0]["sensors"] == ["CO2", "Camera 640x480"]
    # Uncaught, the rejection ends the program where a real run would.
    assert report["status"] == "failed"
    assert (report["error_line"], report["error_column"]) == (6, _column(OUT_OF_AREA, 6, "execute"))
    assert report["log"] == ["two done"]
    assert report["within_quotas"] is True and report["quota"] is None
    # The flights to the two points take time in the copy, and the duration says so, and on
    # what it counts them.
    assert tasks[1]["done_s"] > tasks[0]["done_s"] > 0
    assert report["duration_s"] >= tasks[1]["done_s"]
    assert "on the ground at its depot" in report["assumes"]
    assert report["message_wait_s"] == 0
    # Nothing of it exists on the platform: no VV, task, journal, storage, log, picture.
    assert _counts() == before
    assert _files(Path(settings.MEDIA_ROOT)) == []
    assert "Heli One" not in response.content.decode()


def test_the_quota_verdict_names_the_quota_and_where(api_a, api_b, customer_a, fleet) -> None:
    customer_a.max_tasks_per_vv = 2
    customer_a.save()
    report = api_a.post(DRY_RUN, {"name": "three", "program": THREE_TASKS}, format="json").json()
    assert report["within_quotas"] is False
    assert report["status"] == "killed"
    quota = report["quota"]
    assert quota["quota"] == "tasks" and "more than 2 tasks" in quota["message"]
    assert (quota["line"], quota["column"]) == (3, _column(THREE_TASKS, 3, "execute"))
    assert quota["tasks_before"] == 2 and len(report["tasks"]) == 2
    # Customer B's quota is the default: the same program is fine for B.
    report = api_b.post(DRY_RUN, {"name": "three", "program": THREE_TASKS}, format="json").json()
    assert report["within_quotas"] is True and report["quota"] is None
    assert report["status"] == "finished" and len(report["tasks"]) == 3
    assert all(t["servable"] for t in report["tasks"])


def test_a_wait_for_a_message_is_not_counted_but_said(api_a, fleet) -> None:
    """No other VV runs in a dry run, so no message comes: the program goes on at once, as
    it would after its timeout, and the answer says how long it would have waited."""
    program = (
        "var m = VV.message.receive(600);\n"
        "VV.log(m === null ? 'no message' : 'a message');\n"
        "VV.task.execute({position: new VV.types.LatLngAlt(48.111, 12.861, 30),"
        " sensors: [VV.sensor.get('GPS')]});\n"
    )
    report = api_a.post(DRY_RUN, {"name": "waits", "program": program}, format="json").json()
    assert report["status"] == "finished" and report["log"] == ["no message"]
    assert report["message_wait_s"] == 600
    (task,) = report["tasks"]
    assert task["requested_s"] == 0 and 0 < task["done_s"] == report["duration_s"] < 600
    assert "a wait for one is not counted" in report["assumes"]


def test_only_vehicles_in_service_serve_in_the_copy(api_a, fleet) -> None:
    """A point only a vehicle in maintenance covers is one no vehicle could serve now."""
    VehicleFactory(name="Heli Two", area=AREA_TWO, status=VehicleStatus.MAINTENANCE)
    program = (
        "VV.task.execute({position: new VV.types.LatLngAlt(48.111, 12.866, 30),"
        " sensors: [VV.sensor.get('GPS')]});"
    )
    report = api_a.post(DRY_RUN, {"name": "east", "program": program}, format="json").json()
    (task,) = report["unservable"]
    assert (task["line"], task["column"]) == (1, _column(program, 1, "execute"))
    assert "Heli Two" not in str(report)


def test_a_syntax_error_is_refused_as_a_submission_is(api_a) -> None:
    before = _counts()
    program = "var a = 1;\nvar b = ;\n"
    dry = api_a.post(DRY_RUN, {"name": "bad", "program": program}, format="json")
    submitted = api_a.post("/api/v1/vvs/", {"name": "bad", "program": program}, format="json")
    assert dry.status_code == submitted.status_code == 400
    assert dry.json() == submitted.json()
    assert dry.json()["error"] == {
        "message": "SyntaxError: Unexpected token ';'",
        "line": 2,
        "column": 9,
    }
    assert _counts() == before


def test_bad_requests_say_what_is_wrong(api_a, api_staff, fleet) -> None:
    response = api_a.post(DRY_RUN, {"name": "x"}, format="json")
    assert response.status_code == 400
    assert response.json()["detail"] == "program: This field is required."
    response = api_a.post(DRY_RUN, {"name": "a\u202eb", "program": "VV.log(1);"}, format="json")
    assert response.status_code == 400 and response.json()["detail"].startswith("name: ")
    # Staff own no VVs: nothing to try on their behalf.
    response = api_staff.post(DRY_RUN, {"name": "x", "program": "VV.log(1);"}, format="json")
    assert response.status_code == 403


def test_a_program_that_never_stops_is_stopped_by_its_cpu_quota(api_a, customer_a, fleet) -> None:
    customer_a.cpu_ms_per_step = 200
    customer_a.save()
    program = "VV.log('start');\nwhile (true) {}\n"
    report = api_a.post(DRY_RUN, {"name": "spin", "program": program}, format="json").json()
    assert report["status"] == "killed"
    assert report["quota"]["quota"] == "cpu"
    assert report["within_quotas"] is False


def test_without_a_ground_station_no_vv_could_start(api_a, heli_one) -> None:
    response = api_a.post(DRY_RUN, {"name": "x", "program": THREE_TASKS}, format="json")
    assert response.status_code == 409
    assert "no ground station" in response.json()["detail"]


def test_a_server_running_its_most_dry_runs_says_when_to_come_back(
    api_a, fleet, places, monkeypatch
) -> None:
    monkeypatch.setattr(dry_run, "WAIT_FOR_PLACE_S", 0.1)
    for other in ("other customer 1", "other customer 2"):
        places.take(other, wait_s=0, cpu_budget_s=60, window_s=600)
    response = api_a.post(DRY_RUN, {"name": "x", "program": THREE_TASKS}, format="json")
    assert response.status_code == 429
    assert response["Retry-After"] == "5"
    assert "2 dry runs are running on this server already" in response.json()["detail"]


def test_one_customer_runs_one_dry_run_at_a_time_and_the_next_customer_gets_a_place(
    api_a, api_b, customer_a, fleet, places
) -> None:
    # Customer A's dry run is running (as if a long one were under way): A's next waits for
    # it, B, another customer, is not refused because of A.
    places.take(customer_a.pk, wait_s=0, cpu_budget_s=60, window_s=600)
    refused = api_a.post(DRY_RUN, {"name": "x", "program": THREE_TASKS}, format="json")
    assert refused.status_code == 429 and refused["Retry-After"] == "5"
    assert refused.json()["detail"].startswith("A dry run of yours is running already")
    answered = api_b.post(DRY_RUN, {"name": "x", "program": THREE_TASKS}, format="json")
    assert answered.status_code == 200, answered.content
    assert answered.json()["status"] == "finished"


def test_a_customers_dry_runs_have_a_cpu_budget_and_are_told_when_they_may_go_on(
    api_a, api_b, fleet, settings
) -> None:
    settings.CPCC_DRY_RUN_CPU_S = 0.2  # a dry run's process takes some 0.5-1 s of CPU
    settings.CPCC_DRY_RUN_WINDOW_S = 3600.0
    first = api_a.post(DRY_RUN, {"name": "x", "program": THREE_TASKS}, format="json")
    assert first.status_code == 200, first.content

    second = api_a.post(DRY_RUN, {"name": "x", "program": THREE_TASKS}, format="json")

    assert second.status_code == 429
    detail = second.json()["detail"]
    assert detail.startswith("Your dry runs used ") and "of CPU in the last 3600 s" in detail
    assert 3500 <= int(second["Retry-After"]) <= 3600
    # The budget is the customer's: another customer's dry run goes on.
    assert (
        api_b.post(DRY_RUN, {"name": "x", "program": THREE_TASKS}, format="json").status_code == 200
    )
