"""One depth limit for the JSON customers send: the REST API's parser, the editor's check and
the values a VV stores refuse anything nested more than 100 levels with a 400 that says so,
never a server error."""

from __future__ import annotations

import json

import pytest
from django.urls import reverse

from cpcc_site import json_depth
from cpcc_site.json_depth import MAX_VALUE_DEPTH
from missions.models import VirtualVehicle
from vvm_worker.services import values


def nested(levels: int, inner: object = 1) -> object:
    value = inner
    for n in range(levels):
        value = [value] if n % 2 else {"k": value}
    return value


def deep_text(levels: int) -> str:
    return "[" * levels + "]" * levels


def test_the_services_and_the_parsers_share_one_limit() -> None:
    assert values.MAX_VALUE_DEPTH is MAX_VALUE_DEPTH == 100
    assert json_depth.loads(json.dumps(nested(100))) == nested(100)
    for text in (json.dumps(nested(101)), deep_text(5_000), deep_text(1_000_000)):
        with pytest.raises(json_depth.TooDeep, match="nested more than 100 levels"):
            json_depth.loads(text)
    with pytest.raises(ValueError, match="Expecting"):
        json_depth.loads("[1,")


@pytest.mark.parametrize("levels", [101, 5_000, 500_000])
def test_an_api_body_nested_too_deep_is_a_400_that_says_so(api_a, api_b, levels) -> None:
    for api in (api_a, api_b):  # by token, by session
        response = api.post("/api/v1/vvs/", deep_text(levels), content_type="application/json")
        assert response.status_code == 400
        assert response["Content-Type"] == "application/json"
        assert "nested more than 100 levels" in response.json()["detail"]
    assert not VirtualVehicle.objects.exists()


def test_a_body_100_levels_deep_is_parsed_and_judged_on_its_fields(api_a) -> None:
    body = json.dumps({"name": nested(99), "program": "var a;"})
    response = api_a.post("/api/v1/vvs/", body, content_type="application/json")
    assert response.status_code == 400
    assert response.json()["detail"].startswith("name: Expected a string, got dict")


def test_every_api_endpoint_that_reads_a_body_has_the_limit(api_staff, customer_a) -> None:
    response = api_staff.patch(
        f"/api/v1/customers/{customer_a.pk}/",
        json.dumps({"allowed_api_calls": nested(200)}),
        content_type="application/json",
    )
    assert response.status_code == 400
    assert "nested more than 100 levels" in response.json()["detail"]


def test_the_editors_check_refuses_a_body_nested_too_deep(client, user_a, user_b) -> None:
    for user in (user_a, user_b):
        client.force_login(user)
        for text in (json.dumps({"program": nested(101)}), deep_text(5_000)):
            response = client.post(reverse("vv-check"), text, content_type="application/json")
            assert response.status_code == 400
            assert "nested more than 100 levels" in response.json()["detail"]
