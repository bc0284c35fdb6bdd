"""/api/v1/ground-stations/ (staff only)."""

from __future__ import annotations

import fleet.api.views
from fleet.models import GroundStation
from vvm_worker.services import vv_submit


def test_customers_are_refused(api_a, ground_station) -> None:
    assert api_a.get("/api/v1/ground-stations/").status_code == 403
    response = api_a.post(
        "/api/v1/ground-stations/", {"name": "X", "position": [1, 2]}, format="json"
    )
    assert response.status_code == 403 and "staff" in response.json()["detail"]
    assert api_a.delete(f"/api/v1/ground-stations/{ground_station.pk}/").status_code == 403


def test_staff_create_read_update_and_delete_ground_stations(api_staff, db) -> None:
    created = api_staff.post(
        "/api/v1/ground-stations/", {"name": "GS North", "position": [48.12, 12.86]}, format="json"
    )
    assert created.status_code == 201, created.content
    body = created.json()
    assert body == {
        "id": body["id"],
        "name": "GS North",
        "position": [48.12, 12.86, 0.0],
        "vvs_here": 0,
    }
    url = f"/api/v1/ground-stations/{body['id']}/"
    moved = api_staff.patch(url, {"position": [48.13, 12.87, 5]}, format="json")
    assert moved.json()["position"] == [48.13, 12.87, 5.0] and moved.json()["name"] == "GS North"
    renamed = api_staff.put(url, {"name": "GS N", "position": [48.13, 12.87]}, format="json")
    assert renamed.status_code == 200 and renamed.json()["name"] == "GS N"
    assert [g["name"] for g in api_staff.get("/api/v1/ground-stations/").json()["results"]] == [
        "GS N"
    ]
    assert api_staff.delete(url).status_code == 204
    assert not GroundStation.objects.exists()
    assert api_staff.get(url).status_code == 404


def test_bad_ground_stations_are_refused_naming_the_field(api_staff, ground_station) -> None:
    far = api_staff.post(
        "/api/v1/ground-stations/", {"name": "X", "position": [95, 0]}, format="json"
    )
    assert far.status_code == 400 and "latitude 95" in str(far.json()["position"])
    taken = api_staff.post(
        "/api/v1/ground-stations/", {"name": "GS Base", "position": [48, 12]}, format="json"
    )
    assert taken.status_code == 409 and "already exists" in str(taken.json()["name"])


def test_a_ground_station_holding_vvs_is_not_deleted(
    api_staff, customer_a, ground_station, vvm_factory
) -> None:
    vv_submit(customer=customer_a, name="VV", program="VV.log(1);", vvm=vvm_factory())
    response = api_staff.delete(f"/api/v1/ground-stations/{ground_station.pk}/")
    assert response.status_code == 409
    assert "GS Base holds 1 VV(s) that have not ended" in response.json()["detail"]
    assert GroundStation.objects.filter(pk=ground_station.pk).exists()


def test_a_first_ground_station_starts_the_queued_vvs(
    api_staff, customer_a, customer_b, vvm_factory, monkeypatch
) -> None:
    vvm = vvm_factory()
    for customer in (customer_b, customer_a):
        vv_submit(customer=customer, name="VV", program="VV.log(1);", vvm=vvm, admit=False)
    monkeypatch.setattr(fleet.api.views, "platform_vvm", lambda: vvm)
    response = api_staff.post(
        "/api/v1/ground-stations/", {"name": "GS", "position": [48.1, 12.8]}, format="json"
    )
    assert response.status_code == 201
    assert vvm.dispatcher.slots == sorted([customer_a.pk, customer_b.pk])
