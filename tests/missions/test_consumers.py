"""The live map's socket (/ws/map/): who may open it and what each user is sent."""

from __future__ import annotations

import time

import pytest
from channels.testing import WebsocketCommunicator

from cpcc_site.asgi import application
from missions.events import EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH
from tests.factories import VehicleFactory
from vvm_worker.live import FeedAnnouncer, publish_vehicle
from vvm_worker.services import vv_cancel, vv_submit

# Committed data (the socket reads the database from another thread); the default SDC (a data
# migration) must be back for the tests that run after these.
pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

PROGRAM = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                 tolerance: 2, sensors: [co2]});
"""


@pytest.fixture(autouse=True)
async def _close_socket_connections():
    """The sockets read the database in a worker thread: close its connection after each test,
    or PostgreSQL refuses to drop the test database at the end of the run."""
    yield
    from channels.db import database_sync_to_async
    from django.db import connections

    await database_sync_to_async(connections.close_all)()


@pytest.fixture(autouse=True)
def feed(broker):
    """The test run's Redis carries the feed; empty before each test."""
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)
    yield broker
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)


@pytest.fixture
def announcing(vvm_factory):
    vvm = vvm_factory()
    vvm.announcer = FeedAnnouncer()
    return vvm


def _socket(
    client,
    path: str = "/ws/map/",
    origin: bytes = b"http://testserver",
    host: bytes = b"testserver",
    **extra: bytes,
) -> WebsocketCommunicator:
    """A socket as a page of the site opens it: the Host header names the site, the Origin
    header the page's origin; ``extra`` headers by name (``x_forwarded_proto``)."""
    headers = [(b"host", host), (b"origin", origin)]
    headers += [(name.replace("_", "-").encode(), value) for name, value in extra.items()]
    cookie = client.cookies.get("sessionid")
    if cookie is not None:
        headers.append((b"cookie", f"sessionid={cookie.value}".encode()))
    return WebsocketCommunicator(application, path, headers=headers)


async def _frames_until(socket, predicate, timeout_s: float = 5.0) -> list[dict]:
    """Frames received until one satisfies predicate (every frame checked, none skipped)."""
    frames = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        frame = await socket.receive_json_from(timeout=timeout_s)
        frames.append(frame)
        if predicate(frame):
            return frames
    raise AssertionError(f"no such frame within {timeout_s} s: {frames[-3:]}")


def _carrier_state(vehicle, vvs) -> dict:
    return {
        "id": vehicle.pk,
        "name": vehicle.name,
        "lat": 48.111,
        "lng": 12.862,
        "alt": 50.0,
        "phase": "cruise",
        "status": "active",
        "battery": None,
        "vvs": [{"id": str(vv.pk), "name": vv.name, "customer": vv.customer_id} for vv in vvs],
        "route": [[48.111, 12.862], [48.1111, 12.8619]],
        "t": time.time(),
    }


async def test_an_anonymous_socket_is_refused(client) -> None:
    socket = _socket(client)
    connected, code = await socket.connect()
    assert not connected and code == 4403


async def test_a_user_of_no_customer_is_refused(client, django_user_model) -> None:
    from asgiref.sync import sync_to_async

    nobody = await sync_to_async(django_user_model.objects.create_user)("nobody", password="x")
    await sync_to_async(client.force_login)(nobody)
    connected, code = await _socket(client).connect()
    assert not connected and code == 4403


async def test_a_customer_never_receives_another_customers_vvs_tasks_or_vehicles(
    client, user_a, customer_a, customer_b, ground_station, announcing
) -> None:
    from asgiref.sync import sync_to_async

    mine = await sync_to_async(vv_submit)(
        customer=customer_a, name="mine", program=PROGRAM, vvm=announcing
    )
    theirs = await sync_to_async(vv_submit)(
        customer=customer_b, name="theirs", program=PROGRAM, vvm=announcing
    )
    heli = await sync_to_async(VehicleFactory)(name="Heli One")
    other = await sync_to_async(VehicleFactory)(name="Heli Two")
    await sync_to_async(client.force_login)(user_a)
    socket = _socket(client)
    connected, _ = await socket.connect()
    assert connected
    snapshot = await socket.receive_json_from(timeout=5)
    assert snapshot["type"] == "snapshot" and snapshot["staff"] is False
    assert [vv["name"] for vv in snapshot["vvs"]] == ["mine"]
    assert "Heli" not in str(snapshot) and "GS Base" not in str(snapshot)
    assert all(set(area) == {"area"} for area in snapshot["areas"])

    publish_vehicle(_carrier_state(heli, [mine, theirs]))
    publish_vehicle(_carrier_state(other, [theirs]))
    await sync_to_async(vv_cancel)(vv_id=theirs.pk, vvm=announcing)
    await sync_to_async(vv_cancel)(vv_id=mine.pk, vvm=announcing)
    frames = await _frames_until(
        socket,
        lambda f: any(
            e.get("vv") == str(mine.pk) and e.get("status") == "cancelled"
            for e in f.get("events", ())
        ),
    )
    seen = str(frames)
    assert str(theirs.pk) not in seen and "theirs" not in seen
    assert "Heli" not in seen and "GS Base" not in seen
    carriers = [v for f in frames for v in f.get("vehicles", ())]
    assert carriers, "the vehicle carrying my VV is shown"
    assert {v["id"] for v in carriers} == {carriers[0]["id"]} and carriers[0]["id"].startswith("c")
    assert all(
        v["vvs"] == [{"id": str(mine.pk), "name": "mine", "customer": customer_a.pk}]
        for v in carriers
    )
    assert all("route" not in v and "name" not in v for v in carriers)
    seqs = [f["seq"] for f in [snapshot, *frames]]
    assert seqs == list(range(1, len(seqs) + 1))
    await socket.disconnect()


