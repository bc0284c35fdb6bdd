"""A mission's history for the map and its replay: tasks, the path while carried, migrations."""

from __future__ import annotations

from django.urls import reverse

from fleet.geo import Position, distance_m
from missions.selectors import map_snapshot_for_user
from tests.factories import VehicleFactory
from vvm_worker.services import vv_submit

TWO_TASKS = """
var co2 = VV.sensor.get('CO2');
for (var n = 0; n < 2; ++n) {
  VV.task.execute({type: 'point', tolerance: 2, sensors: [co2],
                   position: new VV.types.LatLngAlt(48.1101 + n * 0.0004, 12.8622, 50)});
}
"""


def _flown(platform, ground_station, customer):
    platform.add_vehicle_loop(VehicleFactory(name="Heli One"))
    vv = vv_submit(customer=customer, name="VV", program=TWO_TASKS, vvm=platform.vvm)
    platform.drain()
    return vv


def test_a_finished_vvs_track_passes_through_every_task_it_had_done(
    platform, ground_station, customer_a, user_a
) -> None:
    vv = _flown(platform, ground_station, customer_a)
    (shown,) = map_snapshot_for_user(user=user_a, vv_id=vv.pk)["vvs"]
    assert shown["status"] == "finished"
    done = [t for t in shown["tasks"] if t["status"] == "done"]
    assert len(done) == 2 and all(t["done_s"] >= t["requested_s"] for t in done)
    track = shown["track"]
    assert [t for t, _, _ in track] == sorted(t for t, _, _ in track)
    for task in done:
        nearest = min(
            distance_m(Position(lat, lng, 0), Position(task["lat"], task["lng"], 0))
            for _, lat, lng in track
        )
        assert nearest <= 2.0, f"task {task['q']} is {nearest:.1f} m off the track"
    moves = shown["migrations"]
    assert [m["from_kind"] + ">" + m["to_kind"] for m in moves] == ["gs>rv", "rv>gs"]
    assert all(m["from_pos"] and m["to_pos"] for m in moves)
    assert moves[0]["from_pos"] == [ground_station.lat, ground_station.lng]


def test_a_customer_sees_its_mission_without_vehicle_or_station_names(
    platform, ground_station, customer_a, user_a, client
) -> None:
    vv = _flown(platform, ground_station, customer_a)
    client.force_login(user_a)
    response = client.get(reverse("vv-map-history", args=[vv.pk]))
    assert response.status_code == 200
    body = response.json()
    assert [v["name"] for v in body["vvs"]] == ["VV"]
    assert "Heli One" not in response.text and ground_station.name not in response.text
    assert body["staff"] is False


def test_another_customers_mission_is_a_404(
    platform, ground_station, customer_a, user_b, client
) -> None:
    vv = _flown(platform, ground_station, customer_a)
    client.force_login(user_b)
    assert client.get(reverse("vv-map-history", args=[vv.pk])).status_code == 404


def test_a_snapshot_reads_every_vvs_latest_history_in_a_few_statements(
    customer_a, user_a, monkeypatch, django_assert_max_num_queries
) -> None:
    from missions import selectors
    from missions.models import Task, TrackPoint, VirtualVehicle

    monkeypatch.setattr(selectors, "MAP_TASKS_PER_VV", 2)
    monkeypatch.setattr(selectors, "MAP_TRACK_PER_VV", 3)
    vvs = [
        VirtualVehicle.objects.create(
            customer=customer_a,
            name=f"VV {k}",
            program="",
            status="running",
            submitted_s=k,
            seed=k,
            start_ms=0,
        )
        for k in range(12)
    ]
    for k, vv in enumerate(vvs):
        for q in range(k % 4):
            Task.objects.create(
                vv=vv, q=q, lat=48.0, lng=12.0, alt=10.0, tolerance_m=1, sensors=[], requested_s=q
            )
        for t in range(k % 5):
            TrackPoint.objects.create(vv=vv, t_s=float(t), lat=48.0 + k, lng=12.0, alt=10.0)
    # However many VVs: those running and those ended, each kind of history once, the areas
    # and the stations.
    with django_assert_max_num_queries(7):
        shown = selectors.map_snapshot_for_user(user=user_a)["vvs"]
    assert [v["name"] for v in shown] == [vv.name for vv in vvs]
    for k, v in enumerate(shown):
        # The latest ones, oldest first, and only this VV's.
        assert [t["q"] for t in v["tasks"]] == list(range(k % 4))[-2:]
        assert v["track"] == [[float(t), 48.0 + k, 12.0] for t in range(k % 5)][-3:]


def test_staff_get_any_customers_whole_mission_with_the_fleets_names(
    platform, ground_station, customer_a, staff, client
) -> None:
    """The staff map's "one VV with its whole history" (static/js/live_map.js)."""
    vv = _flown(platform, ground_station, customer_a)
    client.force_login(staff)
    response = client.get(reverse("vv-map-history", args=[vv.pk]))
    assert response.status_code == 200
    body = response.json()
    assert body["staff"] is True
    (shown,) = body["vvs"]
    assert (shown["vv"], shown["name"], shown["status"]) == (str(vv.pk), "VV", "finished")
    assert [t["status"] for t in shown["tasks"]] == ["done", "done"]
    assert [(m["from"], m["to"]) for m in shown["migrations"]] == [
        (ground_station.name, "Heli One"),
        ("Heli One", ground_station.name),
    ]
    assert len(shown["track"]) >= 2
