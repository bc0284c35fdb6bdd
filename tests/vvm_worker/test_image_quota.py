"""A VV's picture calls (``VV.image.*``) are charged to its CPU quota with its steps: a loop of
them is stopped by the quota as a loop of code is."""

from __future__ import annotations

from missions.models import JournalEntry, VVStatus
from tests.factories import VehicleFactory
from vvm_worker.services import vv_submit

LOOP = """
var cam = VV.sensor.get('Camera 640x480');
var picture = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                               tolerance: 2, sensors: [cam]})[0];
var looks = 0;
while (true) {
  VV.image.stats(picture, {x: 0, y: 0, width: 640, height: 240});
  looks++;
}
"""


def test_a_loop_of_image_calls_is_stopped_by_the_cpu_quota(platform, ground_station, customer_a):
    platform.add_vehicle_loop(VehicleFactory(name="Heli One"))
    customer_a.cpu_ms_per_step = 300
    customer_a.save()
    vv = vv_submit(customer=customer_a, name="looker", program=LOOP, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.KILLED
    assert "quota: CPU time per step" in vv.error and "VV.image" in vv.error
    assert vv.error_line == 7  # the call that went over
    # It looked several times before (each answer in its journal), a bounded number of times.
    looks = sum(
        1
        for e in JournalEntry.objects.filter(vv=vv).values_list("entry", flat=True)
        if e["k"] == "ret"
    )
    assert 2 <= looks < 1000
