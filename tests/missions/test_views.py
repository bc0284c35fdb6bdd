"""Customer pages: one's own VVs only, with their tasks, storage, log and pictures, and never the
vehicles that serve them; anyone else is refused, and pictures are only served through the
REST API to their owner, never by their path under /media/."""

from __future__ import annotations

import html
import importlib
import json
import re
from datetime import UTC, datetime
from pathlib import Path

import pytest
from django.conf import settings as django_settings
from django.urls import clear_url_caches, reverse

import cpcc_site.urls
from missions.models import Task, VirtualVehicle, VVStatus
from missions.readings import image_file, image_references
from missions.views import chart_series
from tests.api_fixtures import MISSION, MISSION_KEYS
from tests.factories import UserFactory
from vvm_worker.services import vv_create_copies_for_user, vv_submit

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
    assert ">Rejected</span>" in page
    assert f'<span class="sub">{tasks[0].message}</span>' in page  # and why
    assert tasks[0].message.startswith("no vehicle can serve the task at")
    assert page.count(">Done<") == 2
    for doc in mission.storage.all():
        assert f'<td class="key">{doc.key}</td>' in page
    assert len(MISSION_KEYS) == mission.storage.count()
    assert '<pre class="json">42</pre>' in page  # 'plain key': any other JSON, pretty-printed
    for line in ("rejected: TaskRejectedError", "done: 6 keys"):
        assert line in page
        assert line in mission.log.values_list("message", flat=True)


def test_the_vv_page_formats_readings_by_kind(client, user_a, mission) -> None:
    client.force_login(user_a)
    page = page_of(client, mission)
    co2 = mission.storage.get(key="p0.co2").value
    # A scalar reading: its value and unit, and the sensor.
    assert f"<strong>{co2['value']:.6g} ppm</strong>" in page
    row = page[page.index('<td class="key">p0.co2</td>') :].split("</tr>")[0]
    assert "CO2" in row and co2["time"] in row
    # A camera reading: a thumbnail that opens the full-size picture (through the API).
    camera = mission.storage.get(key="p0.camera").value
    url = f"/api/v1/vvs/{mission.pk}/images/{image_file(camera['image'])}"
    row = page[page.index('<td class="key">p0.camera</td>') :].split("</tr>")[0]
    assert f'<a class="thumb" href="{url}"' in row and f'<img src="{url}"' in row
    # Other JSON, with readings inside it: pretty-printed, and their pictures as thumbnails.
    nested = mission.storage.get(key="all/readings").value
    row = page[page.index('<td class="key">all/readings</td>') :].split("</tr>")[0]
    assert json.dumps(nested, ensure_ascii=False, indent=2) in row
    assert row.count('<a class="thumb"') == 2


def test_a_gps_reading_shows_latitude_longitude_and_altitude(client, user_a, vv_a) -> None:
    from missions.models import StorageDocument

    fix = {
        "sensor": "GPS",
        "kind": "gps",
        "lat": 48.11112,
        "lng": 12.86191,
        "alt": 49.96,
        "satellites": 9,
        "hdop": 0.8,
        "time": "2025-01-01T00:01:00.000Z",
    }
    StorageDocument.objects.create(vv=vv_a, key="fix", value=fix, size_bytes=10, updated_s=1)
    client.force_login(user_a)
    assert "<strong>48.111120, 12.861910, 50.0 m</strong>" in page_of(client, vv_a)


def test_the_chart_has_one_series_per_scalar_sensor_against_the_time_of_its_readings(
    client, user_a, mission
) -> None:
    client.force_login(user_a)
    page = client.get(reverse("vv-detail", args=[mission.pk])).text
    data = re.search(r'<script id="chart-data" type="application/json">(.*?)</script>', page)
    series = json.loads(data.group(1))
    tasks = list(mission.tasks.order_by("q", "index"))
    co2 = [t.readings[1] for t in tasks if t.status == "done"]

    def epoch_ms(reading: dict) -> int:
        return round(datetime.fromisoformat(reading["time"]).timestamp() * 1000)

    # The rejected first task has no reading: the chart's points are the readings of tasks 2
    # and 3, at the times they were taken (epoch milliseconds), labelled with their task.
    assert series == [
        {
            "sensor": "CO2",
            "unit": "ppm",
            "points": [
                [epoch_ms(co2[0]), co2[0]["value"], str(tasks[1].q)],
                [epoch_ms(co2[1]), co2[1]["value"], str(tasks[2].q)],
            ],
        }
    ]
    assert epoch_ms(co2[0]) < epoch_ms(co2[1])
    assert "/static/vendor/chartjs/chart.umd.min.js" in page


