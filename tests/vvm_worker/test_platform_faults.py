"""Faults of the platform's infrastructure, across real processes (tests/live.py): Redis
restarted mid-mission, the database unavailable for seconds, every message delivered twice,
the web process restarted, a worker's clock an hour behind. Each test ends with every VV
finished and every reading in its storage exactly once (``assert_each_reading_once``).

(A worker killed between a task's completion and its checkpoint: test_distributed_faults.py,
which also compares the outcome with an undisturbed run.)
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
import requests
from django.contrib.auth.hashers import PBKDF2PasswordHasher
from django.db import connection
from rest_framework.authtoken.models import Token

from accounts.models import User
from cpcc_site.embedded_redis import EmbeddedRedis
from missions.models import ENDED_STATUSES, Migration, TaskStatus, VirtualVehicle, VVStatus
from tests.factories import (
    AREA_ONE,
    AREA_TWO,
    CustomerFactory,
    GroundStationFactory,
    UserFactory,
    VehicleFactory,
)
from tests.live import Web, Workers, program_log
from tests.polling import wait_until
from tests.tcp_proxy import TcpProxy
from vvm_worker.dispatch import VV_ADVANCE_TASK
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_submit

# `workers` (tests/live.py): worker processes of the test, flights 25 times as fast as flown.
pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

# TASKS points, in Heli One's area and Heli Two's by turns: the VV migrates at every task, so
# that the hosts need their messages (and the database) all along. Each visit counts in
# storage, keeps its reading, numbers itself with a closure and logs a line with a random
# number: a visit applied twice, or lost, shows in all of them.
VISITS = """
var co2 = VV.sensor.get('CO2');
function counter() { var n = 0; return function () { n += 1; return n; }; }
var next = counter();
VV.log('start', next(), Math.random());
for (var k = 0; k < TASKS; ++k) {
  var west = k % 2 === 0;
  var p = new VV.types.LatLngAlt(48.1100 + 0.0008 * (k % 5), west ? 12.8615 : 12.8665, 50);
  VV.task.execute({type: 'point', position: p, tolerance: 2, sensors: [co2]}, function (data) {
    var count = (VV.storage.load('count') || 0) + 1;
    VV.storage.store('count', count);
    VV.storage.store('visit ' + k, {n: next(), value: data[0].value});
    VV.log('visit', k, 'closure', next(), 'random', Math.random());
  });
}
VV.log('done', VV.storage.load('count'));
"""
TASKS = 6


def program(tasks: int = TASKS) -> str:
    return VISITS.replace("TASKS", str(tasks))


@pytest.fixture
def fleet(transactional_db: None) -> dict[str, object]:
    """A ground station and two RVs side by side; two customers with a token each."""
    gs = GroundStationFactory(name="GS Base")
    heli_one = VehicleFactory(name="Heli One", area=AREA_ONE)
    heli_two = VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lat=48.11, depot_lng=12.865)
    customers = [CustomerFactory(name="Customer A"), CustomerFactory(name="Customer B")]
    users = [UserFactory(username=f"customer-{c.name[-1].lower()}", customer=c) for c in customers]
    tokens = [Token.objects.create(user=u).key for u in users]
    return {"gs": gs, "rvs": [heli_one, heli_two], "customers": customers, "tokens": tokens}


def start_fleet(workers: Workers, **env: str) -> None:
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One", env=env)
    workers.start("rvworker", "Heli Two")


def submit(fleet: dict, count: int = 2, tasks: int = TASKS) -> list[VirtualVehicle]:
    """``count`` VVs of each customer, submitted as the web application does."""
    vvm = platform_vvm()
    return [
        vv_submit(customer=c, name=f"Visits {n}", program=program(tasks), vvm=vvm, seed=7 * n + k)
        for n in range(count)
        for k, c in enumerate(fleet["customers"])
    ]


def done(vvs: list[VirtualVehicle]) -> int:
    return sum(vv.tasks.filter(status=TaskStatus.DONE).count() for vv in vvs)


def ended(vvs: list[VirtualVehicle]) -> bool:
    ids = [vv.pk for vv in vvs]
    return VirtualVehicle.objects.filter(pk__in=ids, status__in=ENDED_STATUSES).count() == len(ids)


def assert_each_reading_once(vv: VirtualVehicle, tasks: int = TASKS) -> None:
    """The VV finished; each of its tasks was served once, its reading is in storage once, and
    each visit ran once in the program's state (the closure's numbers and the log)."""
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    served = list(vv.tasks.order_by("q"))
    assert [t.status for t in served] == [TaskStatus.DONE] * tasks
    assert vv.journal_length == tasks
    storage = dict(vv.storage.values_list("key", "value"))
    assert storage.pop("count") == tasks
    assert storage == {
        f"visit {k}": {"n": 2 + 2 * k, "value": task.readings[0]["value"]}
        for k, task in enumerate(served)
    }
    log = program_log(vv)
    assert len(log) == tasks + 2 and len(set(log)) == len(log), log
    assert [line.split(" random")[0] for line in log[1:-1]] == [
        f"visit {k} closure {3 + 2 * k}" for k in range(tasks)
    ]
    assert log[-1] == f"done {tasks}"


def no_lease_lost(vvs: list[VirtualVehicle]) -> bool:
    """No VV was moved off an RV because its worker seemed gone."""
    return not Migration.objects.filter(vv__in=vvs, reason__contains="stopped reporting").exists()


# --- Redis restarted --------------------------------------------------------------------------


def test_redis_restarted_mid_mission_loses_no_vv_and_no_reading(
    fleet, tmp_path: Path, transactional_db: None
) -> None:
    # A Redis of this test's own (the run's may be shared), restarted as a server is: every
    # connection dropped and, as it keeps nothing on disk, every queued message lost.
    socket_path = tmp_path / "redis" / "redis.sock"
    redis_server = EmbeddedRedis(socket_path).start()
    workers = Workers(tmp_path, f"unix://{socket_path}", speed=25)
    try:
        vvs = submit(fleet)
        start_fleet(workers)
        wait_until(lambda: done(vvs) >= 3, what="the mission under way", details=workers.logs)
        assert not ended(vvs)
        redis_server.stop()
        before = done(vvs)
        # The RVs fly on and the VVs step on their hosts meanwhile; what they send is lost.
        wait_until(
            lambda: done(vvs) >= before + 2,
            what="work done while Redis is down",
            details=workers.logs,
        )
        redis_server = EmbeddedRedis(socket_path).start()
        wait_until(lambda: ended(vvs), timeout=180, what="the VVs to end", details=workers.logs)
        for vv in vvs:
            assert_each_reading_once(vv)
        assert all(p.poll() is None for p in workers.processes.values()), workers.logs()
    finally:
        workers.stop_all()
        redis_server.stop()


# --- the database unavailable -----------------------------------------------------------------


class Outage:
    """The database unavailable to the workers and the web server, as each backend fails:
    PostgreSQL's server unreachable (a proxy between them and it, cut), SQLite's file locked by
    another process for longer than the processes wait for a lock."""

    def __init__(self) -> None:
        settings = connection.settings_dict
        self.sqlite = settings["ENGINE"].endswith("sqlite3")
        self.env: dict[str, str] = {}
        self.proxy: TcpProxy | None = None
        self.lock: sqlite3.Connection | None = None
        self.down = False
        if self.sqlite:
            self.env["CPCC_SQLITE_TIMEOUT_S"] = "1"
        else:
            self.proxy = TcpProxy((settings["HOST"] or "127.0.0.1", int(settings["PORT"] or 5432)))
            user = settings["USER"] or ""
            password = f":{settings['PASSWORD']}" if settings["PASSWORD"] else ""
            self.env["DATABASE_URL"] = (
                f"postgres://{user}{password}@127.0.0.1:{self.proxy.port}/{settings['NAME']}"
            )

    def begin(self) -> None:
        self.down = True
        if self.proxy is not None:
            self.proxy.cut()
        else:
            self.lock = sqlite3.connect(connection.settings_dict["NAME"], isolation_level=None)
            self.lock.execute("BEGIN EXCLUSIVE")

    def end(self) -> None:
        if not self.down:
            return
        self.down = False
        if self.proxy is not None:
            self.proxy.restore()
        elif self.lock is not None:
            self.lock.execute("ROLLBACK")
            self.lock.close()
            self.lock = None

    def close(self) -> None:
        self.end()
        if self.proxy is not None:
            self.proxy.close()


def test_the_database_unavailable_for_seconds_workers_wait_and_the_web_answers_503(
    fleet, workers: Workers, web: Web
) -> None:
    outage = Outage()
    try:
        web.env.update(outage.env)
        web.start()
        api = requests.Session()
        api.headers["Authorization"] = f"Token {fleet['tokens'][0]}"
        body = {"name": "Visits", "program": program()}
        ids = []
        for _ in range(3):
            created = api.post(web.url("/api/v1/vvs/"), json=body, timeout=30)
            assert created.status_code == 201, created.text
            ids.append(created.json()["id"])
        vvs = list(VirtualVehicle.objects.filter(pk__in=ids))
        for name in ("GS Base", "Heli One", "Heli Two"):
            workers.start(
                "rvworker" if name.startswith("Heli") else "gsworker", name, env=outage.env
            )
        wait_until(lambda: done(vvs) >= 2, what="the mission under way", details=workers.logs)
        browser = logged_in(web, "customer-a")

        outage.begin()
        try:
            # The RV workers meet the outage (a heartbeat, a task's completion) and wait.
            logs = [workers.tmp / f"rvworker-Heli_{n}.log" for n in ("One", "Two")]
            wait_until(
                lambda: all(b"database unavailable" in log.read_bytes() for log in logs),
                timeout=60,
                what="the RV workers to meet the outage",
                details=workers.logs,
            )
            refused = api.post(web.url("/api/v1/vvs/"), json=body, timeout=30)
            assert refused.status_code == 503, refused.text
            assert refused.headers["Retry-After"] == "5"
            assert "Send the request again" in refused.json()["detail"]
            listing = api.get(web.url("/api/v1/vvs/"), timeout=30)
            page = browser.get(web.url("/"), timeout=30)
            if outage.sqlite:  # a lock stops writers only: reading goes on
                assert listing.status_code == page.status_code == 200
            else:
                assert listing.status_code == page.status_code == 503, listing.text
                assert "Back in a moment" in page.text and page.headers["Retry-After"] == "5"
            assert ended(vvs) is False
        finally:
            outage.end()

        # Nothing of the refused submission was kept; sent again, it runs.
        assert VirtualVehicle.objects.count() == 3
        again = api.post(web.url("/api/v1/vvs/"), json=body, timeout=30)
        assert again.status_code == 201, again.text
        vvs.append(VirtualVehicle.objects.get(pk=again.json()["id"]))
        wait_until(lambda: ended(vvs), timeout=180, what="the VVs to end", details=workers.logs)
        for vv in vvs:
            assert_each_reading_once(vv)
        assert no_lease_lost(vvs)  # nobody's lease ran out for the outage
        assert all(p.poll() is None for p in workers.processes.values()), workers.logs()
    finally:
        outage.close()


def logged_in(web: Web, username: str) -> requests.Session:
    """A browser's session, logged in through the login page. (The test run hashes passwords
    with a fast hasher that the web server does not take: the user's is hashed for it.)"""
    hashed = PBKDF2PasswordHasher().encode("secret-pass-123", "fault-test-salt", iterations=1000)
    User.objects.filter(username=username).update(password=hashed)
    browser = requests.Session()
    browser.get(web.url("/accounts/login/"), timeout=30)
    form = {
        "username": username,
        "password": "secret-pass-123",
        "csrfmiddlewaretoken": browser.cookies["csrftoken"],
    }
    headers = {"Referer": web.url("/accounts/login/")}
    answer = browser.post(web.url("/accounts/login/"), data=form, headers=headers, timeout=30)
    assert answer.ok and "sessionid" in browser.cookies, answer.text
    return browser


