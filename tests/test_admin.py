"""Every admin page of the platform's models loads for staff and is closed to customers."""

from __future__ import annotations

import html
import json
import re
from datetime import timedelta

import pytest
from django.conf import settings
from django.db import transaction
from django.urls import reverse
from django.utils import timezone

from missions.models import Message
from tests.admin_forms import form_as_shown
from tests.factories import AREA_ONE, AREA_TWO, GroundStationFactory, UserFactory, VehicleFactory
from vvm_worker.services import vv_submit
from vvm_worker.services.messages import message_send

MODELS = [
    ("accounts", "customer"),
    ("accounts", "user"),
    ("fleet", "sensortype"),
    ("fleet", "groundstation"),
    ("fleet", "vehicle"),
    ("fleet", "noflyzone"),
    ("fleet", "rallypoint"),
    ("missions", "virtualvehicle"),
    ("missions", "task"),
    ("missions", "storagedocument"),
    ("missions", "logentry"),
    ("missions", "migration"),
    ("missions", "message"),
]


@pytest.fixture
def populated(customer_a, user_a, vvm_factory):
    GroundStationFactory(name="GS Base")
    VehicleFactory(name="Heli One")
    return vv_submit(customer=customer_a, name="VV 1", program="var a = 1;", vvm=vvm_factory())


def test_admin_index_loads(client, staff) -> None:
    client.force_login(staff)
    response = client.get(reverse("admin:index"))
    assert response.status_code == 200
    for app in ("Customers and users", "Fleet", "Missions"):
        assert app in response.text
    # Each model under a name of its own: the audit log's "Log entries", the VVs' log lines.
    assert response.text.count(">Log entries<") == 1
    assert ">VV log lines<" in response.text


# What only the platform creates: the admin shows it and offers no "Add".
MADE_BY_THE_PLATFORM = {
    ("missions", "task"),
    ("missions", "storagedocument"),
    ("missions", "logentry"),
    ("missions", "migration"),
    ("missions", "message"),
}


@pytest.mark.parametrize(("app", "model"), MODELS)
def test_admin_changelist_and_add_pages_load(client, staff, populated, app, model) -> None:
    client.force_login(staff)
    changelist = client.get(reverse(f"admin:{app}_{model}_changelist"))
    assert changelist.status_code == 200
    add = reverse(f"admin:{app}_{model}_add")
    if (app, model) in MADE_BY_THE_PLATFORM:
        assert client.get(add).status_code == 403
        assert f'href="{add}"' not in changelist.text
    else:
        assert client.get(add).status_code == 200
        assert f'href="{add}"' in changelist.text


@pytest.mark.parametrize(
    ("app", "model", "lookup"),
    [
        ("missions", "virtualvehicle", lambda vv: vv.pk),
        ("accounts", "customer", lambda vv: vv.customer_id),
        ("fleet", "vehicle", lambda vv: VehicleFactory(name="Heli One").pk),
    ],
)
def test_admin_change_pages_load(client, staff, populated, app, model, lookup) -> None:
    client.force_login(staff)
    url = reverse(f"admin:{app}_{model}_change", args=[lookup(populated)])
    assert client.get(url).status_code == 200


def test_the_queued_vv_quota_is_set_in_the_admin_with_the_other_quotas(
    client, staff, customer_a, customer_b
) -> None:
    client.force_login(staff)
    url = reverse("admin:accounts_customer_change", args=[customer_a.pk])
    shown = client.get(url)
    quotas = shown.text[shown.text.index('class="fieldset-heading">Quotas</h2>') :]
    assert 'name="max_parallel_vvs"' in quotas and 'name="max_queued_vvs"' in quotas
    response = client.post(url, form_as_shown(shown) | {"max_queued_vvs": 12})
    assert response.status_code == 302, response.content
    customer_a.refresh_from_db()
    customer_b.refresh_from_db()
    assert (customer_a.max_queued_vvs, customer_b.max_queued_vvs) == (12, 100)