def test_the_chart_plots_a_batch_in_the_order_its_readings_were_taken() -> None:
    def task(q: int, index: int, time: str, value: float) -> Task:
        reading = {"sensor": "CO2", "kind": "scalar", "time": time, "value": value, "unit": "ppm"}
        return Task(q=q, index=index, readings=[reading])

    # An executeAll batch: its second task was served first.
    (series,) = chart_series(
        [task(4, 0, "2025-01-01T00:02:00.500Z", 1.0), task(4, 1, "2025-01-01T00:01:00Z", 2.0)]
    )
    start = datetime(2025, 1, 1, tzinfo=UTC).timestamp() * 1000
    assert series["points"] == [[start + 60_000, 2.0, "4.1"], [start + 120_500, 1.0, "4"]]


def test_the_vv_page_offers_the_downloads_and_its_replay(client, user_a, mission) -> None:
    client.force_login(user_a)
    page = client.get(reverse("vv-detail", args=[mission.pk])).text
    assert f'href="/api/v1/vvs/{mission.pk}/results.zip"' in page
    assert f'href="/vvs/{mission.pk}/storage.json"' in page
    assert 'data-mode="replay"' in page and f'data-history="/vvs/{mission.pk}/map.json"' in page
    assert 'id="replay-time"' in page
    zipped = client.get(f"/api/v1/vvs/{mission.pk}/results.zip")  # the session opens it
    assert zipped.status_code == 200 and zipped["Content-Type"] == "application/zip"


def test_a_running_vv_page_shows_its_mission_live(client, user_a, vv_a) -> None:
    client.force_login(user_a)
    page = client.get(reverse("vv-detail", args=[vv_a.pk])).text
    assert 'data-mode="live"' in page and f'data-socket="/ws/map/?vv={vv_a.pk}"' in page
    assert 'id="replay-time"' not in page


def test_the_storage_downloads_as_json_for_its_owner_only(client, user_a, user_b, mission) -> None:
    client.force_login(user_a)
    response = client.get(reverse("vv-storage-json", args=[mission.pk]))
    assert response.status_code == 200
    assert response["Content-Type"] == "application/json"
    assert response["Content-Disposition"].startswith('attachment; filename="survey-')
    storage = json.loads(response.content)
    assert sorted(storage) == MISSION_KEYS
    assert storage["plain key"] == 42
    camera = storage["p0.camera"]
    assert camera["image_url"] == (
        f"http://testserver/api/v1/vvs/{mission.pk}/images/{image_file(camera['image'])}"
    )
    assert storage["all/readings"]["points"][0]["image_url"] == camera["image_url"]
    client.force_login(user_b)
    assert client.get(reverse("vv-storage-json", args=[mission.pk])).status_code == 404


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


# --- the dashboard ----------------------------------------------------------------------------


@pytest.fixture
def page_vvm(monkeypatch, vvm_factory):
    """The VVM the pages' actions use: a recording dispatcher instead of Celery."""
    import missions.views

    vvm = vvm_factory()
    monkeypatch.setattr(missions.views, "platform_vvm", lambda: vvm)
    return vvm


def row_of(page: str, vv) -> str:
    start = page.index(f'<tr data-vv="{vv.pk}"')
    return page[start : page.index("</tr>", start)]


