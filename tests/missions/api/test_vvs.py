"""POST/GET /api/v1/vvs/: submitting programs and reading one's own VVs."""

from __future__ import annotations

from rest_framework.test import APIClient

from missions.models import VirtualVehicle, VVStatus
from tests.broker import queued
from vvm_worker.dispatch import SHARED_QUEUE

PROGRAM = "var gps = VV.sensor.get('GPS');\nVV.log('hello');\n"


def test_a_customer_submits_a_program_by_token(api_a, customer_a) -> None:
    response = api_a.post("/api/v1/vvs/", {"name": "first", "program": PROGRAM}, format="json")
    assert response.status_code == 201, response.content
    body = response.json()
    assert body["name"] == "first" and body["status"] == "queued"
    assert {"id", "host", "tasks_done", "tasks_open", "error", "created", "finished"} <= set(body)
    vv = VirtualVehicle.objects.get(pk=body["id"])
    assert vv.customer == customer_a and vv.program == PROGRAM and vv.status == VVStatus.QUEUED


def test_the_workers_are_asked_to_admit_a_new_vv_once_it_is_committed(
    api_a, customer_a, broker, django_capture_on_commit_callbacks
) -> None:
    with django_capture_on_commit_callbacks(execute=True):
        api_a.post("/api/v1/vvs/", {"name": "first", "program": PROGRAM}, format="json")
        assert queued(broker, SHARED_QUEUE) == [], "nothing is sent before the commit"
    assert queued(broker, SHARED_QUEUE) == [("cpcc.admit", [customer_a.pk])]
    with django_capture_on_commit_callbacks(execute=True) as callbacks:
        api_a.post("/api/v1/vvs/", {"name": "bad", "program": "var = ;"}, format="json")
    assert callbacks == [], "nothing to admit for a refused program"
    assert queued(broker, SHARED_QUEUE) == [("cpcc.admit", [customer_a.pk])]


def test_a_program_with_a_syntax_error_is_refused_with_line_and_column(api_a) -> None:
    response = api_a.post(
        "/api/v1/vvs/", {"name": "bad", "program": "var a = 1;\nvar b = ;\n"}, format="json"
    )
    assert response.status_code == 400
    body = response.json()
    assert body["error"] == {"message": "SyntaxError: Unexpected token ';'", "line": 2, "column": 9}
    assert body["program"] == ["line 2, column 9: SyntaxError: Unexpected token ';'"]
    assert not VirtualVehicle.objects.exists()


def test_missing_fields_say_which(api_a) -> None:
    response = api_a.post("/api/v1/vvs/", {"name": "nothing"}, format="json")
    assert response.status_code == 400
    assert response.json() == {
        "detail": "program: This field is required.",
        "program": ["This field is required."],
    }


def test_another_customers_vv_answers_404(api_a, api_b) -> None:
    created = api_a.post("/api/v1/vvs/", {"name": "mine", "program": PROGRAM}, format="json").json()
    assert api_a.get(f"/api/v1/vvs/{created['id']}/").status_code == 200
    assert api_b.get(f"/api/v1/vvs/{created['id']}/").status_code == 404
    assert api_b.get("/api/v1/vvs/").json()["results"] == []
    listed = api_a.get("/api/v1/vvs/?status=queued").json()
    assert [v["name"] for v in listed["results"]] == ["mine"]
    assert api_a.get("/api/v1/vvs/?status=finished").json()["results"] == []


def test_anonymous_callers_are_refused(db) -> None:
    assert APIClient().get("/api/v1/vvs/").status_code in (401, 403)


def test_the_openapi_schema_describes_the_vv_endpoints(api_a) -> None:
    response = api_a.get("/api/schema/", HTTP_ACCEPT="application/vnd.oai.openapi+json")
    assert response.status_code == 200
    assert "/api/v1/vvs/" in response.json()["paths"]