async def test_a_staff_socket_sees_every_vv_vehicle_and_name(
    client, staff, customer_a, customer_b, ground_station, announcing
) -> None:
    from asgiref.sync import sync_to_async

    vvs = [
        await sync_to_async(vv_submit)(customer=c, name=n, program=PROGRAM, vvm=announcing)
        for c, n in [(customer_a, "mine"), (customer_b, "theirs")]
    ]
    heli = await sync_to_async(VehicleFactory)(name="Heli One")
    await sync_to_async(client.force_login)(staff)
    socket = _socket(client)
    assert (await socket.connect())[0]
    snapshot = await socket.receive_json_from(timeout=5)
    assert snapshot["staff"] is True
    assert sorted(vv["name"] for vv in snapshot["vvs"]) == ["mine", "theirs"]
    assert [a["name"] for a in snapshot["areas"]] == ["Heli One"]
    assert [s["name"] for s in snapshot["stations"]] == ["GS Base"]
    publish_vehicle(_carrier_state(heli, vvs))
    for vv in vvs:
        await sync_to_async(vv_cancel)(vv_id=vv.pk, vvm=announcing)
    frames = await _frames_until(
        socket,
        lambda f: (
            {e["vv"] for e in f.get("events", ()) if e.get("status") == "cancelled"}
            == {str(vv.pk) for vv in vvs}
        ),
    )
    vehicles = [v for f in frames for v in f["vehicles"]]
    assert vehicles[0]["name"] == "Heli One" and len(vehicles[0]["vvs"]) == 2
    assert vehicles[0]["route"][-1] == [48.1111, 12.8619]
    await socket.disconnect()


async def test_another_customers_vv_cannot_be_followed(
    client, user_b, customer_a, ground_station, announcing
) -> None:
    from asgiref.sync import sync_to_async

    vv = await sync_to_async(vv_submit)(
        customer=customer_a, name="mine", program=PROGRAM, vvm=announcing
    )
    await sync_to_async(client.force_login)(user_b)
    connected, code = await _socket(client, f"/ws/map/?vv={vv.pk}").connect()
    assert not connected and code == 4404


async def test_a_socket_from_another_site_is_refused(client, user_a) -> None:
    from asgiref.sync import sync_to_async

    await sync_to_async(client.force_login)(user_a)
    socket = WebsocketCommunicator(
        application,
        "/ws/map/",
        headers=[
            (b"host", b"testserver"),
            (b"origin", b"http://evil.example"),
            (b"cookie", f"sessionid={client.cookies['sessionid'].value}".encode()),
        ],
    )
    connected, _ = await socket.connect()
    assert not connected


async def _opens(socket: WebsocketCommunicator) -> bool:
    connected, _ = await socket.connect()
    if connected:
        await socket.receive_json_from(timeout=5)  # the snapshot
        await socket.disconnect()
    return connected


async def test_only_the_sites_own_origin_opens_a_socket_scheme_host_and_port(
    client, user_a, user_b
) -> None:
    """A page served by another program on the same host (another port) or over the other
    scheme is another site: its sockets are refused for every user."""
    from asgiref.sync import sync_to_async

    for user in (user_a, user_b):
        await sync_to_async(client.force_login)(user)
        site = {"host": b"testserver:8000"}
        assert await _opens(_socket(client, origin=b"http://testserver:8000", **site))
        for origin in (
            b"http://testserver:9999",
            b"http://testserver",
            b"https://testserver:8000",
            b"http://testserver:8000.evil.example",
            b"http://evil.example:8000",
            b"null",
            b"",
        ):
            assert not await _opens(_socket(client, origin=origin, **site)), origin
        # A Host header that ALLOWED_HOSTS does not list is no site of ours, whatever the
        # origin says.
        forged = _socket(client, origin=b"http://evil.example", host=b"evil.example")
        assert not await _opens(forged)
        # No Origin header at all (not a browser's page): refused.
        bare = WebsocketCommunicator(
            application,
            "/ws/map/",
            headers=[
                (b"host", b"testserver"),
                (b"cookie", f"sessionid={client.cookies['sessionid'].value}".encode()),
            ],
        )
        assert not (await bare.connect())[0]


