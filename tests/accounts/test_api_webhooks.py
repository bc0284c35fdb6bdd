"""Webhooks over the REST API (/api/v1/webhooks/): made with a URL and events, the secret shown
once, loopback and private addresses refused unless the platform allows them, another
customer's webhook not found."""

from __future__ import annotations

import pytest

from accounts.models import Customer, Webhook

pytestmark = pytest.mark.django_db

URL = "/api/v1/webhooks/"
PUBLIC = "http://93.184.215.14/cpcc-hook"  # an address on the internet: no DNS, nothing sent


def test_the_secret_is_in_the_answer_to_the_making_only(api_a, customer_a) -> None:
    made = api_a.post(URL, {"url": PUBLIC, "events": ["vv.finished", "vv.failed"]}, format="json")
    assert made.status_code == 201, made.json()
    body = made.json()
    assert body["url"] == PUBLIC and body["events"] == ["vv.finished", "vv.failed"]
    assert body["secret"].startswith("whsec_") and len(body["secret"]) == 6 + 64
    assert Webhook.objects.get().secret == body["secret"]
    listed = api_a.get(URL).json()["results"]
    assert [w["id"] for w in listed] == [body["id"]] and "secret" not in listed[0]
    assert "secret" not in api_a.get(f"{URL}{body['id']}/").json()
    # The customer's VVs are listened to for these events from now on, and no longer once the
    # webhook is removed.
    assert Customer.objects.get(pk=customer_a.pk).notify_events == ["vv.finished", "vv.failed"]
    assert api_a.delete(f"{URL}{body['id']}/").status_code == 204
    assert Customer.objects.get(pk=customer_a.pk).notify_events == []


@pytest.mark.parametrize(
    ("url", "kind"),
    [
        ("http://127.0.0.1:8000/hook", "127.0.0.1 is a loopback address"),
        ("http://localhost/hook", "localhost (127.0.0.1) is a loopback address"),
        ("https://[::1]/hook", "::1 is a loopback address"),
        ("http://10.1.2.3/hook", "10.1.2.3 is a private address"),
        ("http://192.168.0.10:8080/", "192.168.0.10 is a private address"),
        ("http://169.254.169.254/latest/meta-data/", "169.254.169.254 is a link-local address"),
        ("http://0.0.0.0/", "0.0.0.0 is an unspecified address"),
        ("http://[::ffff:127.0.0.1]/", "::ffff:127.0.0.1 is a loopback address"),
        (
            "http://[2002:7f00:1::]/",
            "2002:7f00:1:: is a 6to4 address of 127.0.0.1, a loopback address",
        ),
    ],
)
def test_loopback_and_private_addresses_are_refused_without_the_setting(
    api_a, settings, url, kind
) -> None:
    settings.CPCC_WEBHOOK_ALLOW_PRIVATE = False
    refused = api_a.post(URL, {"url": url, "events": ["vv.finished"]}, format="json")
    assert refused.status_code == 400
    assert refused.json()["url"] == [
        f"{kind}: webhooks go to addresses on the public internet only."
    ]
    assert not Webhook.objects.exists()


def test_the_setting_allows_them(api_a, settings) -> None:
    settings.CPCC_WEBHOOK_ALLOW_PRIVATE = True
    made = api_a.post(
        URL, {"url": "http://localhost:8000/h", "events": ["task.done"]}, format="json"
    )
    assert made.status_code == 201


@pytest.mark.parametrize(
    ("body", "field", "problem"),
    [
        ({"url": "ftp://93.184.215.14/", "events": ["vv.finished"]}, "url", "Give an http://"),
        (
            {"url": "http://no-such-host.invalid/", "events": ["vv.failed"]},
            "url",
            "does not resolve",
        ),
        ({"url": "http://user:pw@93.184.215.14/", "events": ["vv.failed"]}, "url", "Give an http"),
        (
            {"url": PUBLIC, "events": []},
            "events",
            "Choose at least one event: vv.finished, vv.failed, task.done.",
        ),
        ({"url": PUBLIC, "events": ["vv.exploded"]}, "events", '"vv.exploded" is not a valid'),
        ({"events": ["vv.failed"]}, "url", "This field is required."),
        ({"url": PUBLIC, "events": "vv.failed"}, "events", "Expected a list"),
    ],
)
def test_bad_input_is_refused_saying_what_and_where(api_a, body, field, problem) -> None:
    refused = api_a.post(URL, body, format="json")
    assert refused.status_code == 400
    assert field in refused.json() and problem in str(refused.json()[field]), refused.json()
    assert refused.json()["detail"].startswith(f"{field}")


def test_a_url_is_hooked_once_per_customer(api_a, api_b) -> None:
    assert (
        api_a.post(URL, {"url": PUBLIC, "events": ["vv.failed"]}, format="json").status_code == 201
    )
    again = api_a.post(URL, {"url": PUBLIC, "events": ["task.done"]}, format="json")
    assert again.status_code == 409 and "already have a webhook" in again.json()["url"][0]
    assert (
        api_b.post(URL, {"url": PUBLIC, "events": ["vv.failed"]}, format="json").status_code == 201
    )


def test_another_customers_webhook_is_not_found(api_a, api_b) -> None:
    made = api_a.post(URL, {"url": PUBLIC, "events": ["vv.failed"]}, format="json").json()
    for path in (f"{URL}{made['id']}/", f"{URL}{made['id']}/deliveries/"):
        answer = api_b.get(path)
        assert answer.status_code == 404, path
        assert answer.json()["detail"].startswith("No webhook with this id among yours")
    assert api_b.delete(f"{URL}{made['id']}/").status_code == 404
    assert api_b.get(URL).json()["results"] == []
    assert Webhook.objects.filter(pk=made["id"]).exists()
    assert api_a.get(f"{URL}{made['id']}/deliveries/").json()["results"] == []


def test_staff_have_no_webhooks(api_staff) -> None:
    refused = api_staff.post(URL, {"url": PUBLIC, "events": ["vv.failed"]}, format="json")
    assert refused.status_code == 403 and "belong to a customer" in refused.json()["detail"]
    assert api_staff.get(URL).json()["results"] == []


def test_a_customer_saved_from_an_older_copy_keeps_listening(api_a, customer_a) -> None:
    stale = Customer.objects.get(pk=customer_a.pk)  # read before the webhook is made
    api_a.post(URL, {"url": PUBLIC, "events": ["task.done"]}, format="json")
    stale.max_parallel_vvs = 7
    stale.save()
    fresh = Customer.objects.get(pk=customer_a.pk)
    assert (fresh.max_parallel_vvs, fresh.notify_events) == (7, ["task.done"])
