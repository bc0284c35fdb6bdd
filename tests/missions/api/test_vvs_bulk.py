"""POST /api/v1/vvs/ with a JSON list: several VVs in one request and one transaction, each
item answered as a single submission would be (DESIGN.md section 9)."""

from __future__ import annotations

from rest_framework.test import APIClient

from missions.models import VirtualVehicle, VVStatus
from tests.broker import queued
from tests.missions.api.test_vvs import PROGRAM
from vvm_worker.dispatch import SHARED_QUEUE
from vvm_worker.services import MAX_SUBMISSIONS

URL = "/api/v1/vvs/"
BROKEN = "var a = 1;\nvar b = ;\n"  # line 2, column 9


def items(*names: str) -> list[dict[str, str]]:
    return [{"name": name, "program": PROGRAM} for name in names]


def test_a_list_answers_a_list_of_vvs_in_order_each_as_one_submission_would(
    api_a, api_b, customer_a
) -> None:
    single = api_a.post(URL, {"name": "alone", "program": PROGRAM}, format="json")
    assert single.status_code == 201
    response = api_a.post(URL, items("a", "b", "c"), format="json")
    assert response.status_code == 201, response.content
    answered = response.json()
    assert [vv["name"] for vv in answered] == ["a", "b", "c"]
    for vv in answered:
        assert set(vv) == set(single.json())
        assert (vv["status"], vv["tasks_done"], vv["tasks_open"]) == ("queued", 0, 0)
        assert api_a.get(f"{URL}{vv['id']}/").json() == vv
        # Another customer's VV is not found, as always.
        assert api_b.get(f"{URL}{vv['id']}/").status_code == 404
    stored = VirtualVehicle.objects.filter(pk__in=[vv["id"] for vv in answered])
    assert {(vv.customer_id, vv.status) for vv in stored} == {(customer_a.pk, VVStatus.QUEUED)}
    assert api_b.get(URL).json()["results"] == []


def test_a_list_asks_the_workers_to_admit_once_it_is_committed(
    api_a, customer_a, broker, django_capture_on_commit_callbacks
) -> None:
    with django_capture_on_commit_callbacks(execute=True):
        assert api_a.post(URL, items("a", "b", "c"), format="json").status_code == 201
        assert queued(broker, SHARED_QUEUE) == [], "nothing is sent before the commit"
    assert queued(broker, SHARED_QUEUE) == [("cpcc.admit", [customer_a.pk])]


def test_one_refused_item_refuses_the_list_naming_each_item_and_creates_nothing(
    api_a, django_capture_on_commit_callbacks
) -> None:
    single = api_a.post(URL, {"name": "bad", "program": BROKEN}, format="json").json()
    body = [
        {"name": "fine", "program": PROGRAM},
        {"name": "bad", "program": BROKEN},
        {"name": "nothing"},
        "not an object",
        {"name": 7, "program": PROGRAM},
        None,
    ]
    with django_capture_on_commit_callbacks(execute=True) as callbacks:
        response = api_a.post(URL, body, format="json")
    assert response.status_code == 400
    answer = response.json()
    assert answer["detail"] == (
        "item 2: program: This field is required. (and 3 more item(s)). Nothing was "
        "submitted: correct the items that 'errors' names and send the list again."
    )
    errors = answer["errors"]
    assert len(errors) == len(body)
    assert errors[0] == {}
    assert errors[2] == {
        "detail": "program: This field is required.",
        "program": ["This field is required."],
    }
    assert errors[3]["non_field_errors"] == ["Invalid data. Expected a dictionary, but got str."]
    assert errors[4]["name"] == ["Expected a string, got int: 7."]
    assert errors[5]["non_field_errors"] == ["This field may not be null."]
    # Checked after the fields: the program's syntax, once these are fixed.
    assert errors[1] == {}
    body = [body[0], body[1]]
    response = api_a.post(URL, body, format="json")
    assert response.status_code == 400
    errors = response.json()["errors"]
    assert errors == [{}, single]  # the body of the single submission, line and column
    assert errors[1]["error"] == {
        "message": "SyntaxError: Unexpected token ';'",
        "line": 2,
        "column": 9,
    }
    assert response.json()["detail"].startswith(
        "item 1: program: line 2, column 9: SyntaxError: Unexpected token ';'. Nothing was"
    )
    assert not VirtualVehicle.objects.exists()
    assert callbacks == [], "nothing to admit"