def test_a_name_with_control_or_bidi_characters_is_refused_naming_the_problem(api_a, api_b) -> None:
    for api, name, shown in [
        (api_a, "\x1b[31mred", "a control character (U+001B) at character 1"),
        (api_b, "invoice\u202egpj.exe", "(U+202E RIGHT-TO-LEFT OVERRIDE) at character 8"),
        (api_a, "\u2067rtl\u2069", "(U+2067 RIGHT-TO-LEFT ISOLATE) at character 1"),
        (api_b, "mark\u200e", "(U+200E LEFT-TO-RIGHT MARK) at character 5"),
    ]:
        response = api.post("/api/v1/vvs/", {"name": name, "program": PROGRAM}, format="json")
        assert response.status_code == 400, name
        body = response.json()
        assert body["detail"].startswith("name: The name has ") and shown in body["detail"]
        assert shown in body["name"][0]
    assert not VirtualVehicle.objects.exists()


def test_a_program_longer_than_a_submission_may_be_is_refused_with_400(api_a) -> None:
    too_long = "x" * 1_000_001
    response = api_a.post("/api/v1/vvs/", {"name": "long", "program": too_long}, format="json")
    assert response.status_code == 400
    assert response.json() == {
        "detail": "program: A program has at most 1,000,000 characters: split the work into "
        "several VVs or make the program shorter.",
        "program": [
            "A program has at most 1,000,000 characters: split the work into several VVs or "
            "make the program shorter."
        ],
    }


def test_a_submission_beyond_the_queue_quota_answers_429_for_that_customer(
    api_a, api_b, customer_a
) -> None:
    customer_a.max_queued_vvs = 2
    customer_a.save()
    for n in range(2):  # no ground station: they stay queued
        created = api_a.post("/api/v1/vvs/", {"name": f"q{n}", "program": PROGRAM}, format="json")
        assert created.status_code == 201
    refused = api_a.post("/api/v1/vvs/", {"name": "q2", "program": PROGRAM}, format="json")
    assert refused.status_code == 429
    assert "Retry-After" not in refused  # waiting alone does not help: the message says what does
    detail = refused.json()["detail"]
    assert "Customer A has 2 VV(s) waiting in the queue and may have at most 2" in detail
    assert "cancel some" in detail
    assert VirtualVehicle.objects.filter(customer=customer_a).count() == 2
    # Customer B's queue is its own.
    other = api_b.post("/api/v1/vvs/", {"name": "b", "program": PROGRAM}, format="json")
    assert other.status_code == 201
    # Cancelling one makes room.
    first = VirtualVehicle.objects.get(name="q0")
    assert api_a.post(f"/api/v1/vvs/{first.pk}/cancel/").status_code == 200
    again = api_a.post("/api/v1/vvs/", {"name": "q2", "program": PROGRAM}, format="json")
    assert again.status_code == 201


def test_a_vv_reads_as_its_declared_fields_say_in_one_and_in_a_list(
    api_a, api_staff, customer_a, fleet_one
) -> None:
    # VVSerializer writes its representation out (speed): it must stay what DRF's generic
    # ModelSerializer makes of the declared fields, counts and hosts included.
    from django.utils import timezone
    from rest_framework import serializers

    from missions.api.serializers import VVSerializer
    from missions.models import Task, TaskStatus

    vv = VirtualVehicle.objects.create(
        customer=customer_a,
        name="Seen",
        seed=1,
        start_ms=0,
        submitted_s=0.0,
        program=PROGRAM,
        status=VVStatus.FAILED,
        host_rv=fleet_one,
        error="TypeError: x is not a function",
        error_line=3,
        error_column=7,
        finished=timezone.now(),
    )
    for q, status in enumerate([TaskStatus.DONE, TaskStatus.DONE, TaskStatus.OPEN, "rejected"]):
        Task.objects.create(
            vv=vv, q=q, lat=47.0, lng=13.0, alt=10.0, tolerance_m=1.0, sensors=[], requested_s=q,
            status=status,
        )  # fmt: skip
    for api, host in [(api_a, "vehicle"), (api_staff, fleet_one.name)]:
        request = api.get("/api/v1/vvs/").wsgi_request
        one, listed = api.get(f"/api/v1/vvs/{vv.pk}/").json(), api.get("/api/v1/vvs/").json()
        vv.refresh_from_db()
        generic = serializers.ModelSerializer.to_representation(
            VVSerializer(vv, context={"request": request}), vv
        )
        assert one == listed["results"][0] == dict(generic)
        assert (one["host"], one["tasks_done"], one["tasks_open"]) == (host, 2, 1)