def test_the_message_quotas_are_set_in_the_admin_with_the_other_quotas(
    client, staff, customer_a, customer_b
) -> None:
    client.force_login(staff)
    url = reverse("admin:accounts_customer_change", args=[customer_a.pk])
    shown = client.get(url)
    quotas = shown.text[shown.text.index('class="fieldset-heading">Quotas</h2>') :]
    assert 'name="max_messages_per_vv"' in quotas and 'name="max_message_bytes"' in quotas
    form = form_as_shown(shown) | {"max_messages_per_vv": 7, "max_message_bytes": "0.5"}  # KB
    response = client.post(url, form)
    assert response.status_code == 302, response.content
    customer_a.refresh_from_db()
    customer_b.refresh_from_db()
    assert (customer_a.max_messages_per_vv, customer_a.max_message_bytes) == (7, 512)
    assert (customer_b.max_messages_per_vv, customer_b.max_message_bytes) == (1000, 65_536)
    refused = client.post(url, {**form, "max_message_bytes": "0.001"})  # 1 byte
    assert refused.status_code == 200
    assert refused.context["adminform"].form.errors["max_message_bytes"] == ["At least 0.002 KB."]
    customer_a.refresh_from_db()
    assert customer_a.max_message_bytes == 512


def test_messages_are_shown_to_staff_read_only_and_found_by_recipient(
    client, staff, populated, vvm_factory
) -> None:
    other = vv_submit(
        customer=populated.customer, name="Other VV", program="var b = 1;", vvm=vvm_factory()
    )
    with transaction.atomic():
        to_populated = message_send(
            customer_id=populated.customer_id,
            sender=other,
            to="VV 1",
            value_json='{"found": 3}',
            vvm=vvm_factory(),
        )
        message_send(
            customer_id=populated.customer_id,
            sender=None,
            to=other,
            value_json='"over the API"',
            vvm=vvm_factory(),
        )
    client.force_login(staff)
    changelist = reverse("admin:missions_message_changelist")

    listed = html.unescape(client.get(changelist).text)
    assert "(the customer's system, over the API)" in listed and "Other VV" in listed
    found = html.unescape(client.get(changelist, {"q": "VV 1"}).text)
    assert "1 message" in found and f"/{to_populated.pk}/change/" in found

    detail = client.get(reverse("admin:missions_message_change", args=[to_populated.pk]))
    assert detail.status_code == 200
    assert '{"found": 3}' in html.unescape(detail.text)
    assert 'name="value"' not in detail.text, "nothing to edit"
    delete = reverse("admin:missions_message_delete", args=[to_populated.pk])
    assert client.post(delete, {"post": "yes"}).status_code == 403
    assert Message.objects.count() == 2


def test_customers_cannot_open_the_admin(client, user_a) -> None:
    client.force_login(user_a)
    response = client.get(reverse("admin:missions_virtualvehicle_changelist"))
    assert response.status_code == 302
    assert "/admin/login/" in response["Location"]


# What the admin's vehicle actions and forms do, through the real services on the in-process
# platform (discrete-event time): a VV aboard asks for two CO2 readings in area one, where
# Heli One (fast) and Heli Two (slow) both fly, so it goes to Heli One first.
TWO_TASKS = """
var co2 = VV.sensor.get('CO2');
for (var n = 0; n < 2; ++n) {
  var d = VV.task.execute({type: 'point', tolerance: 2, sensors: [co2],
                           position: new VV.types.LatLngAlt(48.1101 + n * 0.0004, 12.8622, 50)});
  VV.storage.store('co2.' + n, d[0]);
}
"""


