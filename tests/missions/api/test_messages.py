"""/api/v1/vvs/{id}/messages/: a VV's messages in and out, newest first, and a message from the
customer's own system to a VV that has not ended; the second customer gets 404 for both."""

from __future__ import annotations

import datetime as dt
import json

import pytest
from django.db import transaction
from django.db.models import F

from missions.models import Message, VirtualVehicle
from missions.selectors import vv_messages_pages_for_user
from vvm_worker.services.messages import message_send

NO_SUCH_ID = "00000000-0000-0000-0000-000000000000"


def messages_url(vv_id) -> str:
    return f"/api/v1/vvs/{vv_id}/messages/"


def submitted(api, name: str) -> str:
    """A new VV of the caller's (queued: it has not ended), by its id."""
    response = api.post("/api/v1/vvs/", {"name": name, "program": "var a = 1;"}, format="json")
    assert response.status_code == 201, response.content
    return response.json()["id"]


def send_between(sender_id: str, to: str, value, vvm) -> Message:
    """What ``VV.message.send(to, value)`` in the program of ``sender_id`` does."""
    sender = VirtualVehicle.objects.get(pk=sender_id)
    with transaction.atomic():
        return message_send(
            customer_id=sender.customer_id,
            sender=sender,
            to=to,
            value_json=json.dumps(value),
            vvm=vvm,
        )


def test_a_message_posted_by_the_customers_system_is_listed_as_in_from_no_vv(api_a) -> None:
    vv_id = submitted(api_a, "Listener")
    value = {"goto": [48.11, 12.86], "note": "ü ✓", "deep": [[1, None, True]]}

    response = api_a.post(messages_url(vv_id), {"value": value}, format="json")

    assert response.status_code == 201, response.content
    sent = response.json()
    assert set(sent) == {
        "id", "direction", "from", "to", "value", "bytes", "sent_at", "received_at",
    }  # fmt: skip
    assert sent["direction"] == "in" and sent["from"] is None
    assert sent["to"] == {"id": vv_id, "name": "Listener"}
    assert sent["value"] == value and sent["received_at"] is None
    stored = Message.objects.get(pk=sent["id"])
    assert sent["bytes"] == stored.bytes == len(stored.value.encode())
    assert json.loads(stored.value) == value and stored.sender is None
    assert sent["sent_at"].endswith("Z")
    listed = api_a.get(messages_url(vv_id)).json()
    assert listed["count"] == 1 and listed["results"] == [sent]


@pytest.mark.parametrize("value", [None, 0, "text", [], {"a": {"b": 1.5}}])
def test_any_json_value_may_be_sent(api_a, value) -> None:
    vv_id = submitted(api_a, "Any")
    response = api_a.post(messages_url(vv_id), {"value": value}, format="json")
    assert response.status_code == 201, response.content
    assert response.json()["value"] == value


def test_a_body_without_a_value_is_refused(api_a) -> None:
    vv_id = submitted(api_a, "V")
    response = api_a.post(messages_url(vv_id), {"valu": 1}, format="json")
    assert response.status_code == 400
    assert response.json()["detail"] == "value: This field is required."
    assert not Message.objects.exists()


def test_a_value_over_the_customers_size_of_a_message_is_refused_saying_why(
    api_a, customer_a
) -> None:
    customer_a.max_message_bytes = 100
    customer_a.save()
    vv_id = submitted(api_a, "Small")
    fits = api_a.post(messages_url(vv_id), {"value": "x" * 98}, format="json")  # 100 as JSON
    assert fits.status_code == 201, fits.content

    response = api_a.post(messages_url(vv_id), {"value": "x" * 99}, format="json")

    assert response.status_code == 400
    detail = response.json()["detail"]
    assert "101 bytes" in detail and "100 allowed" in detail and "bytes per message" in detail
    assert response.json()["value"] == [detail]
    assert Message.objects.count() == 1


def test_messages_over_the_api_count_against_the_customers_messages_per_vv(
    api_a, customer_a, vvm_factory
) -> None:
    customer_a.max_messages_per_vv = 3
    customer_a.save()
    vv_id, other_id = submitted(api_a, "Inbox"), submitted(api_a, "Other")
    send_between(other_id, vv_id, "from a VV: counted where it was sent", vvm_factory())
    for n in range(3):
        assert api_a.post(messages_url(vv_id), {"value": n}, format="json").status_code == 201

    refused = api_a.post(messages_url(vv_id), {"value": 3}, format="json")

    assert refused.status_code == 400
    assert refused.json()["detail"] == (
        "Inbox has been sent 3 messages over the API, as many as it may take (quota: messages "
        "per VV)"
    )
    assert Message.objects.filter(recipient_id=vv_id).count() == 4
    # The quota is each VV's: another VV of the customer still takes messages.
    assert api_a.post(messages_url(other_id), {"value": 0}, format="json").status_code == 201