def test_the_dashboard_shows_each_vv_with_where_it_is_tasks_and_actions(
    client, user_a, customer_a, mission, page_vvm
) -> None:
    queued, _ = vv_create_copies_for_user(
        user=user_a, name="Waiting", program="VV.log(1);", copies=1, vvm=page_vvm
    )
    client.force_login(user_a)
    page = html.unescape(client.get(reverse("home")).text)
    finished = row_of(page, mission)
    assert ">Finished</span>" in finished and "at a ground station" in finished
    assert re.search(r'<td class="num tasks-done"[^>]*>2</td>', finished)
    assert re.search(r'<td class="num tasks-open"[^>]*>0</td>', finished)
    assert f'action="/vvs/{mission.pk}/restart/"' in finished
    assert "/cancel/" not in finished and "/edit/" not in finished
    waiting = row_of(page, queued[0])
    assert ">Queued</span>" in waiting and re.search(r'<td class="where"[^>]*>queued</td>', waiting)
    assert f'href="/vvs/{queued[0].pk}/edit/"' in waiting
    assert f'action="/vvs/{queued[0].pk}/cancel/"' in waiting
    assert "/restart/" not in waiting
    # Live: the page listens on the map's socket and fetches its rows again.
    assert 'data-socket="/ws/map/"' in page and 'data-rows-url="/vvs/rows/"' in page
    assert "/static/js/dashboard.js" in page


def test_the_dashboard_rows_alone_are_the_users_own(client, user_a, user_b, vv_a, vv_b) -> None:
    client.force_login(user_b)
    rows = client.get(reverse("vv-rows")).text
    assert "Bravo VV" in rows and "Alpha VV" not in rows
    assert "<html" not in rows
    assert client.get(reverse("vv-rows")).status_code == 200
    client.logout()
    assert client.get(reverse("vv-rows")).status_code == 302


def test_the_dashboard_filters_by_status(client, user_a, vv_a, customer_a, vvm_factory) -> None:
    from vvm_worker.services import vv_cancel

    ended = vv_submit(customer=customer_a, name="Old VV", program="var c;", vvm=vvm_factory())
    vv_cancel(vv_id=ended.pk, vvm=vvm_factory())
    client.force_login(user_a)
    active = client.get(reverse("home") + "?show=active").text
    assert "Alpha VV" in active and "Old VV" not in active
    done = client.get(reverse("vv-rows") + "?show=ended").text
    assert "Old VV" in done and "Alpha VV" not in done


def test_staff_see_the_customer_and_the_host_of_every_vv(client, staff, vv_a, vv_b) -> None:
    client.force_login(staff)
    page = client.get(reverse("home")).text
    assert "<th>Customer</th>" in page
    assert "Customer A" in row_of(page, vv_a) and "Customer B" in row_of(page, vv_b)
    assert "GS Base (ground station)" in row_of(page, vv_a)


# --- navigation and accounts ------------------------------------------------------------------


def test_every_page_has_the_same_navigation(client, user_a, vv_a) -> None:
    client.force_login(user_a)
    for url in (
        reverse("home"),
        reverse("vv-new"),
        reverse("vv-detail", args=[vv_a.pk]),
        reverse("map"),
        reverse("password_change"),
    ):
        page = client.get(url).text
        assert '<link rel="stylesheet" href="/static/css/cpcc.css">' in page, url
        nav = page[page.index('<nav id="site-nav"') : page.index("</nav>")]
        for href, text in (
            ("/", "Dashboard"),
            ("/vvs/new/", "New VV"),
            ("/map/", "Map"),
            ("/api/docs/", "API docs"),
            ("/accounts/password_change/", "Password"),
        ):
            assert re.search(rf'<a href="{href}"[^>]*>{text}</a>', nav), (url, text)
        assert 'href="/admin/"' not in nav  # staff only
        logout = nav[nav.index('action="/accounts/logout/"') - 40 :]
        assert 'method="post"' in logout and "csrfmiddlewaretoken" in logout


def test_staff_navigation_has_the_admin_and_no_new_vv(client, staff) -> None:
    client.force_login(staff)
    page = client.get(reverse("home")).text
    nav = page[page.index('<nav id="site-nav"') : page.index("</nav>")]
    assert 'href="/admin/"' in nav and 'href="/vvs/new/"' not in nav


def test_the_login_page_is_styled_like_the_rest(client, db) -> None:
    page = client.get("/accounts/login/").text
    assert "/static/css/cpcc.css" in page and 'class="card auth"' in page


def test_a_user_changes_their_password(client, user_a) -> None:
    client.force_login(user_a)
    page = client.get("/accounts/password_change/").text
    assert 'class="card auth"' in page and 'name="old_password"' in page
    response = client.post(
        "/accounts/password_change/",
        {
            "old_password": "secret-pass-123",
            "new_password1": "a-new-pass-456",
            "new_password2": "a-new-pass-456",
        },
    )
    assert response.status_code == 302 and response["Location"] == "/accounts/password_change/done/"
    assert "Password changed" in client.get(response["Location"]).text
    user_a.refresh_from_db()
    assert user_a.check_password("a-new-pass-456")


