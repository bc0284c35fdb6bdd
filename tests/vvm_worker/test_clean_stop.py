"""Processes that use V8 survive many customers at once and stop cleanly (issue 20).

The web server (daphne, as in production, and the in-process server) answers every one of many
concurrent submissions, each checked by V8; a worker or the web server stopped with SIGTERM in
the middle of work exits with status 0 (never a segmentation fault in V8), and every VV
finishes once the workers are back. Run on SQLite and on PostgreSQL (CI's second pass).
"""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
import requests
from rest_framework.authtoken.models import Token

from fleet.models import Vehicle
from missions.models import VirtualVehicle, VVStatus
from tests.factories import (
    AREA_ONE,
    CustomerFactory,
    GroundStationFactory,
    UserFactory,
    VehicleFactory,
)
from tests.live import Workers
from tests.polling import wait_until
from tests.vvm_worker.test_distributed import (
    all_ended,
    assert_paper_results,
    load,
    wait_mid_mission,
)
from tests.vvm_worker.test_distributed_faults import counter_program, ended, step_under_way
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_submit

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

CLIENTS = 16
SUBMISSIONS = 200
# Each client's programs differ (so no check is answered from a cache), and every fifth has a
# syntax error, which V8 finds and the API reports with its place.
PROGRAM = """
var co2 = VV.sensor.get('CO2');
var n = {n};
VV.task.execute({{type: 'point', position: new VV.types.LatLngAlt(48.11, 12.86, 50),
                  tolerance: 2, sensors: [co2]}}, function (d) {{ VV.storage.store('n', n); }});
"""
BROKEN = "var n = {n};\nvar = ;\n"


def body(n: int) -> dict[str, str]:
    source = BROKEN if n % 5 == 0 else PROGRAM
    return {"name": f"Burst {n}", "program": source.format(n=n)}


def burst(url: str, tokens: list[str]) -> list[tuple[int, int, dict]]:
    """SUBMISSIONS submissions from CLIENTS concurrent clients (a session each, the customers'
    tokens by turns): (n, status, answer) of each."""

    def client(c: int) -> list[tuple[int, int, dict]]:
        api = requests.Session()
        api.headers["Authorization"] = f"Token {tokens[c % len(tokens)]}"
        out = []
        for n in range(c, SUBMISSIONS, CLIENTS):
            response = api.post(f"{url}/api/v1/vvs/", json=body(n), timeout=60)
            out.append((n, response.status_code, response.json()))
        return out

    with ThreadPoolExecutor(CLIENTS) as pool:
        return [answer for answers in pool.map(client, range(CLIENTS)) for answer in answers]


def assert_every_submission_answered(answers: list[tuple[int, int, dict]]) -> None:
    assert len(answers) == SUBMISSIONS
    for n, status, answer in answers:
        if n % 5 == 0:
            assert status == 400, (n, status, answer)
            assert "line 2" in json.dumps(answer), answer
        else:
            assert status in (201, 429), (n, status, answer)
    created = {a["name"] for n, status, a in answers if status == 201}
    assert created, "every submission was throttled: the burst tested nothing"
    assert set(VirtualVehicle.objects.values_list("name", flat=True)) == created


@pytest.fixture
def tokens(transactional_db: None) -> list[str]:
    customers = [CustomerFactory(name=f"Customer {c}") for c in "ABCD"]
    users = [UserFactory(username=f"customer-{c.name[-1].lower()}", customer=c) for c in customers]
    return [Token.objects.create(user=u).key for u in users]


def test_daphne_answers_every_concurrent_submission_and_stops_cleanly(web, tokens) -> None:
    web.start()
    answers = burst(web.url(""), tokens)
    assert_every_submission_answered(answers)
    listing = requests.get(
        web.url("/api/v1/vvs/"), headers={"Authorization": f"Token {tokens[0]}"}, timeout=30
    )
    assert listing.status_code == 200, "the server did not survive the burst"
    # Stopped while customers still submit: no crash, status 0.
    with ThreadPoolExecutor(4) as pool:
        pending = [pool.submit(burst_one, web.url(""), tokens[k], k) for k in range(4)]
        status = web.terminate()
        for future in pending:
            future.result()
    assert status == 0, web.log.read_text()[-3000:]
    assert "Fatal Python error" not in web.log.read_text()