def test_a_value_the_platform_cannot_keep_is_refused_saying_why(api_a) -> None:
    vv_id = submitted(api_a, "Nul")
    response = api_a.post(messages_url(vv_id), {"value": {"k": "a\x00b"}}, format="json")
    assert response.status_code == 400
    assert "U+0000" in response.json()["detail"]
    assert not Message.objects.exists()


def test_a_vv_that_has_ended_takes_no_more_messages(api_a) -> None:
    vv_id = submitted(api_a, "Gone")
    assert api_a.post(f"/api/v1/vvs/{vv_id}/cancel/").status_code == 200

    response = api_a.post(messages_url(vv_id), {"value": 1}, format="json")

    assert response.status_code == 409
    assert response.json() == {
        "detail": "'Gone' has already ended (cancelled): it takes no more messages."
    }
    assert not Message.objects.exists()
    assert api_a.get(messages_url(vv_id)).json()["count"] == 0


def test_another_customers_vv_is_not_found_for_listing_and_sending(api_a, api_b) -> None:
    vv_id = submitted(api_a, "Mine")
    assert api_a.post(messages_url(vv_id), {"value": "secret"}, format="json").status_code == 201
    for method in ("get", "post"):
        call = getattr(api_b, method)
        theirs = call(messages_url(vv_id), {"value": 1}, format="json")
        missing = call(messages_url(NO_SUCH_ID), {"value": 1}, format="json")
        assert theirs.status_code == missing.status_code == 404, method
        assert theirs.json() == missing.json(), "another customer's VV looks like a missing one"
        assert "secret" not in theirs.content.decode()
    assert Message.objects.count() == 1


def test_messages_in_and_out_newest_first_with_both_ends(api_a, vvm_factory) -> None:
    scout, base = submitted(api_a, "Scout"), submitted(api_a, "Base")
    vvm = vvm_factory()
    first = send_between(scout, "Base", {"found": 1}, vvm)
    assert api_a.post(messages_url(scout), {"value": "go on"}, format="json").status_code == 201
    back = send_between(base, scout, "thanks", vvm)  # by id
    to_self = send_between(scout, "Scout", "note to self", vvm)

    listed = api_a.get(messages_url(scout)).json()["results"]

    assert [m["value"] for m in listed] == ["note to self", "thanks", "go on", {"found": 1}]
    assert [m["direction"] for m in listed] == ["in", "in", "in", "out"]
    scout_end, base_end = {"id": scout, "name": "Scout"}, {"id": base, "name": "Base"}
    assert [(m["from"], m["to"]) for m in listed] == [
        (scout_end, scout_end),
        (base_end, scout_end),
        (None, scout_end),
        (scout_end, base_end),
    ]
    assert [m["id"] for m in listed] == [to_self.pk, back.pk, listed[2]["id"], first.pk]
    base_side = api_a.get(messages_url(base)).json()["results"]
    assert [(m["direction"], m["value"]) for m in base_side] == [
        ("out", "thanks"),
        ("in", {"found": 1}),
    ]


def test_a_received_message_says_when_it_was_taken(api_a) -> None:
    vv_id = submitted(api_a, "R")
    assert api_a.post(messages_url(vv_id), {"value": 1}, format="json").status_code == 201
    Message.objects.update(received_s=F("sent_s") + 30)

    (shown,) = api_a.get(messages_url(vv_id)).json()["results"]

    sent, received = (dt.datetime.fromisoformat(shown[k]) for k in ("sent_at", "received_at"))
    assert received - sent == dt.timedelta(seconds=30)


def test_the_list_is_paged_like_the_other_lists(api_a, user_a, settings) -> None:
    vv_id = submitted(api_a, "Many")
    for n in range(53):
        assert api_a.post(messages_url(vv_id), {"value": n}, format="json").status_code == 201
    first = api_a.get(messages_url(vv_id)).json()
    assert first["count"] == 53 and len(first["results"]) == 50
    assert [m["value"] for m in first["results"][:2]] == [52, 51]
    second = api_a.get(first["next"]).json()
    assert [m["value"] for m in second["results"]] == [2, 1, 0]
    assert api_a.get(messages_url(vv_id) + "?page=x").status_code == 400
    assert len(vv_messages_pages_for_user(user=user_a, vv_id=vv_id)[0:5]) == 5


def test_staff_see_and_send_to_any_customers_vv(api_a, api_staff) -> None:
    vv_id = submitted(api_a, "Watched")
    response = api_staff.post(messages_url(vv_id), {"value": "from the operator"}, format="json")
    assert response.status_code == 201, response.content
    assert response.json()["from"] is None
    assert api_staff.get(messages_url(vv_id)).json()["count"] == 1
    assert api_a.get(messages_url(vv_id)).json()["results"][0]["value"] == "from the operator"