async def test_an_origin_behind_a_proxy_is_the_sites_when_trusted_or_forwarded_as_https(
    client, user_a, user_b, settings
) -> None:
    from asgiref.sync import sync_to_async

    await sync_to_async(client.force_login)(user_b)
    site = {"host": b"testserver"}
    public = b"https://cpcc.example.com"
    assert not await _opens(_socket(client, origin=public, **site))
    settings.CSRF_TRUSTED_ORIGINS = ["https://cpcc.example.com"]
    assert await _opens(_socket(client, origin=public, **site))
    assert not await _opens(_socket(client, origin=b"http://cpcc.example.com", **site))
    assert not await _opens(_socket(client, origin=b"https://cpcc.example.com:8443", **site))
    settings.CSRF_TRUSTED_ORIGINS = ["https://*.example.com"]
    assert await _opens(_socket(client, origin=b"https://map.example.com", **site))
    assert not await _opens(_socket(client, origin=b"https://example.org", **site))
    # A proxy that ends TLS says so in the header SECURE_PROXY_SSL_HEADER names: the site's
    # own origin is then https.
    settings.CSRF_TRUSTED_ORIGINS = []
    settings.SECURE_PROXY_SSL_HEADER = ("HTTP_X_FORWARDED_PROTO", "https")
    await sync_to_async(client.force_login)(user_a)
    forwarded = {"host": b"testserver", "x_forwarded_proto": b"https"}
    assert await _opens(_socket(client, origin=b"https://testserver", **forwarded))
    assert not await _opens(_socket(client, origin=b"http://testserver", **forwarded))
    assert await _opens(_socket(client, origin=b"http://testserver", **site))


async def test_a_message_nested_too_deep_or_not_json_answers_an_error_frame(
    client, user_a, user_b
) -> None:
    from asgiref.sync import sync_to_async

    for user in (user_a, user_b):
        await sync_to_async(client.force_login)(user)
        socket = _socket(client)
        assert (await socket.connect())[0]
        assert (await socket.receive_json_from(timeout=5))["type"] == "snapshot"
        for text in ("[" * 5_000 + "]" * 5_000, '{"type": ' * 101 + "1" + "}" * 101):
            await socket.send_to(text_data=text)
            error = await socket.receive_json_from(timeout=5)
            assert error["type"] == "error"
            assert "nested more than 100 levels" in error["detail"]
        await socket.send_to(text_data="resync, please")
        assert "not JSON" in (await socket.receive_json_from(timeout=5))["detail"]
        # The socket is still there and answers a proper message.
        await socket.send_json_to({"type": "resync"})
        assert (await socket.receive_json_from(timeout=5))["type"] == "snapshot"
        await socket.disconnect()


async def test_a_browser_that_asks_to_resync_gets_the_whole_state_again(
    client, user_a, customer_a, ground_station, announcing
) -> None:
    from asgiref.sync import sync_to_async

    await sync_to_async(client.force_login)(user_a)
    socket = _socket(client)
    assert (await socket.connect())[0]
    first = await socket.receive_json_from(timeout=5)
    assert first["type"] == "snapshot" and first["vvs"] == []
    vv = await sync_to_async(vv_submit)(
        customer=customer_a, name="later", program=PROGRAM, vvm=announcing
    )
    await socket.send_json_to({"type": "resync"})
    frames = await _frames_until(socket, lambda f: f["type"] == "snapshot")
    again = frames[-1]
    assert [v["vv"] for v in again["vvs"]] == [str(vv.pk)]
    assert again["seq"] == first["seq"] + len(frames), "numbered on from the first snapshot"
    await socket.disconnect()


async def test_a_snapshot_says_the_time_on_the_platforms_clock(client, user_a) -> None:
    """The page's time window counts back from it (static/js/map.js), not from the browser's
    clock, which may be wrong."""
    from asgiref.sync import sync_to_async

    await sync_to_async(client.force_login)(user_a)
    socket = _socket(client)
    assert (await socket.connect())[0]
    before = time.time()
    snapshot = await socket.receive_json_from(timeout=5)
    assert snapshot["type"] == "snapshot"
    assert before - 5.0 <= snapshot["now"] <= time.time()
    await socket.disconnect()