# --- the program editor -----------------------------------------------------------------------

BROKEN = "var a = 1;\nvar b = ;\n"  # line 2, column 9
FINE = "VV.log('hello');\n"


def test_the_check_answers_like_the_api(client, user_a, db) -> None:
    client.force_login(user_a)
    url = reverse("vv-check")
    good = client.post(url, {"program": FINE}, content_type="application/json")
    assert good.status_code == 200 and good.json() == {"ok": True}
    bad = client.post(url, {"program": BROKEN}, content_type="application/json")
    answer = bad.json()
    assert (answer["ok"], answer["line"], answer["column"]) == (False, 2, 9)
    assert answer["message"].startswith("SyntaxError")
    assert answer["error"] == f"line 2, column 9: {answer['message']}"
    form = client.post(url, {"program": BROKEN})  # form data works too
    assert form.json()["line"] == 2
    assert not VirtualVehicle.objects.exists()


def test_the_check_needs_a_login_a_post_and_the_csrf_token(client, user_a, db) -> None:
    from django.test import Client

    url = reverse("vv-check")
    assert client.post(url, {"program": FINE}).status_code == 302  # to the login page
    client.force_login(user_a)
    assert client.get(url).status_code == 405
    assert client.post(url, {"nothing": 1}).status_code == 400
    strict = Client(enforce_csrf_checks=True)
    strict.force_login(user_a)
    assert strict.post(url, {"program": FINE}).status_code == 403


def test_the_editor_has_highlighting_check_file_upload_and_copies(client, user_a) -> None:
    client.force_login(user_a)
    page = client.get(reverse("vv-new")).text
    for asset in (
        "vendor/codemirror/lib/codemirror.js",
        "vendor/codemirror/lib/codemirror.css",
        "vendor/codemirror/mode/javascript/javascript.js",
        "js/editor.js",
    ):
        assert f"/static/{asset}" in page, asset
    assert 'data-check-url="/vvs/check/"' in page and 'id="check-button"' in page
    assert 'type="file" name="program_file"' in page and 'enctype="multipart/form-data"' in page
    assert 'name="copies"' in page


def test_one_submitted_vv_opens_its_own_page(client, user_a, page_vvm) -> None:
    client.force_login(user_a)
    response = client.post(reverse("vv-new"), {"name": "Survey", "copies": 1, "program": FINE})
    vv = VirtualVehicle.objects.get(name="Survey")
    assert response.status_code == 302 and response["Location"] == f"/vvs/{vv.pk}/"


def test_a_cancelled_vv_shows_no_error_on_the_dashboard(client, user_a, page_vvm) -> None:
    vv = vv_submit(customer=user_a.customer, name="Gone", program=FINE, vvm=page_vvm)
    VirtualVehicle.objects.filter(pk=vv.pk).update(
        status=VVStatus.CANCELLED, error="cancelled by its owner"
    )
    client.force_login(user_a)
    page = client.get(reverse("home") + "?show=all").text
    row = re.search(rf'<tr data-vv="{vv.pk}".*?</tr>', page, re.S)[0]
    error_cell = re.search(r'<td class="error-text"[^>]*>(.*?)</td>', row, re.S)[1]
    assert error_cell.strip() == ""
    assert 'title="cancelled by its owner"' in row  # the reason stays at hand


def test_n_copies_are_submitted_at_once(client, user_a, page_vvm) -> None:
    client.force_login(user_a)
    response = client.post(reverse("vv-new"), {"name": "Survey", "copies": 3, "program": FINE})
    assert response.status_code == 302 and response["Location"] == reverse("home")
    vvs = VirtualVehicle.objects.order_by("submitted_s", "created")
    assert [(vv.name, vv.program, vv.customer_id) for vv in vvs] == [
        (name, FINE, user_a.customer_id) for name in ("Survey", "Survey (2)", "Survey (3)")
    ]
    assert page_vvm.dispatcher.slots == [user_a.customer_id]
    assert "3 copies of “Survey” are submitted." in client.get(reverse("home")).text


