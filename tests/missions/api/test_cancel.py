"""POST /api/v1/vvs/{id}/cancel/: stop a VV; 409 when it had already ended."""

from __future__ import annotations

from missions.models import TaskStatus, VirtualVehicle, VVStatus
from tests.api_fixtures import MISSION
from vvm_worker.services import vv_submit


def test_a_queued_vv_is_cancelled_then_cancelling_again_is_a_conflict(api_a, api_b) -> None:
    vv = api_a.post("/api/v1/vvs/", {"name": "q", "program": "var a = 1;"}, format="json").json()
    assert api_b.post(f"/api/v1/vvs/{vv['id']}/cancel/").status_code == 404
    response = api_a.post(f"/api/v1/vvs/{vv['id']}/cancel/")
    assert response.status_code == 200, response.content
    assert response.json()["status"] == "cancelled" and response.json()["id"] == vv["id"]
    assert response.json()["finished"] is not None
    again = api_a.post(f"/api/v1/vvs/{vv['id']}/cancel/")
    assert again.status_code == 409
    assert again.json() == {
        "detail": "'q' has already ended (cancelled): there is nothing to cancel."
    }


def test_a_finished_vv_cannot_be_cancelled(mission, api_a) -> None:
    response = api_a.post(f"/api/v1/vvs/{mission.pk}/cancel/")
    assert response.status_code == 409
    assert "already ended (finished)" in response.json()["detail"]
    mission.refresh_from_db()
    assert mission.status == VVStatus.FINISHED


def test_a_vv_flying_on_an_rv_is_cancelled_and_keeps_what_it_stored(
    platform, fleet_one, customer_a, api_a
) -> None:
    vv = vv_submit(customer=customer_a, name="Flying", program=MISSION, vvm=platform.vvm)
    platform.drain(until=lambda: vv.storage.filter(key="p0.co2").exists())
    response = api_a.post(f"/api/v1/vvs/{vv.pk}/cancel/")
    assert response.status_code == 200 and response.json()["status"] == "cancelled"
    platform.drain()  # the RV carries on without it
    vv = VirtualVehicle.objects.get(pk=vv.pk)
    assert vv.status == VVStatus.CANCELLED and vv.host_rv is None
    assert vv.storage.filter(key="p0.co2").exists()
    assert not vv.tasks.filter(status=TaskStatus.OPEN).exists()