def test_the_queue_quota_counts_the_whole_list(api_a, api_b, customer_a) -> None:
    customer_a.max_queued_vvs = 3
    customer_a.save()
    assert api_a.post(URL, items("waiting"), format="json").status_code == 201
    refused = api_a.post(URL, items("a", "b", "c"), format="json")
    assert refused.status_code == 429
    assert "Retry-After" not in refused
    detail = refused.json()["detail"]
    assert "Customer A has 1 VV(s) waiting in the queue and may have at most 3" in detail
    assert "so 3 more cannot be submitted now" in detail
    assert VirtualVehicle.objects.filter(customer=customer_a).count() == 1
    assert api_a.post(URL, items("a", "b"), format="json").status_code == 201
    # Customer B's queue is its own.
    assert api_b.post(URL, items("a", "b", "c"), format="json").status_code == 201


def test_an_empty_or_too_long_list_is_refused_saying_how_long_one_may_be(api_a, customer_a) -> None:
    customer_a.max_queued_vvs = MAX_SUBMISSIONS + 1  # not the quota's refusal
    customer_a.save()
    too_long = api_a.post(
        URL, items(*(f"vv {n}" for n in range(MAX_SUBMISSIONS + 1))), format="json"
    )
    assert too_long.status_code == 400
    assert too_long.json() == {
        "detail": f"A list holds 1 to {MAX_SUBMISSIONS} submissions, this one "
        f"{MAX_SUBMISSIONS + 1}: send them in several requests of at most {MAX_SUBMISSIONS}."
    }
    empty = api_a.post(URL, [], format="json")
    assert empty.status_code == 400
    assert empty.json()["detail"].startswith(f"A list holds 1 to {MAX_SUBMISSIONS} submissions")
    assert not VirtualVehicle.objects.exists()
    full = api_a.post(URL, items(*(f"vv {n}" for n in range(MAX_SUBMISSIONS))), format="json")
    assert full.status_code == 201
    assert len(full.json()) == MAX_SUBMISSIONS


def test_staff_of_no_customer_cannot_submit_a_list(api_staff) -> None:
    response = api_staff.post(URL, items("a"), format="json")
    assert response.status_code == 403
    assert response.json()["detail"] == "Only a customer's users can submit VVs."


def test_anonymous_callers_cannot_submit_a_list(db) -> None:
    assert APIClient().post(URL, items("a"), format="json").status_code in (401, 403)


def test_the_openapi_schema_describes_both_forms(api_a) -> None:
    schema = api_a.get("/api/schema/", HTTP_ACCEPT="application/vnd.oai.openapi+json").json()
    post = schema["paths"]["/api/v1/vvs/"]["post"]
    body = post["requestBody"]["content"]["application/json"]["schema"]
    assert body == {"$ref": "#/components/schemas/VVSubmission"}
    assert schema["components"]["schemas"]["VVSubmission"]["oneOf"] == [
        {"$ref": "#/components/schemas/VVCreate"},
        {
            "type": "array",
            "items": {"$ref": "#/components/schemas/VVCreate"},
            "minItems": 1,  # an empty list is refused (400): the schema says so
            "maxItems": MAX_SUBMISSIONS,
        },
    ]
    answer = post["responses"]["201"]["content"]["application/json"]["schema"]
    assert answer == {"$ref": "#/components/schemas/VVSubmitted"}
    assert schema["components"]["schemas"]["VVSubmitted"]["oneOf"] == [
        {"$ref": "#/components/schemas/VV"},
        {"type": "array", "items": {"$ref": "#/components/schemas/VV"}},
    ]
    assert f"a list of 1 to {MAX_SUBMISSIONS}" in post["description"]
