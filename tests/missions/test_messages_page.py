"""A VV's page: its messages in and out (the last ones, newest first, names as text) and the
form that sends it a message from the customer's own system, as the REST API does."""

from __future__ import annotations

import html
import json

import pytest
from django.db import transaction
from django.urls import reverse

from missions.models import Message, VirtualVehicle
from missions.views import MESSAGES_SHOWN
from vvm_worker.services import vv_cancel, vv_submit
from vvm_worker.services.messages import message_send

# A VV's name is the customer's text: the page must show it, never run it.
MARKUP_NAME = "<b>Scout</b> & co"


@pytest.fixture
def vvm(vvm_factory):
    return vvm_factory()


@pytest.fixture
def scout(customer_a, ground_station, vvm) -> VirtualVehicle:
    return vv_submit(customer=customer_a, name=MARKUP_NAME, program="var a = 1;", vvm=vvm)


@pytest.fixture
def base(customer_a, ground_station, vvm) -> VirtualVehicle:
    return vv_submit(customer=customer_a, name="Base", program="var b = 1;", vvm=vvm)


def page_url(vv: VirtualVehicle) -> str:
    return reverse("vv-detail", args=[vv.pk])


def send(sender: VirtualVehicle | None, to: VirtualVehicle, value, vvm) -> Message:
    customer_id = to.customer_id
    with transaction.atomic():
        return message_send(
            customer_id=customer_id,
            sender=sender,
            to=str(to.pk),
            value_json=json.dumps(value),
            vvm=vvm,
        )


def messages_section(page: str) -> str:
    start = page.index('<section class="card" id="messages">')
    return page[start : page.index("</section>", start)]


def test_the_page_shows_messages_in_and_out_newest_first_with_names_as_text(
    client, user_a, scout, base, vvm
) -> None:
    send(scout, base, {"found": "green"}, vvm)
    send(None, scout, "steer north", vvm)
    send(base, scout, [1, 2], vvm)
    client.force_login(user_a)

    response = client.get(page_url(scout))

    assert response.status_code == 200
    section = messages_section(response.text)
    assert "<b>Scout</b>" not in response.text, "a VV's name is text, never markup"
    assert "&lt;b&gt;Scout&lt;/b&gt; &amp; co" in section
    rows = section.split('<tr class="message-')[1:]
    assert [row.split('"', 1)[0] for row in rows] == ["in", "in", "out"]
    shown = [html.unescape(row) for row in rows]
    assert "Base" in shown[0] and "[\n  1,\n  2\n]" in shown[0]
    assert "your system (API)" in shown[1] and '"steer north"' in shown[1]
    assert '"found": "green"' in shown[2] and "Base" in shown[2]
    assert 'name="value"' in section, "a VV that has not ended can be sent a message"


def test_the_page_shows_the_last_messages_and_links_to_the_api_for_all(
    client, user_a, scout, vvm
) -> None:
    for n in range(MESSAGES_SHOWN + 3):
        send(None, scout, n, vvm)
    client.force_login(user_a)

    section = messages_section(client.get(page_url(scout)).text)

    assert section.count('<tr class="message-in">') == MESSAGES_SHOWN
    assert f"the last {MESSAGES_SHOWN} of {MESSAGES_SHOWN + 3}" in section
    assert f'href="/api/v1/vvs/{scout.pk}/messages/"' in section
    assert '<pre class="json">52</pre>' in section and '<pre class="json">2</pre>' not in section


def test_the_form_sends_a_message_the_vvs_program_receives_from_no_vv(
    client, user_a, scout
) -> None:
    client.force_login(user_a)

    response = client.post(page_url(scout), {"value": '{"goto": [48.1, 12.8]}'})

    assert response.status_code == 302
    assert response["Location"] == page_url(scout) + "#messages"
    (message,) = Message.objects.all()
    assert message.recipient == scout and message.sender is None and message.sender_name == ""
    assert json.loads(message.value) == {"goto": [48.1, 12.8]}
    page = html.unescape(client.get(response["Location"]).text)
    assert f"The message is sent to “{MARKUP_NAME}”." in page
    assert '"goto": [' in messages_section(page)


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("", "Write the value to send as JSON"),
        ("{goto: 1}", "The value is not JSON: Expecting property name"),
        ('"' + "x" * 70_000 + '"', "more than the 65,536 allowed (quota: bytes per message)"),
        ("[" * 101 + "]" * 101, "nested more than 100 levels deep"),
    ],
)
def test_a_value_that_cannot_be_sent_shows_why_and_keeps_what_was_written(
    client, user_a, scout, text, why
) -> None:
    client.force_login(user_a)

    response = client.post(page_url(scout), {"value": text})

    assert response.status_code == 400
    page = html.unescape(response.text)
    assert why in page
    assert 'aria-invalid="true"' in response.text
    if text:
        assert text[:50] in page, "the value written is kept in the form"
    assert not Message.objects.exists()


def test_a_vv_that_has_ended_has_no_form_and_takes_no_message(client, user_a, scout, vvm) -> None:
    vv_cancel(vv_id=scout.pk, vvm=vvm)
    client.force_login(user_a)

    assert 'name="value"' not in messages_section(client.get(page_url(scout)).text)
    response = client.post(page_url(scout), {"value": "1"}, follow=True)

    assert response.status_code == 200
    assert "has ended (cancelled): it takes no more messages." in html.unescape(response.text)
    assert not Message.objects.exists()


def test_another_customer_cannot_send_to_a_vv_or_see_its_messages(
    client, user_b, scout, vvm
) -> None:
    send(None, scout, "secret plan", vvm)
    client.force_login(user_b)

    assert client.get(page_url(scout)).status_code == 404
    response = client.post(page_url(scout), {"value": '"taken over"'})

    assert response.status_code == 404
    assert "secret plan" not in response.text
    assert list(Message.objects.values_list("value", flat=True)) == ['"secret plan"']