def test_a_list_counts_each_pages_tasks_in_one_statement(api_a, customer_a) -> None:
    from django.db import connection
    from django.test.utils import CaptureQueriesContext

    from missions.models import Task, TaskStatus

    def vv(n: int) -> VirtualVehicle:
        return VirtualVehicle(
            customer=customer_a, name=f"vv {n}", program=PROGRAM, seed=n, start_ms=0,
            submitted_s=0.0,
        )  # fmt: skip

    vvs = VirtualVehicle.objects.bulk_create([vv(n) for n in range(55)])
    Task.objects.bulk_create(
        Task(
            vv=v,
            q=q,
            lat=47.0,
            lng=13.0,
            alt=10.0,
            tolerance_m=1.0,
            sensors=[],
            requested_s=q,
            status=TaskStatus.DONE if q < n % 4 else TaskStatus.OPEN,
        )
        for n, v in enumerate(vvs)
        for q in range(n % 4 + 1)
    )
    expected = {f"vv {n}": (n % 4, 1) for n in range(55)}
    api_a.get("/api/v1/vvs/")  # the token, remembered
    with CaptureQueriesContext(connection) as first:
        page1 = api_a.get("/api/v1/vvs/").json()
    statements = [q["sql"] for q in first.captured_queries]  # (the next request clears them)
    page2 = api_a.get("/api/v1/vvs/?page=2").json()
    seen = {
        v["name"]: (v["tasks_done"], v["tasks_open"]) for v in page1["results"] + page2["results"]
    }
    assert page1["count"] == 55 and len(page1["results"]) == 50 and seen == expected
    # The count, the page, the page's task counts, the places of its queued VVs in their
    # queue (what they wait for): none per VV, none joins every task.
    assert len(statements) == 4, statements


def test_a_list_shows_the_users_vvs_newest_first_of_the_status_asked(
    api_a, api_b, api_staff, customer_a, customer_b
) -> None:
    import datetime as dt

    from django.utils import timezone

    start = timezone.now()
    for n, (customer, status) in enumerate(
        [(customer_a, "queued"), (customer_b, "queued"), (customer_a, "finished"),
         (customer_a, "queued"), (customer_b, "finished")]
    ):  # fmt: skip
        vv = VirtualVehicle.objects.create(
            customer=customer, name=f"vv {n}", program=PROGRAM, seed=n, start_ms=0,
            submitted_s=0.0, status=status,
        )  # fmt: skip
        VirtualVehicle.objects.filter(pk=vv.pk).update(created=start + dt.timedelta(seconds=n))

    def names(api: APIClient, query: str = "") -> tuple[int, list[str]]:
        body = api.get(f"/api/v1/vvs/{query}").json()
        return body["count"], [vv["name"] for vv in body["results"]]

    assert names(api_a) == (3, ["vv 3", "vv 2", "vv 0"])
    assert names(api_a, "?status=queued") == (2, ["vv 3", "vv 0"])
    assert names(api_b, "?status=finished") == (1, ["vv 4"])
    assert names(api_staff) == (5, ["vv 4", "vv 3", "vv 2", "vv 1", "vv 0"])
    assert names(api_staff, "?status=finished") == (2, ["vv 4", "vv 2"])
    assert names(api_a, "?status=failed") == (0, [])
    assert api_a.get("/api/v1/vvs/?page=2").status_code == 404
