"""POST /api/v1/vehicles/{id}/return-home/ and .../land/ (issue 26): staff only, the RV into
maintenance with the command waiting for its worker, and who asked in the audit log."""

from __future__ import annotations

import pytest
from auditlog.models import LogEntry

import fleet.api.views
from fleet.models import Vehicle, VehicleStatus
from missions.models import VVStatus
from tests.factories import VehicleFactory
from vvm_worker.services import vehicle_set_status, vv_submit


@pytest.mark.parametrize(
    ("path", "command", "words"),
    [("return-home", "return_home", "return home now"), ("land", "land", "land now")],
)
def test_staff_send_a_vehicle_home_or_down_and_the_audit_log_says_who(
    api_staff, staff, heli_one, path, command, words
) -> None:
    response = api_staff.post(f"/api/v1/vehicles/{heli_one.pk}/{path}/")
    assert response.status_code == 200, response.content
    shown = response.json()
    assert (shown["status"], shown["command"]) == ("maintenance", command)
    assert shown["status_reason"] == f"{words}: asked by operator over the API"
    assert shown["command_requested"] is not None and shown["command_taken"] is None
    heli_one.refresh_from_db()
    assert (heli_one.status, heli_one.command) == (VehicleStatus.MAINTENANCE, command)
    updates = LogEntry.objects.get_for_object(heli_one).filter(action=LogEntry.Action.UPDATE)
    changes = {
        field: (entry.actor, values)
        for entry in updates
        for field, values in entry.changes_dict.items()
    }
    assert changes["command"] == (staff, ["", command])
    assert changes["status"] == (staff, ["active", "maintenance"])
    assert changes["status_reason"][0] == staff


def test_customers_are_refused_and_nothing_moves(api_a, api_b, heli_one) -> None:
    for client in (api_a, api_b):
        for path in ("return-home", "land"):
            response = client.post(f"/api/v1/vehicles/{heli_one.pk}/{path}/")
            assert response.status_code == 403, path
            assert "Only platform staff" in response.json()["detail"]
    heli_one.refresh_from_db()
    assert (heli_one.status, heli_one.command) == (VehicleStatus.ACTIVE, "")
    assert not LogEntry.objects.filter(object_pk=str(heli_one.pk), actor__isnull=False).exists()


def test_an_unknown_or_removed_vehicle_is_a_404_that_says_which(api_staff, heli_one) -> None:
    unknown = api_staff.post("/api/v1/vehicles/999/land/")
    assert (unknown.status_code, unknown.json()) == (404, {"detail": "No vehicle with id '999'."})
    api_staff.post(f"/api/v1/vehicles/{heli_one.pk}/remove/")
    removed = api_staff.post(f"/api/v1/vehicles/{heli_one.pk}/return-home/")
    assert removed.status_code == 404
    assert "was removed from the fleet" in removed.json()["detail"]
    assert Vehicle.objects.get(pk=heli_one.pk).command == ""


def test_a_vehicle_in_maintenance_still_takes_a_command(api_staff, heli_one, vvm_factory) -> None:
    vehicle_set_status(
        vehicle=heli_one, status=VehicleStatus.MAINTENANCE, vvm=vvm_factory(), reason="rotor"
    )
    response = api_staff.post(f"/api/v1/vehicles/{heli_one.pk}/land/")
    assert response.status_code == 200
    assert response.json()["command"] == "land"
    assert response.json()["status_reason"] == "rotor", "the reason it went out of service"


PROGRAM = """
var co2 = VV.sensor.get('CO2');
var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1095, 12.8632, 40),
                         tolerance: 2, sensors: [co2]});
VV.storage.store('co2', d[0]);
"""


def test_the_vvs_aboard_move_on_and_finish_elsewhere(
    api_staff, platform, ground_station, customer_a, monkeypatch
) -> None:
    monkeypatch.setattr(fleet.api.views, "platform_vvm", lambda: platform.vvm)
    one = VehicleFactory(name="Heli One")
    platform.add_vehicle_loop(one)
    platform.add_vehicle_loop(VehicleFactory(name="Heli Two", max_speed_mps=2.0))
    vv = vv_submit(customer=customer_a, name="VV", program=PROGRAM, vvm=platform.vvm)
    platform.drain(until=lambda: vv.tasks.filter(vehicle=one).exists())
    response = api_staff.post(f"/api/v1/vehicles/{one.pk}/return-home/")
    assert response.status_code == 200
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    assert vv.tasks.get().vehicle.name == "Heli Two"
    one.refresh_from_db()
    assert one.status == VehicleStatus.MAINTENANCE and one.command_taken is not None