def test_gunicorn_answers_every_concurrent_submission_and_stops_cleanly(web, tokens) -> None:
    # Production's HTTP (cpcc_site/gunicorn_conf.py): each worker process checks programs
    # with V8 and closes it when SIGTERM stops it.
    web.server = "gunicorn"
    web.start()
    assert_every_submission_answered(burst(web.url(""), tokens))
    with ThreadPoolExecutor(4) as pool:
        pending = [pool.submit(burst_one, web.url(""), tokens[k], k) for k in range(4)]
        status = web.terminate()
        for future in pending:
            future.result()
    log = web.log.read_text()
    assert status == 0, log[-3000:]
    assert "Fatal Python error" not in log and "was sent" not in log, log[-3000:]
    assert "exited with code" not in log or "exited with code 0" in log, log[-3000:]


def burst_one(url: str, token: str, k: int) -> None:
    """Submissions until the server is gone (its stop may cut one short)."""
    api = requests.Session()
    api.headers["Authorization"] = f"Token {token}"
    for n in range(50):
        try:
            api.post(f"{url}/api/v1/vvs/", json=body(1000 + 50 * k + n + 1), timeout=30)
        except requests.ConnectionError:
            return


def test_the_in_process_server_answers_every_concurrent_submission(
    live_server, tokens, broker_url
) -> None:
    answers = burst(live_server.url, tokens)
    assert_every_submission_answered(answers)


def test_workers_stopped_with_sigterm_mid_mission_exit_0_and_the_vvs_finish_after_a_restart(
    workers, tmp_path, monkeypatch
) -> None:
    load("paper-fig3.json", tmp_path, monkeypatch)
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    workers.start("gsworker", "GS Base")
    wait_mid_mission(workers)
    statuses = {name: workers.terminate(name) for name in ("Heli One", "Heli Two", "GS Base")}
    logs = workers.logs()
    assert statuses == {"Heli One": 0, "Heli Two": 0, "GS Base": 0}, logs
    assert "Fatal Python error" not in logs
    # The operator sees at once that nobody drives the RVs.
    assert {v.health.get("worker") for v in Vehicle.objects.all()} == {"stopped"}
    assert not all_ended(), "the mission ended before the stop: it tested nothing"
    assert VirtualVehicle.objects.filter(status=VVStatus.FINISHED).count() < 3
    workers.start("rvworker", "Heli One")
    workers.start("rvworker", "Heli Two")
    workers.start("gsworker", "GS Base")
    wait_until(
        all_ended, timeout=180, what="the VVs to end after the restart", details=workers.logs
    )
    assert_paper_results()


def test_an_rv_worker_stopped_with_sigterm_in_the_middle_of_steps_exits_0(
    broker_url, tmp_path
) -> None:
    """Instant flights and steps that compute for a while: the stop comes while V8 runs."""
    GroundStationFactory(name="GS Base")
    VehicleFactory(name="Heli One", area=AREA_ONE)
    customers = [CustomerFactory(name="Customer A"), CustomerFactory(name="Customer B")]
    vvm = platform_vvm()
    vvs = [
        # Work enough for three stops however fast the worker gets through it.
        vv_submit(customer=c, name=f"Counter {k}", program=counter_program(24), vvm=vvm, seed=k)
        for c in customers
        for k in range(2)
    ]
    pool = Workers(tmp_path, broker_url, speed=0)
    try:
        pool.start("gsworker", "GS Base")
        for stop in range(3):
            pool.start("rvworker", "Heli One")
            wait_until(
                lambda: step_under_way() or ended(*vvs),
                timeout=60,
                what="a step under way on Heli One",
                details=pool.logs,
            )
            assert not ended(*vvs), "the VVs ended before the stop: it tested nothing"
            status = pool.terminate("Heli One")
            assert status == 0, (stop, pool.logs())
        pool.start("rvworker", "Heli One")
        wait_until(lambda: ended(*vvs), timeout=180, what="the VVs to end", details=pool.logs)
        assert pool.terminate("GS Base") == 0
        assert pool.terminate("Heli One") == 0
        logs = pool.logs()
    finally:
        pool.stop_all()
    assert "Fatal Python error" not in logs
    for vv in vvs:
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error


@pytest.mark.parametrize("after_s", [0.0, 0.2, 0.5])
def test_a_worker_stopped_with_sigterm_while_celery_starts_exits_0(
    broker_url, tmp_path, after_s
) -> None:
    """A stop that comes as the worker has taken up its work and Celery is starting (before
    Celery's own signal handlers, or just after) ends it like any other."""
    VehicleFactory(name="Heli One", area=AREA_ONE)
    VehicleFactory(name="Heli Two", area=AREA_ONE, depot_lng=12.862)
    pool = Workers(tmp_path, broker_url, speed=0)
    try:
        pool.start("rvworker", "Heli One", "Heli Two")  # returns as Celery starts
        time.sleep(after_s)  # the moment of the stop is what is tested, not a wait for it
        assert pool.terminate("Heli One", timeout=20) == 0
    finally:
        pool.stop_all()
