"""VV.task.executeAll: the platform picks the order and splits the batch across RVs by area."""

from __future__ import annotations

import pytest

from missions.models import Migration, TaskStatus, VVStatus
from tests.factories import AREA_TWO, VehicleFactory
from vvm_worker.services import vv_submit

# Alternating between Heli One's area (west of 12.864) and Heli Two's (east of it).
BATCH = """
var gps = VV.sensor.get('GPS');
var points = [[48.1111, 12.8619], [48.1111, 12.8667], [48.1115, 12.8625],
              [48.1115, 12.8660], [48.1119, 12.8631], [48.1119, 12.8655]];
var tasks = points.map(function (p) {
  return {type: 'point', position: new VV.types.LatLngAlt(p[0], p[1], 40), tolerance: 2, sensors: [gps]};
});
var order = [];
var all = VV.task.executeAll(tasks, function (data, index) {
  order.push(index);
  VV.storage.store('at-' + index, data[0].position);
});
VV.storage.store('order', order);
VV.storage.store('lngs', all.map(function (d) { return d[0].position.lng; }));
"""


@pytest.fixture
def two_rvs(platform, ground_station):
    one = VehicleFactory(name="Heli One")
    two = VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lng=12.8675)
    platform.add_vehicle_loop(one)
    platform.add_vehicle_loop(two)
    return one, two


def test_a_batch_is_split_by_area_and_the_vv_migrates_between_the_parts(
    platform, two_rvs, customer_a
) -> None:
    vv = vv_submit(customer=customer_a, name="batch", program=BATCH, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    order = vv.storage.get(key="order").value
    assert sorted(order) == [0, 1, 2, 3, 4, 5]
    # Heli One serves its three tasks first, then the VV moves once to Heli Two.
    assert set(order[:3]) == {0, 2, 4} and set(order[3:]) == {1, 3, 5}
    assert vv.storage.get(key="lngs").value == [12.8619, 12.8667, 12.8625, 12.866, 12.8631, 12.8655]
    served = {t.index: t.vehicle.name for t in vv.tasks.select_related("vehicle")}
    assert served == {
        0: "Heli One",
        1: "Heli Two",
        2: "Heli One",
        3: "Heli Two",
        4: "Heli One",
        5: "Heli Two",
    }
    moves = [(m.from_name, m.to_name) for m in Migration.objects.filter(vv=vv)]
    assert moves == [("GS Base", "Heli One"), ("Heli One", "Heli Two"), ("Heli Two", "GS Base")]


def test_a_batch_with_a_task_no_rv_can_serve_is_rejected_as_a_whole(
    platform, two_rvs, customer_a
) -> None:
    source = (
        BATCH.replace("[48.1119, 12.8655]]", "[48.1119, 12.8655], [49.0, 13.0]]")
        .replace("var all = VV.task.executeAll", "try { var all = VV.task.executeAll")
        .replace(
            "VV.storage.store('order', order);",
            "} catch (e) { VV.storage.store('rejected', [e.name, e.message]); }\nVV.storage.store('order', order);",
        )
        .replace("VV.storage.store('lngs'", "// VV.storage.store('lngs'")
    )
    vv = vv_submit(customer=customer_a, name="batch", program=source, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    name, message = vv.storage.get(key="rejected").value
    assert name == "TaskRejectedError"
    assert message.startswith("task 6 of the batch:") and "outside every operation area" in message
    assert vv.storage.get(key="order").value == []
    assert set(vv.tasks.values_list("status", flat=True)) == {TaskStatus.REJECTED}