@pytest.fixture
def in_process(platform, ground_station, monkeypatch):
    """Two RVs over area one flying on the in-process platform, which the admin uses."""
    import fleet.admin

    monkeypatch.setattr(fleet.admin, "platform_vvm", lambda: platform.vvm)
    for name, speed in [("Heli One", 10.0), ("Heli Two", 1.0)]:
        platform.add_vehicle_loop(VehicleFactory(name=name, max_speed_mps=speed))
    return platform


def _vv_aboard_heli_one(platform, customer):
    from fleet.models import Vehicle

    vv = vv_submit(customer=customer, name="VV", program=TWO_TASKS, vvm=platform.vvm)
    one = Vehicle.objects.get(name="Heli One")
    platform.drain(until=lambda: vv.tasks.filter(vehicle=one).exists())
    return vv


def _finished_by(vv) -> list[str]:
    from missions.models import TaskStatus, VVStatus

    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert set(vv.tasks.values_list("status", flat=True)) == {TaskStatus.DONE}
    assert sorted(vv.storage.values_list("key", flat=True)) == ["co2.0", "co2.1"]
    return [t.vehicle.name for t in vv.tasks.select_related("vehicle").order_by("q")]


def test_admin_actions_take_an_rv_out_of_service_and_back(
    client, staff, in_process, customer_a
) -> None:
    from fleet.models import Vehicle, VehicleStatus

    client.force_login(staff)
    vv = _vv_aboard_heli_one(in_process, customer_a)
    heli = Vehicle.objects.get(name="Heli One")
    url = reverse("admin:fleet_vehicle_changelist")

    def act(action: str) -> None:
        response = client.post(url, {"action": action, "_selected_action": [heli.pk]}, follow=True)
        assert response.status_code == 200
        in_process.drain()
        heli.refresh_from_db()

    act("put_into_maintenance")
    assert heli.status == VehicleStatus.MAINTENANCE
    assert _finished_by(vv) == ["Heli Two", "Heli Two"], "handed over before its first reading"
    assert ("Heli One", "Heli Two") in vv.migrations.values_list("from_name", "to_name")
    act("return_to_service")
    assert heli.status == VehicleStatus.ACTIVE
    again = _vv_aboard_heli_one(in_process, customer_a)
    act("remove_from_fleet")
    assert heli.status == VehicleStatus.REMOVED
    assert _finished_by(again) == ["Heli Two", "Heli Two"]


def _vehicle_form(vehicle, **changes) -> dict:
    data = {
        "name": vehicle.name,
        "kind": vehicle.kind,
        "driver": vehicle.driver,
        "driver_url": vehicle.driver_url,
        "depot_lat": vehicle.depot_lat,
        "depot_lng": vehicle.depot_lng,
        "depot_alt": vehicle.depot_alt,
        "area": json.dumps(vehicle.area),
        "min_altitude_m": vehicle.min_altitude_m,
        "max_altitude_m": vehicle.max_altitude_m,
        "max_speed_mps": vehicle.max_speed_mps,
        "climb_rate_mps": vehicle.climb_rate_mps,
        "battery_s": vehicle.battery_s or "",
        "sensors": list(vehicle.sensors.values_list("pk", flat=True)),
    }
    return data | changes


def test_a_vehicle_added_in_the_admin_takes_work(client, staff, in_process, customer_a) -> None:
    from fleet.models import SensorType, Vehicle, VehicleStatus
    from vvm_worker.services import vehicle_set_status

    vv = _vv_aboard_heli_one(in_process, customer_a)
    for name in ("Heli One", "Heli Two"):
        vehicle = Vehicle.objects.get(name=name)
        vehicle_set_status(vehicle=vehicle, status=VehicleStatus.MAINTENANCE, vvm=in_process.vvm)
    in_process.drain()
    vv.refresh_from_db()
    assert vv.host_gs is not None and vv.pending is not None, "waits for an RV on the GS"
    client.force_login(staff)
    template = Vehicle.objects.get(name="Heli One")
    co2 = SensorType.objects.get(name="CO2")
    response = client.post(
        reverse("admin:fleet_vehicle_add"),
        _vehicle_form(template, name="Heli Three", sensors=[co2.pk]),
    )
    assert response.status_code == 302, response.content.decode()[:2000]
    three = Vehicle.objects.get(name="Heli Three")
    assert three.status == VehicleStatus.ACTIVE
    assert list(three.sensors.values_list("name", flat=True)) == ["CO2"]
    in_process.add_vehicle_loop(three)
    in_process.drain()
    assert _finished_by(vv) == ["Heli Three", "Heli Three"]


