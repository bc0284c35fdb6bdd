"""A webhook end to end on the distributed platform: a ground-station worker (a process of its
own, on the test run's Redis) runs a VV to its end, and a receiver on 127.0.0.1 gets the
signed POST, first answering 500, then the retry the worker sends after its back-off."""

from __future__ import annotations

import hashlib
import hmac
import json

import pytest

from accounts.models import WebhookDelivery
from tests.factories import GroundStationFactory
from tests.live import wait_for
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_submit
from vvm_worker.services.notifications import webhook_create

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]


def test_a_worker_posts_a_finished_vv_signed_and_retries_after_a_500(
    workers, customer_a, receiver
) -> None:
    GroundStationFactory(name="GS Base")
    webhook = webhook_create(
        customer=customer_a, url=receiver.url, events=["vv.finished"], allow_private=True
    )
    receiver.answers = [500]
    workers.env.update(
        {
            "CPCC_WEBHOOK_ALLOW_PRIVATE": "1",  # the receiver is on this machine
            "CPCC_WEBHOOK_RETRY_S": "0.2",
            "CPCC_GS_ISOLATE_POOL": "1",
        }
    )
    workers.start("gsworker", "GS Base")
    vv = vv_submit(customer=customer_a, name="hello", program="VV.log('hi');", vvm=platform_vvm())

    first, second = receiver.wait_for(2, timeout=60)
    expected = hmac.new(webhook.secret.encode(), second.body, hashlib.sha256).hexdigest()
    assert second.headers["X-CPCC-Signature"] == f"sha256={expected}"
    assert first.body == second.body
    body = json.loads(second.body)
    assert (body["event"], body["id"], body["status"]) == ("vv.finished", str(vv.pk), "finished")

    attempts = WebhookDelivery.objects.filter(webhook=webhook).order_by("attempt")
    wait_for(lambda: attempts.count() == 2, timeout=30, what="both attempts logged")
    assert list(attempts.values_list("attempt", "status_code")) == [(1, 500), (2, 200)]