def test_a_program_from_the_browser_is_kept_with_lf_line_ends(client, user_a, page_vvm) -> None:
    client.force_login(user_a)
    typed = FINE.replace("\n", "\r\n")  # what a browser sends for a text box
    client.post(reverse("vv-new"), {"name": "Survey", "copies": 1, "program": typed})
    assert VirtualVehicle.objects.get().program == FINE


def test_the_admin_pages_link_to_the_map(client, staff) -> None:
    client.force_login(staff)
    page = client.get(reverse("admin:index")).text
    assert f'<a href="{reverse("map")}">Map</a>' in page


def test_a_program_with_a_syntax_error_is_never_submitted(client, user_a, page_vvm) -> None:
    client.force_login(user_a)
    response = client.post(reverse("vv-new"), {"name": "Bad", "copies": 2, "program": BROKEN})
    assert response.status_code == 400
    page = html.unescape(response.text)
    assert 'data-error-line="2" data-error-column="9"' in page
    assert "Line 2, column 9: SyntaxError" in page
    assert BROKEN.strip() in page  # the program stays in the editor
    assert not VirtualVehicle.objects.exists()


def test_a_js_file_is_the_program_when_the_box_is_empty(client, user_a, page_vvm) -> None:
    from django.core.files.uploadedfile import SimpleUploadedFile

    client.force_login(user_a)
    upload = SimpleUploadedFile("survey.js", FINE.encode(), content_type="text/javascript")
    response = client.post(
        reverse("vv-new"), {"name": "From file", "copies": 1, "program": "", "program_file": upload}
    )
    assert response.status_code == 302
    assert VirtualVehicle.objects.get().program == FINE


def test_the_editor_refuses_what_it_cannot_submit(client, user_a, staff, page_vvm) -> None:
    client.force_login(user_a)
    for data in (
        {"name": "", "copies": 1, "program": FINE},
        {"name": "x", "copies": 0, "program": FINE},
        {"name": "x", "copies": 1, "program": "  "},
        {"name": "x" * 118, "copies": 12, "program": FINE},
    ):
        assert client.post(reverse("vv-new"), data).status_code == 400, data
    assert not VirtualVehicle.objects.exists()
    client.force_login(staff)  # staff have no customer: nobody to own the VV
    assert client.get(reverse("vv-new")).status_code == 403
    assert (
        client.post(reverse("vv-new"), {"name": "x", "copies": 1, "program": FINE}).status_code
        == 403
    )


def test_the_editor_starts_from_one_of_the_users_own_vvs_only(client, user_a, vv_a, vv_b) -> None:
    client.force_login(user_a)
    page = client.get(reverse("vv-new") + f"?from={vv_a.pk}").text
    assert 'value="Alpha VV"' in page and "var a = 1;" in page
    assert client.get(reverse("vv-new") + f"?from={vv_b.pk}").status_code == 404


# --- editing, cancelling, restarting ----------------------------------------------------------


@pytest.fixture
def queued_a(user_a, vvm_factory):
    (vv,), _ = vv_create_copies_for_user(
        user=user_a, name="Draft", program=FINE, copies=1, vvm=vvm_factory()
    )
    return vv


def test_a_queued_vv_is_edited(client, user_a, queued_a, page_vvm) -> None:
    client.force_login(user_a)
    url = reverse("vv-edit", args=[queued_a.pk])
    page = client.get(url).text
    assert 'value="Draft"' in page and html.escape(FINE.strip()) in page
    assert 'name="copies"' not in page
    bad = client.post(url, {"name": "Final", "program": BROKEN})
    assert bad.status_code == 400 and 'data-error-line="2"' in bad.text
    response = client.post(url, {"name": "Final", "program": "VV.log(2);"})
    assert response.status_code == 302 and response["Location"] == f"/vvs/{queued_a.pk}/"
    queued_a.refresh_from_db()
    assert (queued_a.name, queued_a.program) == ("Final", "VV.log(2);")