def test_editing_an_rvs_sensors_or_area_in_the_admin_reroutes_its_vvs(
    client, staff, in_process, customer_a
) -> None:
    from fleet.models import SensorType, Vehicle

    client.force_login(staff)
    heli = Vehicle.objects.get(name="Heli One")
    change = reverse("admin:fleet_vehicle_change", args=[heli.pk])
    vv = _vv_aboard_heli_one(in_process, customer_a)
    gps = SensorType.objects.get(name="GPS")
    response = client.post(change, _vehicle_form(heli, sensors=[gps.pk]))
    assert response.status_code == 302, response.content.decode()[:2000]
    in_process.drain()
    assert _finished_by(vv) == ["Heli Two", "Heli Two"], "Heli One has no CO2 sensor any more"

    heli.refresh_from_db()
    co2 = SensorType.objects.get(name="CO2")
    client.post(change, _vehicle_form(heli, sensors=[co2.pk, gps.pk]))
    again = _vv_aboard_heli_one(in_process, customer_a)
    response = client.post(change, _vehicle_form(heli, area=json.dumps(AREA_TWO)))
    assert response.status_code == 302, response.content.decode()[:2000]
    heli.refresh_from_db()
    assert heli.area == AREA_TWO
    in_process.drain()
    assert _finished_by(again) == ["Heli Two", "Heli Two"], "area one is no longer Heli One's"


# The operation area on a map (fleet/widgets.py, static/js/admin/area-widget.js): the page
# carries what the map draws; the browser writes the drawn ring into the textarea as compact
# JSON, which the form saves through the services like any other edit.


def _json_script(page: str, element_id: str):
    found = re.search(rf'<script id="{element_id}" type="application/json">(.*?)</script>', page)
    assert found, f"no #{element_id} on the page"
    return json.loads(found.group(1))


def test_the_vehicle_change_page_draws_the_area_on_a_map(client, staff, db) -> None:
    from fleet.models import VehicleStatus

    heli = VehicleFactory(name="Heli One")
    VehicleFactory(name="Heli Two", area=AREA_TWO)
    VehicleFactory(name="Heli Gone", status=VehicleStatus.REMOVED)
    GroundStationFactory(name="GS Base")
    client.force_login(staff)
    page = client.get(reverse("admin:fleet_vehicle_change", args=[heli.pk])).text

    assert 'id="id_area_map" data-area-map' in page
    assert 'data-input="id_area" data-context="id_area_context"' in page
    assert 'data-state="loading" data-points="0"' in page, "the script reports when it drew"
    textarea = re.search(r'<textarea name="area"[^>]*>(.*?)</textarea>', page, re.DOTALL)
    assert textarea and json.loads(html.unescape(textarea.group(1))) == AREA_ONE
    context = _json_script(page, "id_area_context")
    assert context["others"] == [{"name": "Heli Two", "status": "active", "area": AREA_TWO}]
    assert context["stations"] == [{"name": "GS Base", "lat": 48.1132, "lng": 12.8598}]
    for script in [
        "vendor/leaflet/leaflet.js",
        "js/admin/map-common.js",
        "vendor/leaflet-geoman/leaflet-geoman.min.js",
        "js/admin/area-widget.js",
    ]:
        assert f'src="/static/{script}"' in page, script
    assert page.index("vendor/leaflet/leaflet.js") < page.index("js/admin/area-widget.js")
    assert 'href="/static/vendor/leaflet-geoman/leaflet-geoman.css"' in page