# --- every message twice ----------------------------------------------------------------------


def test_every_message_delivered_twice_changes_nothing(
    fleet, workers: Workers, tmp_path: Path, monkeypatch
) -> None:
    from celery.app import base

    twice = tmp_path / "duplicates.txt"
    twice.touch()
    send = base.Celery.send_task

    def send_twice(self, *args, **kwargs):  # what this process sends, too
        send(self, *args, **kwargs)
        with twice.open("a") as log:
            log.write(f"{args[0]}\n")
        return send(self, *args, **kwargs)

    monkeypatch.setattr(base.Celery, "send_task", send_twice)
    fault = {"CPCC_FAULT_DUPLICATES": str(twice)}
    workers.start("gsworker", "GS Base", env=fault)
    workers.start("rvworker", "Heli One", env=fault)
    workers.start("rvworker", "Heli Two", env=fault)
    vvs = submit(fleet)
    wait_until(lambda: ended(vvs), timeout=180, what="the VVs to end", details=workers.logs)
    for vv in vvs:
        assert_each_reading_once(vv)
    sent = twice.read_text().split()
    # Each VV went from host to host by message (migrations) and each arrival came twice.
    assert sent.count(VV_ADVANCE_TASK) >= len(vvs) * TASKS, sent


# --- the web process restarted ----------------------------------------------------------------