def test_a_vv_that_left_the_queue_or_another_customers_is_not_edited(
    client, user_a, user_b, vv_a, queued_a, page_vvm
) -> None:
    client.force_login(user_a)
    assert vv_a.status == VVStatus.RUNNING
    for method in (client.get, client.post):
        response = method(reverse("vv-edit", args=[vv_a.pk]), {"name": "x", "program": FINE})
        assert response.status_code == 302 and response["Location"] == f"/vvs/{vv_a.pk}/"
    vv_a.refresh_from_db()
    assert vv_a.program == "var a = 1;"
    client.force_login(user_b)
    assert client.get(reverse("vv-edit", args=[queued_a.pk])).status_code == 404
    assert (
        client.post(
            reverse("vv-edit", args=[queued_a.pk]), {"name": "x", "program": FINE}
        ).status_code
        == 404
    )
    queued_a.refresh_from_db()
    assert queued_a.name == "Draft"


def test_a_vv_is_cancelled_from_its_row_and_another_customers_is_not_found(
    client, user_a, user_b, vv_a, page_vvm
) -> None:
    url = reverse("vv-cancel", args=[vv_a.pk])
    client.force_login(user_b)
    assert client.post(url).status_code == 404
    client.force_login(user_a)
    assert client.get(url).status_code == 405  # a state change is a POST
    response = client.post(url, {"next": "/?show=active"})
    assert response.status_code == 302 and response["Location"] == "/?show=active"
    vv_a.refresh_from_db()
    assert vv_a.status == VVStatus.CANCELLED
    again = client.post(url, {"next": "https://example.org/"})  # never off the site
    assert again.status_code == 302 and again["Location"] == f"/vvs/{vv_a.pk}/"


def test_an_ended_vv_is_restarted_as_a_new_one(client, user_a, user_b, mission, page_vvm) -> None:
    url = reverse("vv-restart", args=[mission.pk])
    client.force_login(user_b)
    assert client.post(url).status_code == 404
    assert VirtualVehicle.objects.count() == 1
    client.force_login(user_a)
    response = client.post(url)
    new = VirtualVehicle.objects.exclude(pk=mission.pk).get()
    assert response.status_code == 302 and response["Location"] == f"/vvs/{new.pk}/"
    assert (new.name, new.program, new.status) == (mission.name, mission.program, VVStatus.QUEUED)
    assert page_vvm.dispatcher.slots == [user_a.customer_id]


def test_a_running_vv_is_not_restarted(client, user_a, vv_a, page_vvm) -> None:
    client.force_login(user_a)
    response = client.post(reverse("vv-restart", args=[vv_a.pk]))
    assert response.status_code == 302 and response["Location"] == f"/vvs/{vv_a.pk}/"
    assert VirtualVehicle.objects.count() == 1


# --- what the editor refuses: long programs (in its check too), names, a full queue -----------

TOO_LONG = "A program has at most 1,000,000 characters: split the work into several VVs or make the program shorter."


def test_the_check_refuses_a_program_longer_than_a_submission_as_the_api_does(
    client, user_a, user_b, settings
) -> None:
    from tests.api_fixtures import token_client

    program = "var x = 1;\n" * 90_910  # 1,000,010 characters: a body of 1 MB, under the 2 MB
    submission = token_client(user_a).post(
        "/api/v1/vvs/", {"name": "long", "program": program}, format="json"
    )
    assert submission.status_code == 400
    expected = {"detail": f"program: {TOO_LONG}", "program": [TOO_LONG]}
    assert submission.json() == expected
    for user in (user_a, user_b):
        client.force_login(user)
        url = reverse("vv-check")
        as_json = client.post(url, {"program": program}, content_type="application/json")
        assert (as_json.status_code, as_json.json()) == (400, expected)
        as_form = client.post(url, {"program": program})
        assert (as_form.status_code, as_form.json()) == (400, expected)
        fits = client.post(url, {"program": program[:1_000_000]}, content_type="application/json")
        assert fits.status_code == 200 and fits.json() == {"ok": True}
    editor = client.post(reverse("vv-new"), {"name": "long", "copies": 1, "program": program})
    assert editor.status_code == 400 and TOO_LONG in html.unescape(editor.text)
    # Above the request limit both answer 413 before reading the body.
    settings.CPCC_MAX_REQUEST_BYTES = 100_000
    check = client.post(reverse("vv-check"), {"program": program}, content_type="application/json")
    submission = token_client(user_a).post(
        "/api/v1/vvs/", {"name": "big", "program": program}, format="json"
    )
    assert check.status_code == submission.status_code == 413
    assert "at most 100,000" in check.json()["detail"]
    assert not VirtualVehicle.objects.exists()


