"""Hearing when a VV ends: the services tell the notifier only of events the customer listens
for, the Celery tasks POST them signed to a real receiver on 127.0.0.1, retry what failed and
log every attempt for the customer, and e-mail the users who chose the event.

Celery runs the delivery tasks eagerly here (in the test); tests/accounts/test_webhook_worker.py
does the same through a real worker and Redis.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import uuid

import pytest
from django.core import mail
from django.db import connection, transaction
from django.test.utils import CaptureQueriesContext

from accounts.models import WebhookDelivery
from accounts.services import user_set_email_events, webhook_create
from cpcc_site.celery import app
from missions.models import VirtualVehicle, VVStatus
from tests.broker import queued
from vvm_worker import tasks
from vvm_worker.celery_dispatch import CeleryNotifier
from vvm_worker.delivery import NOTIFY_QUEUE, retry_delay_s
from vvm_worker.services import vv_submit
from vvm_worker.services.notifications import vv_notify

pytestmark = pytest.mark.django_db

ONE_TASK = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                 tolerance: 2, sensors: [co2]});
VV.log('read');
"""


class RecordingNotifier:
    def __init__(self) -> None:
        self.told: list[tuple[str, uuid.UUID, int | None]] = []

    def vv_event(self, *, event, vv_id, at_ms, task_id=None) -> None:
        self.told.append((event, vv_id, task_id))


@pytest.fixture
def eager(settings):
    """Celery tasks run in the test as they are sent (countdowns included: no waiting)."""
    settings.CPCC_WEBHOOK_ALLOW_PRIVATE = True
    app.conf.task_always_eager = True
    app.conf.task_eager_propagates = True
    yield
    app.conf.task_always_eager = False
    app.conf.task_eager_propagates = False


@pytest.fixture
def notify_queue(broker):
    broker.delete(NOTIFY_QUEUE)
    yield lambda: queued(broker, NOTIFY_QUEUE)
    broker.delete(NOTIFY_QUEUE)


def hook(customer, url: str, events: list[str]):
    return webhook_create(customer=customer, url=url, events=events, allow_private=True)


