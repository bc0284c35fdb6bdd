"""Ids that are not ids: 404 with a JSON body, never a server error."""

from __future__ import annotations

import pytest
from rest_framework.test import APIClient

BAD_VV_IDS = ["not-a-uuid", "-" * 36, "0" * 36, "zzzzzzzz-zzzz-zzzz-zzzz-zzzzzzzzzzzz", "1"]


@pytest.mark.django_db
@pytest.mark.parametrize("vv_id", BAD_VV_IDS)
@pytest.mark.parametrize(
    ("method", "suffix"),
    [("get", ""), ("post", "cancel/"), ("get", "storage/"), ("get", "storage/k/"),
     ("get", "tasks/"), ("get", "log/"), ("get", "results.zip"), ("get", "images/a.png")],
)  # fmt: skip
def test_a_vv_id_that_is_no_uuid_is_not_found(
    api_a: APIClient, vv_id: str, method: str, suffix: str
) -> None:
    response = getattr(api_a, method)(f"/api/v1/vvs/{vv_id}/{suffix}")
    assert response.status_code == 404
    assert response["Content-Type"].startswith("application/json")
    assert response.json()["detail"]


@pytest.mark.django_db
@pytest.mark.parametrize("path", ["vehicles", "ground-stations", "customers"])
@pytest.mark.parametrize("bad_id", ["abc", "1.5", "-1", "99999999999999999999"])
def test_a_fleet_or_customer_id_that_is_no_number_is_not_found(
    api_staff: APIClient, path: str, bad_id: str
) -> None:
    for method in ("get", "patch", "delete"):
        response = getattr(api_staff, method)(f"/api/v1/{path}/{bad_id}/", {}, format="json")
        assert response.status_code == 404, (method, path, bad_id)
        assert response.json()["detail"]


@pytest.mark.django_db
@pytest.mark.parametrize("debug", [True, False])
@pytest.mark.parametrize(
    "path",
    ["/api/v1/customers/0.5/", "/api/v1/vvs/null%2Cnull/log/", "/api/v1/nothing-here/", "/api/"],
)
def test_an_unmatched_api_path_answers_json_whatever_debug_is(
    api_a: APIClient, settings, debug: bool, path: str
) -> None:
    # With DEBUG on, Django's debug page (listing every URL pattern) would answer first.
    settings.DEBUG = debug
    response = api_a.get(path)
    assert response.status_code == 404
    assert response["Content-Type"] == "application/json"
    assert response.json()["detail"].startswith("No API endpoint at /api/")


@pytest.mark.django_db
def test_a_refused_host_under_the_api_answers_json(api_a: APIClient, settings) -> None:
    settings.DEBUG = True
    response = api_a.get("/api/v1/vvs/", HTTP_HOST="evil.example")
    assert response.status_code == 400
    assert response["Content-Type"] == "application/json"
    assert response.json()["detail"].startswith("Bad Request")