def test_the_editor_refuses_a_name_with_control_or_bidi_characters(
    client, user_a, queued_a, page_vvm
) -> None:
    client.force_login(user_a)
    response = client.post(reverse("vv-new"), {"name": "\x1b[31mred", "copies": 1, "program": FINE})
    assert response.status_code == 400
    assert "The name has a control character (U+001B) at character 1" in html.unescape(
        response.text
    )
    edit = client.post(
        reverse("vv-edit", args=[queued_a.pk]), {"name": "Draft\u202e1v", "program": FINE}
    )
    assert edit.status_code == 400
    assert "(U+202E RIGHT-TO-LEFT OVERRIDE) at character 6" in html.unescape(edit.text)
    queued_a.refresh_from_db()
    assert queued_a.name == "Draft"
    assert VirtualVehicle.objects.count() == 1


def test_the_editor_shows_why_a_full_queue_refuses_a_submission(
    client, user_a, user_b, customer_a, vv_a, queued_a, page_vvm
) -> None:
    from vvm_worker.services import vv_cancel

    vv_cancel(vv_id=vv_a.pk, vvm=page_vvm)  # ended: it may be restarted
    customer_a.max_queued_vvs = 2  # queued_a waits in it already
    customer_a.save()
    client.force_login(user_a)
    response = client.post(reverse("vv-new"), {"name": "Many", "copies": 2, "program": FINE})
    assert response.status_code == 429
    page = html.unescape(response.text)
    assert "Customer A has 1 VV(s) waiting in the queue and may have at most 2" in page
    assert "so 2 more cannot be submitted now" in page
    assert FINE.strip() in page  # the program stays in the editor
    assert not VirtualVehicle.objects.filter(name__startswith="Many").exists()
    one = client.post(reverse("vv-new"), {"name": "One", "copies": 1, "program": FINE})
    assert one.status_code == 302
    # Full now: a restart is refused too, saying why.
    restart = client.post(reverse("vv-restart", args=[vv_a.pk]), follow=True)
    assert "may have at most 2" in html.unescape(restart.text)
    assert VirtualVehicle.objects.filter(customer=customer_a).count() == 3
    # Customer B's queue is its own.
    client.force_login(user_b)
    other = client.post(reverse("vv-new"), {"name": "B", "copies": 2, "program": FINE})
    assert other.status_code == 302


def test_a_failed_vvs_page_says_why_once_shows_where_and_offers_a_copy_not_a_restart(
    client, user_a, vv_a
) -> None:
    # VV failed at line 3, column 9: a task no vehicle could serve (refused).
    VirtualVehicle.objects.filter(pk=vv_a.pk).update(
        status=VVStatus.FAILED,
        error="no vehicle can serve the task at (48.200000, 12.861900) at 50 m: it is outside "
        "every operation area (line 3, column 9)",
        error_line=3,
        error_column=9,
        finished_s=12.0,
    )
    Task.objects.create(
        vv=vv_a,
        q=1,
        lat=48.2,
        lng=12.8619,
        alt=50.0,
        tolerance_m=2.0,
        sensors=["CO2"],
        status="rejected",
        requested_s=1.0,
    )
    client.force_login(user_a)
    page = page_of(client, vv_a)
    # The place once, as the link to the line; the reason in words before it.
    assert page.count("line 3, column 9") == 1
    assert "outside every operation area\n" in page or "outside every operation area " in page
    assert 'class="error-where">line 3, column 9</a>' in page
    # The refused point is named in the map's legend; an ended VV read none, not "yet".
    assert "refused task" in page
    assert "No scalar readings: it read none." in page and "readings yet" not in page
    assert "No messages: it sent and received none." in page and " yet." not in page
    # Run again as it is it would fail the same way: a copy to change, no Restart.
    assert f'action="/vvs/{vv_a.pk}/restart/"' not in page
    assert "it would fail the same way" in page and f'href="/vvs/new/?from={vv_a.pk}"' in page
    dashboard = html.unescape(client.get(reverse("home")).text)
    assert f'action="/vvs/{vv_a.pk}/restart/"' not in dashboard