def run(platform, customer, program: str, name: str = "Survey") -> VirtualVehicle:
    vv = vv_submit(customer=customer, name=name, program=program, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    return vv


def signature(secret: str, body: bytes) -> str:
    return "sha256=" + hmac.new(secret.encode(), body, hashlib.sha256).hexdigest()


# The notifier's message goes to the broker even with eager tasks: the test reads it there.
@pytest.mark.filterwarnings("ignore::celery.exceptions.AlwaysEagerIgnored")
def test_a_finished_vv_is_posted_signed_and_retried_after_a_500(
    platform,
    ground_station,
    customer_a,
    api_a,
    api_b,
    receiver,
    eager,
    notify_queue,
    django_capture_on_commit_callbacks,
) -> None:
    made = api_a.post(
        "/api/v1/webhooks/", {"url": receiver.url, "events": ["vv.finished"]}, format="json"
    ).json()
    platform.vvm.notifier = CeleryNotifier()
    receiver.answers = [500]  # then 200
    with django_capture_on_commit_callbacks(execute=True):
        vv = run(platform, customer_a, "VV.log('hello');", name="Hello")
    assert vv.status == VVStatus.FINISHED

    # The VV's end put one message on the notify queue, once its transaction committed.
    ((name, args),) = notify_queue()
    assert name == "cpcc.notify" and args[:2] == ["vv.finished", str(vv.pk)]
    tasks.notify.apply(args=args)  # what a worker on the notify queue does with it

    first, second = receiver.wait_for(2)
    assert first.body == second.body
    for post in (first, second):
        assert post.method == "POST" and post.path == "/hooks/cpcc"
        assert post.headers["Content-Type"] == "application/json"
        assert post.headers["X-CPCC-Event"] == "vv.finished"
        assert post.headers["X-CPCC-Signature"] == signature(made["secret"], post.body)
    assert first.headers["X-CPCC-Delivery"] == second.headers["X-CPCC-Delivery"]
    body = json.loads(first.body)
    assert body == {
        "event": "vv.finished",
        "id": str(vv.pk),
        "name": "Hello",
        "status": "finished",
        "time": vv.finished.isoformat(timespec="milliseconds").replace("+00:00", "Z"),
    }

    log = api_a.get(f"/api/v1/webhooks/{made['id']}/deliveries/").json()["results"]
    assert [(a["attempt"], a["status_code"], a["ok"], a["error"]) for a in log] == [
        (2, 200, True, ""),
        (1, 500, False, "answered 500"),
    ]
    assert {a["vv"] for a in log} == {str(vv.pk)} and {a["event"] for a in log} == {"vv.finished"}
    assert api_b.get(f"/api/v1/webhooks/{made['id']}/deliveries/").status_code == 404

    # The same message delivered again (Celery delivers at least once) posts nothing more.
    tasks.notify.apply(args=args)
    assert len(receiver.requests) == 2


def test_attempts_are_bounded_and_back_off(
    customer_a, platform, ground_station, receiver, eager, settings
) -> None:
    settings.CPCC_WEBHOOK_ATTEMPTS = 3
    receiver.answers = [503] * 10
    webhook = hook(customer_a, receiver.url, ["vv.failed"])
    vv = run(platform, customer_a, "null.boom;")
    assert vv.status == VVStatus.FAILED
    tasks.notify.apply(args=["vv.failed", str(vv.pk), 0, None])
    assert len(receiver.requests) == 3
    assert list(webhook.deliveries.order_by("attempt").values_list("attempt", "status_code")) == [
        (1, 503),
        (2, 503),
        (3, 503),
    ]
    body = json.loads(receiver.requests[0].body)
    assert body["status"] == "failed" and "TypeError" in body["error"]
    assert body["error_line"] == 1
    # 30 s, then twice the wait before each time.
    assert [retry_delay_s(n, first_s=30) for n in (1, 2, 3, 4)] == [30, 60, 120, 240]


def test_only_what_someone_listens_for_is_told(
    platform, fleet_one, customer_a, customer_b, receiver
) -> None:
    told = RecordingNotifier()
    platform.vvm.notifier = told
    hook(customer_a, receiver.url, ["vv.finished"])
    hook(customer_b, receiver.url, ["task.done"])
    a = run(platform, customer_a, ONE_TASK, name="A's")
    b = run(platform, customer_b, ONE_TASK, name="B's")
    assert (a.status, b.status) == (VVStatus.FINISHED, VVStatus.FINISHED)
    (task,) = b.tasks.all()
    assert told.told == [("vv.finished", a.pk, None), ("task.done", b.pk, task.pk)]


def test_nobody_listening_costs_no_query(customer_a, vvm_factory) -> None:
    vvm = vvm_factory()
    told = RecordingNotifier()
    vvm.notifier = told
    vv = vv_submit(customer=customer_a, name="quiet", program="VV.log(1);", vvm=vvm)
    vv = VirtualVehicle.objects.select_related("customer").get(pk=vv.pk)
    with CaptureQueriesContext(connection) as queries:
        for event in ("vv.finished", "vv.failed", "task.done"):
            vv_notify(vv=vv, event=event, vvm=vvm, at_ms=0)
    assert queries.captured_queries == [] and told.told == []


def test_a_rolled_back_end_tells_nobody(
    customer_a, receiver, notify_queue, django_capture_on_commit_callbacks
) -> None:
    hook(customer_a, receiver.url, ["vv.finished"])
    with django_capture_on_commit_callbacks(execute=True) as callbacks:
        try:
            with transaction.atomic():
                CeleryNotifier().vv_event(event="vv.finished", vv_id=uuid.uuid4(), at_ms=0)
                raise RuntimeError("rolled back")
        except RuntimeError:
            pass
    assert callbacks == [] and notify_queue() == []


def test_a_url_that_turned_private_is_not_posted_to_nor_retried(
    customer_a, platform, ground_station, receiver, eager, settings
) -> None:
    webhook = hook(customer_a, receiver.url, ["vv.finished"])  # while the setting allowed it
    settings.CPCC_WEBHOOK_ALLOW_PRIVATE = False
    vv = run(platform, customer_a, "VV.log(1);")
    tasks.notify.apply(args=["vv.finished", str(vv.pk), 0, None])
    assert receiver.requests == []
    (attempt,) = WebhookDelivery.objects.filter(webhook=webhook)
    assert attempt.status_code is None and "is a loopback address" in attempt.error


def test_a_failed_vv_emails_the_users_who_chose_it(
    customer_a, user_a, platform, ground_station, eager, settings
) -> None:
    from tests.factories import UserFactory

    settings.CPCC_SITE_URL = "https://cpcc.example.com/"
    UserFactory(username="colleague", customer=customer_a, email="c@example.com")
    user_set_email_events(user=user_a, email="a@example.com", events=["vv.failed"])
    told = RecordingNotifier()
    platform.vvm.notifier = told
    finished = run(platform, customer_a, "VV.log(1);", name="fine")
    failed = run(platform, customer_a, "VV.log(1);\nnull.boom;", name="Broken")
    assert told.told == [("vv.failed", failed.pk, None)]  # nobody listens for vv.finished
    assert finished.status == VVStatus.FINISHED
    tasks.notify.apply(args=["vv.failed", str(failed.pk), 0, None])
    (message,) = mail.outbox
    assert message.to == ["a@example.com"]
    assert message.subject == "[CPCC] Broken failed"
    assert "TypeError" in message.body and "error_line: 2" in message.body
    assert f"https://cpcc.example.com/vvs/{failed.pk}/" in message.body


def test_a_job_of_a_customer_whose_posts_are_all_under_way_goes_back_to_the_queue(
    customer_a, customer_b, receiver, notify_queue, settings
) -> None:
    settings.CPCC_WEBHOOK_ALLOW_PRIVATE = True
    settings.CPCC_NOTIFY_PER_CUSTOMER = 1

    def job(customer) -> dict:
        webhook = hook(customer, receiver.url, ["vv.finished"])
        return {
            "webhook_id": webhook.pk,
            "delivery": str(uuid.uuid4()),
            "event": "vv.finished",
            "vv_id": str(uuid.uuid4()),
            "task_id": None,
            "body": "{}",
            "customer_id": customer.pk,
        }

    a_job, b_job = job(customer_a), job(customer_b)
    assert tasks._POSTING.try_take(customer_a.pk)  # a POST of customer A's under way
    try:
        tasks.webhook_deliver.apply(args=[a_job, 1])
        tasks.webhook_deliver.apply(args=[b_job, 1])
    finally:
        tasks._POSTING.give_back(customer_a.pk)
    # A's job waits its turn on the queue, the same attempt; its thread posted B's meanwhile.
    assert notify_queue() == [("cpcc.webhook_deliver", [a_job, 1])]
    assert [json.loads(r.body) for r in receiver.requests] == [{}]
    assert receiver.requests[0].headers["X-CPCC-Delivery"] == b_job["delivery"]
