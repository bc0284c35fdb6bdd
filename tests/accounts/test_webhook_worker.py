"""A webhook end to end on the distributed platform: a ground-station worker (a process of its
own, on the test run's Redis) runs a VV to its end, the notify worker POSTs it, and a receiver
on 127.0.0.1 gets the signed POST, first answering 500, then the retry sent after its back-off.
A receiver that never answers delays only its own customer's notifications."""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import json
import socket
import threading
from collections.abc import Iterator

import pytest

from accounts.models import WebhookDelivery
from accounts.services import webhook_create
from tests.factories import GroundStationFactory
from tests.polling import wait_until
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_submit

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
    workers.start("notifyworker", "notify")
    vv = vv_submit(customer=customer_a, name="hello", program="VV.log('hi');", vvm=platform_vvm())

    first, second = receiver.wait_for(2, timeout=60)
    expected = hmac.new(webhook.secret.encode(), second.body, hashlib.sha256).hexdigest()
    assert second.headers["X-CPCC-Signature"] == f"sha256={expected}"
    assert first.body == second.body
    body = json.loads(second.body)
    assert (body["event"], body["id"], body["status"]) == ("vv.finished", str(vv.pk), "finished")

    attempts = WebhookDelivery.objects.filter(webhook=webhook).order_by("attempt")
    wait_until(lambda: attempts.count() == 2, timeout=30, what="both attempts logged")
    assert list(attempts.values_list("attempt", "status_code")) == [(1, 500), (2, 200)]


class Stalling:
    """A webhook receiver that reads each request and never answers: the client gives up."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.server.getsockname()[1]}/hook"
        self.accepted = 0
        self.open = 0
        self.held: list[socket.socket] = []
        self.closed = False
        self.lock = threading.Lock()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                connection, _ = self.server.accept()
            except OSError:
                return
            with self.lock:
                if self.closed:  # accepted as it closed: let go at once
                    connection.close()
                    return
                self.accepted += 1
                self.open += 1
                self.held.append(connection)
            threading.Thread(target=self._hold, args=(connection,), daemon=True).start()

    def _hold(self, connection: socket.socket) -> None:
        with connection, contextlib.suppress(OSError):
            while connection.recv(65536):  # until the client closes it
                pass
        with self.lock:
            self.open -= 1

    def close(self) -> None:
        """Stop, and let go of what is held (the worker stops without waiting it out)."""
        with self.lock:
            self.closed = True
            self.server.close()
            for connection in self.held:
                with contextlib.suppress(OSError):
                    connection.shutdown(socket.SHUT_RDWR)


@pytest.fixture
def stalling() -> Iterator[Stalling]:
    receiver = Stalling()
    yield receiver
    receiver.close()


def test_a_receiver_that_never_answers_delays_no_other_customers_notifications(
    workers, customer_a, customer_b, receiver, stalling
) -> None:
    GroundStationFactory(name="GS Base")
    webhook_create(
        customer=customer_a, url=receiver.url, events=["vv.finished"], allow_private=True
    )
    webhook_create(
        customer=customer_b, url=stalling.url, events=["vv.finished"], allow_private=True
    )
    workers.env.update(
        {
            "CPCC_WEBHOOK_ALLOW_PRIVATE": "1",
            "CPCC_WEBHOOK_TIMEOUT_S": "20",
            "CPCC_WEBHOOK_RETRY_S": "600",  # one attempt each within this test
            "CPCC_NOTIFY_THREADS": "3",
            "CPCC_NOTIFY_PER_CUSTOMER": "1",
            "CPCC_GS_ISOLATE_POOL": "1",
        }
    )
    workers.start("gsworker", "GS Base")
    workers.start("notifyworker", "notify")
    vvm = platform_vvm()
    # Customer B's receiver holds every delivery for the whole 20 s: four of them, 80 s in all
    # (one at a time: B's share of the threads).
    for n in range(4):
        vv_submit(customer=customer_b, name=f"b{n}", program="VV.log('b');", vvm=vvm)
    wait_until(lambda: stalling.open == 1, timeout=30, what="B's first delivery held")

    # Meanwhile customer A's VV runs to its end and A's receiver hears of it.
    vv = vv_submit(customer=customer_a, name="a", program="VV.log('a');", vvm=vvm)
    (posted,) = receiver.wait_for(1, timeout=30)

    assert json.loads(posted.body)["id"] == str(vv.pk)
    with stalling.lock:  # B's first is still held: A's came past it, not after it
        assert (stalling.accepted, stalling.open) == (1, 1)
