"""Customer pages: one's own VVs only, with their tasks, storage, log and pictures, and never the
vehicles that serve them; anyone else is refused, and pictures are only served through the
REST API to their owner, never by their path under /media/."""

from __future__ import annotations

import html
import importlib
from pathlib import Path

import pytest
from django.conf import settings as django_settings
from django.urls import clear_url_caches, reverse

import cpcc_site.urls
from missions.models import VirtualVehicle, VVStatus
from missions.readings import image_file, image_references
from tests.api_fixtures import MISSION, MISSION_KEYS
from tests.factories import UserFactory
from vvm_worker.services import vv_submit

# Names of the fleet that serves the VVs of these tests (tests.api_fixtures.fleet_one and the
# ground_station fixture): a customer's page must name neither.
FLEET_NAMES = ("Heli One", "GS Base")


@pytest.fixture
def vv_a(customer_a, ground_station, vvm_factory):
    return vv_submit(customer=customer_a, name="Alpha VV", program="var a = 1;", vvm=vvm_factory())


@pytest.fixture
def vv_b(customer_b, ground_station, vvm_factory):
    return vv_submit(customer=customer_b, name="Bravo VV", program="var b = 1;", vvm=vvm_factory())


@pytest.fixture
def nobody(db):
    """A user who logs in but belongs to no customer and is not staff."""
    return UserFactory(username="nobody")


def page_of(client, vv) -> str:
    response = client.get(reverse("vv-detail", args=[vv.pk]))
    assert response.status_code == 200
    return html.unescape(response.text)


def test_pages_need_a_login(client, vv_a) -> None:
    for url in (reverse("home"), reverse("vv-detail", args=[vv_a.pk])):
        response = client.get(url)
        assert response.status_code == 302, url
        assert response["Location"].startswith("/accounts/login/?next=")
        assert "Alpha VV" not in response.text


def test_a_user_of_no_customer_is_refused(client, nobody, vv_a) -> None:
    client.force_login(nobody)
    for url in (reverse("home"), reverse("vv-detail", args=[vv_a.pk])):
        response = client.get(url)
        assert response.status_code == 403, url
        assert "Alpha VV" not in response.text


def test_login_page_loads(client, db) -> None:
    response = client.get("/accounts/login/")
    assert response.status_code == 200
    assert 'name="username"' in response.text and 'name="password"' in response.text


def test_a_customer_sees_only_its_own_vvs(client, user_a, vv_a, vv_b) -> None:
    client.force_login(user_a)
    page = client.get(reverse("home")).text
    assert "Alpha VV" in page and "Bravo VV" not in page
    assert "Alpha VV" in page_of(client, vv_a)


def test_another_customers_vv_is_not_found(client, user_a, vv_b) -> None:
    client.force_login(user_a)
    response = client.get(reverse("vv-detail", args=[vv_b.pk]))
    assert response.status_code == 404
    assert "Bravo VV" not in response.text


def test_staff_see_every_vv(client, staff, vv_a, vv_b) -> None:
    client.force_login(staff)
    page = client.get(reverse("home")).text
    assert "Alpha VV" in page and "Bravo VV" in page


def test_the_vv_page_shows_the_owners_tasks_storage_and_log(client, user_a, mission) -> None:
    client.force_login(user_a)
    page = page_of(client, mission)
    assert "Survey" in page and "Finished" in page
    tasks = list(mission.tasks.order_by("q", "index"))
    assert [t.status for t in tasks] == ["rejected", "done", "done"]
    for task in tasks:
        assert f"{task.lat:.6f}, {task.lng:.6f}, {task.alt:.1f} m" in page
    assert "Rejected: no vehicle can serve the task at" in page  # and why
    assert page.count(">Done<") == 2
    for doc in mission.storage.all():
        assert f"<td>{doc.key}</td>" in page
    assert len(MISSION_KEYS) == mission.storage.count()
    assert "<code>42</code>" in page  # 'plain key'
    co2 = mission.storage.get(key="p0.co2").value
    assert f'"value": {co2["value"]}' in page and '"unit": "ppm"' in page
    for line in ("rejected: TaskRejectedError", "done: 6 keys"):
        assert line in page
        assert line in mission.log.values_list("message", flat=True)


def test_the_vv_page_names_no_vehicle_or_ground_station(
    client, user_a, staff, platform, fleet_one, customer_a
) -> None:
    vv = vv_submit(customer=customer_a, name="Survey", program=MISSION, vvm=platform.vvm)
    # Stop while the VV is aboard Heli One with a task assigned to it.
    platform.drain(
        until=lambda: VirtualVehicle.objects.filter(
            pk=vv.pk, host_rv=fleet_one, tasks__vehicle=fleet_one, tasks__status="open"
        ).exists()
    )
    client.force_login(staff)
    assert "Heli One" in client.get(reverse("home")).text  # the name is there to be shown...
    client.force_login(user_a)
    in_flight = page_of(client, vv)
    home = client.get(reverse("home")).text
    assert "Running" in in_flight and "in flight" in home
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED
    assert vv.tasks.filter(vehicle=fleet_one).count() == 2
    finished = page_of(client, vv)
    assert "Finished" in finished
    for name in FLEET_NAMES:  # ...but not to a customer, neither in flight nor after
        for page in (in_flight, home, finished):
            assert name not in page


def test_the_vv_page_links_its_pictures_to_the_api_for_their_owner_only(
    client, user_a, user_b, nobody, mission
) -> None:
    client.force_login(user_a)
    page = page_of(client, mission)
    readings = [t.readings for t in mission.tasks.filter(status="done")]
    files = {image_file(ref) for r in readings for ref in image_references(r)}
    assert len(files) == 2
    urls = {f"/api/v1/vvs/{mission.pk}/images/{file}" for file in files}
    for url in urls:
        assert f'href="{url}"' in page and f'src="{url}"' in page
    assert "/media/" not in page
    for url in urls:  # the owner's session opens them
        response = client.get(url)
        assert response.status_code == 200 and response["Content-Type"] == "image/png"
        assert b"".join(response.streaming_content).startswith(b"\x89PNG")
    for other in (user_b, nobody):
        client.force_login(other)
        for url in urls:
            assert client.get(url).status_code == 404
    client.logout()
    for url in urls:
        assert client.get(url).status_code in (401, 403)


@pytest.fixture
def routes_built_with_debug(settings):
    """Builds the site's URL routes again, as at start-up, with DEBUG on or off."""
    original = django_settings.DEBUG

    def build(debug: bool) -> None:
        settings.DEBUG = debug
        importlib.reload(cpcc_site.urls)
        clear_url_caches()

    yield build
    settings.DEBUG = original
    importlib.reload(cpcc_site.urls)
    clear_url_caches()


@pytest.mark.parametrize("debug", [True, False], ids=["debug", "production"])
def test_pictures_under_media_are_served_to_nobody(
    client, user_a, user_b, mission, routes_built_with_debug, debug
) -> None:
    routes_built_with_debug(debug)
    references = {ref for t in mission.tasks.all() for ref in image_references(t.readings)}
    assert references
    for reference in references:
        assert (Path(django_settings.MEDIA_ROOT) / reference).is_file()
        url = f"{django_settings.MEDIA_URL}{reference}"
        client.logout()
        assert client.get(url).status_code == 404, "an anonymous user got a picture"
        client.force_login(user_b)
        assert client.get(url).status_code == 404, "another customer got a picture"
        client.force_login(user_a)  # even the owner: the API serves pictures, not /media/
        assert client.get(url).status_code == 404