def test_the_add_page_shows_the_fleet_on_the_map(client, staff, db) -> None:
    VehicleFactory(name="Heli One")
    client.force_login(staff)
    page = client.get(reverse("admin:fleet_vehicle_add")).text
    assert "data-area-map" in page
    assert [o["name"] for o in _json_script(page, "id_area_context")["others"]] == ["Heli One"]


@pytest.fixture
def spied_vehicle_update(monkeypatch):
    """The admin's calls of the vehicle_update service (which still runs)."""
    import fleet.admin

    calls: list[dict] = []
    real = fleet.admin.vehicle_update

    def spy(**kwargs):
        calls.append(kwargs)
        return real(**kwargs)

    monkeypatch.setattr(fleet.admin, "vehicle_update", spy)
    return calls


def test_saving_an_area_drawn_on_the_map_updates_it_through_the_services(
    client, staff, in_process, spied_vehicle_update
) -> None:
    from fleet.models import Vehicle

    client.force_login(staff)
    heli = Vehicle.objects.get(name="Heli One")
    drawn = [
        [48.1095, 12.8595],
        [48.109612, 12.863507],
        [48.1135, 12.8632],
        [48.1131, 12.859701],
        [48.1095, 12.8595],
    ]
    response = client.post(
        reverse("admin:fleet_vehicle_change", args=[heli.pk]),
        _vehicle_form(heli, area=json.dumps(drawn, separators=(",", ":"))),
    )
    assert response.status_code == 302, response.content.decode()[:2000]
    heli.refresh_from_db()
    assert heli.area == drawn
    [call] = spied_vehicle_update
    assert call["config"] == {"area": drawn}, "only what changed"
    assert call["sensors"] is None


def test_an_area_that_is_not_a_closed_ring_is_refused_with_the_reason(
    client, staff, in_process, spied_vehicle_update
) -> None:
    from fleet.models import Vehicle

    client.force_login(staff)
    heli = Vehicle.objects.get(name="Heli One")
    open_ring = [[48.1095, 12.8595], [48.1096, 12.8635], [48.1135, 12.8632]]
    response = client.post(
        reverse("admin:fleet_vehicle_change", args=[heli.pk]),
        _vehicle_form(heli, area=json.dumps(open_ring)),
    )
    assert response.status_code == 200
    assert "must be closed" in response.text
    assert "data-area-map" in response.text, "the map is shown again with the form"
    heli.refresh_from_db()
    assert heli.area == AREA_ONE
    assert spied_vehicle_update == []


# The fleet overview (VehicleAdmin.overview_view).


def _overview_row(page: str, name: str) -> tuple[dict[str, str], str]:
    found = re.search(
        rf'<tr data-vehicle="{re.escape(name)}" data-status="(\w+)" data-lease="(\w+)">(.*?)</tr>',
        page,
        re.DOTALL,
    )
    assert found, f"no row for {name}"
    return {"status": found.group(1), "lease": found.group(2)}, found.group(3)


