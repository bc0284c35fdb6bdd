"""A VV's picture calls (``VV.image.*``) are charged to its CPU quota with its steps: a loop of
them is stopped by the quota as a loop of code is. The pictures it makes count against its
storage quota, however many steps they are spread over."""

from __future__ import annotations

from missions.models import JournalEntry, LogEntry, Picture, VVStatus
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


RESIZES = """
var cam = VV.sensor.get('Camera 640x480');
var picture = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                               tolerance: 2, sensors: [cam]})[0];
var made = 0, refused = null;
while (refused === null) {
  try { VV.image.resize(picture, 64 + made, 48); made++; } catch (e) { refused = e.message; }
  VV.message.receive(0);  // each resize in a step of its own
}
VV.log('made ' + made + ': ' + refused);
VV.storage.store('big', 'x'.repeat(20000));
"""


def test_pictures_made_across_steps_fill_the_storage_quota(platform, ground_station, customer_a):
    platform.add_vehicle_loop(VehicleFactory(name="Heli One"))
    customer_a.storage_bytes = 40_000
    customer_a.save()
    vv = vv_submit(customer=customer_a, name="resizer", program=RESIZES, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    made = Picture.objects.filter(vv=vv, made=True)
    assert 2 <= made.count() < 40
    assert vv.picture_bytes == sum(made.values_list("bytes", flat=True))
    assert 40_000 - 10_000 < vv.picture_bytes <= 40_000
    (line,) = LogEntry.objects.filter(vv=vv, seq__isnull=False).values_list("message", flat=True)
    assert line.startswith(f"made {made.count()}: VV.image.resize(picture, width, height): ")
    assert line.endswith("more than the 40,000 allowed (quota: storage bytes)")
    # What its storage may hold is what the pictures leave.
    assert vv.status == VVStatus.KILLED
    assert vv.error.startswith(
        f'storing "big" would use 20005 bytes of storage and its pictures {vv.picture_bytes} '
        "more, more than the 40000 allowed (quota: storage bytes)"
    )
    assert vv.error_line == 11