def test_the_web_process_killed_and_restarted_mid_mission_loses_nothing(
    fleet, workers: Workers, web: Web
) -> None:
    web.start()
    start_fleet(workers)
    api = requests.Session()
    api.headers["Authorization"] = f"Token {fleet['tokens'][1]}"
    body = {"name": "Visits", "program": program()}
    ids = [api.post(web.url("/api/v1/vvs/"), json=body, timeout=30).json()["id"] for _ in range(3)]
    vvs = list(VirtualVehicle.objects.filter(pk__in=ids))
    assert len(vvs) == 3
    wait_until(lambda: done(vvs) >= 2, what="the mission under way", details=workers.logs)

    web.kill()
    with pytest.raises(requests.ConnectionError):
        api.get(web.url("/api/v1/vvs/"), timeout=5)
    assert not ended(vvs)  # the fleet flies on without the web
    web.start()

    def finished_over_rest() -> bool:
        listed = api.get(web.url("/api/v1/vvs/"), timeout=30).json()["results"]
        return sorted(v["id"] for v in listed if v["status"] == "finished") == sorted(ids)

    wait_until(finished_over_rest, timeout=180, what="the VVs to finish", details=workers.logs)
    for vv in vvs:
        assert_each_reading_once(vv)
        storage = api.get(web.url(f"/api/v1/vvs/{vv.pk}/storage/"), timeout=30).json()
        assert len(storage["results"]) == TASKS + 1
        results = api.get(web.url(f"/api/v1/vvs/{vv.pk}/results.zip"), timeout=30)
        assert results.status_code == 200 and results.content.startswith(b"PK")


# --- a worker's clock behind ------------------------------------------------------------------


def test_an_rv_worker_whose_clock_is_an_hour_behind_keeps_its_lease_and_its_work(
    fleet, workers: Workers
) -> None:
    vvs = submit(fleet)
    start_fleet(workers, CPCC_FAULT_CLOCK_S=str(-3600))
    wait_until(lambda: ended(vvs), timeout=180, what="the VVs to end", details=workers.logs)
    for vv in vvs:
        assert_each_reading_once(vv)
    assert no_lease_lost(vvs)
    heli_one = fleet["rvs"][0]
    # Heli One, its clock behind, served its half of every VV's visits.
    assert heli_one.tasks.filter(status=TaskStatus.DONE).count() == len(vvs) * TASKS // 2