def test_the_fleet_overview_shows_each_rv_to_staff(client, staff, in_process, customer_a) -> None:
    from fleet.models import Vehicle, VehicleStatus
    from vvm_worker.services import vehicle_record_health, vehicle_set_status

    _vv_aboard_heli_one(in_process, customer_a)
    now = timezone.now()
    expired = now - timedelta(seconds=settings.CPCC_RV_LEASE_S + 300)  # minutes ago
    Vehicle.objects.filter(name="Heli One").update(worker_seen=now, battery_s=100, flight_s=25)
    Vehicle.objects.filter(name="Heli Two").update(worker_seen=expired)
    two = Vehicle.objects.get(name="Heli Two")
    vehicle_set_status(
        vehicle=two, status=VehicleStatus.MAINTENANCE, vvm=in_process.vvm, reason="rotor check"
    )
    vehicle_record_health(
        vehicle_id=two.pk,
        health={"link": "down", "armed": False, "mode": "LAND", "fence": "loaded"},
    )
    VehicleFactory(name="Heli Three")

    client.force_login(staff)
    response = client.get(reverse("admin:fleet_vehicle_overview"))
    assert response.status_code == 200
    page = response.text
    assert "<h1>Fleet overview</h1>" in page

    one, cells = _overview_row(page, "Heli One")
    assert one == {"status": "active", "lease": "fresh"}
    assert "Active" in cells and 'data-vvs-aboard="1"' in cells and "75 %" in cells
    assert re.search(r"fresh, \d+ s ago", cells)
    two_row, cells = _overview_row(page, "Heli Two")
    assert two_row == {"status": "maintenance", "lease": "expired"}
    assert "In maintenance" in cells and 'data-vvs-aboard="0"' in cells
    assert re.search(r"rotor check, \d\d:\d\d:\d\d", cells)
    assert "link down · disarmed · LAND · fence loaded" in cells
    assert re.search(r"expired, \d+ min ago", cells)
    three, cells = _overview_row(page, "Heli Three")
    assert three == {"status": "active", "lease": "never"}
    assert "never reported" in cells and "(depot)" in cells
    assert '<tr data-station="GS Base">' in page

    data = _json_script(page, "fleet-overview-data")
    aboard = {v["name"]: (v["status"], v["vvs_aboard"]) for v in data["vehicles"]}
    assert aboard == {
        "Heli One": ("active", 1),
        "Heli Three": ("active", 0),
        "Heli Two": ("maintenance", 0),
    }
    assert data["vehicles"][0]["area"] == AREA_ONE
    assert data["stations"][0]["name"] == "GS Base"
    assert 'src="/static/js/admin/fleet-overview.js"' in page


def test_the_fleet_overview_is_linked_from_the_index_and_the_vehicle_list(client, staff) -> None:
    client.force_login(staff)
    overview = reverse("admin:fleet_vehicle_overview")
    assert f'href="{overview}"' in client.get(reverse("admin:index")).text
    assert f'href="{overview}"' in client.get(reverse("admin:fleet_vehicle_changelist")).text


def test_the_fleet_overview_is_closed_to_customers_and_staff_without_permission(
    client, user_a, db
) -> None:
    overview = reverse("admin:fleet_vehicle_overview")
    client.force_login(user_a)
    response = client.get(overview)
    assert response.status_code == 302
    assert "/admin/login/" in response["Location"]
    client.force_login(UserFactory(username="helpdesk", is_staff=True))
    assert client.get(overview).status_code == 403
    assert f'href="{overview}"' not in client.get(reverse("admin:index")).text


def test_a_no_fly_zone_drawn_in_the_admin_is_refused_when_open_and_kept_when_closed(
    client, staff, db
) -> None:
    """Issue 24: the zone's ring is checked as an RV's area is, and saved through the service
    (which tells every RV's worker)."""
    from fleet.models import NoFlyZone

    client.force_login(staff)
    ring = [[48.1105, 12.861], [48.1105, 12.8625], [48.1115, 12.8625], [48.1105, 12.861]]
    form = {"name": "Prison", "min_altitude_m": "0", "max_altitude_m": ""}
    add = reverse("admin:fleet_noflyzone_add")
    page = client.get(add)
    assert 'class="cpcc-area-json' in page.text  # drawn on the map widget
    refused = client.post(add, {**form, "area": json.dumps(ring[:3])})
    assert refused.status_code == 200 and "must be closed" in refused.text
    saved = client.post(add, {**form, "area": json.dumps(ring)})
    assert saved.status_code == 302, saved.content.decode()[:2000]
    zone = NoFlyZone.objects.get()
    assert (zone.area, zone.max_altitude_m) == (ring, None)
