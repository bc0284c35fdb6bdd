"""Messages between VVs on the distributed platform (worker processes of their own, tests/live.py,
a real Redis, instant flights): two VVs on RVs in different cells, each RV its own worker
process, exchange ten messages each way; with each RV worker SIGKILLed in the middle of the
exchange, every message is still received exactly once, in order."""

from __future__ import annotations

import pytest

from missions.models import ENDED_STATUSES, Message, VirtualVehicle, VVStatus
from tests.factories import (
    AREA_ONE,
    AREA_TWO,
    CustomerFactory,
    GroundStationFactory,
    VehicleFactory,
)
from tests.live import Workers
from tests.polling import wait_until
from tests.vvm_worker.test_distributed_faults import workers  # noqa: F401 - instant flights
from tests.vvm_worker.test_messages import ROUNDS, exchange
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_submit

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]


def both_ended(vvs: list[VirtualVehicle]) -> bool:
    ids = [vv.pk for vv in vvs]
    return VirtualVehicle.objects.filter(pk__in=ids, status__in=ENDED_STATUSES).count() == len(ids)


def received(vvs: list[VirtualVehicle]) -> int:
    return Message.objects.filter(recipient__in=vvs, received_s__isnull=False).count()


def start_exchange(pool: Workers) -> list[VirtualVehicle]:
    GroundStationFactory(name="GS Base")
    VehicleFactory(name="Heli One", area=AREA_ONE)
    VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lng=12.8675)
    customer = CustomerFactory(name="Customer A")
    vvm = platform_vvm()
    vvs = [
        vv_submit(
            customer=customer,
            name="west",
            program=exchange(peer="east", lat=48.1111, lng=12.8610),
            vvm=vvm,
        ),
        vv_submit(
            customer=customer,
            name="east",
            program=exchange(peer="west", lat=48.1116, lng=12.8667),
            vvm=vvm,
        ),
    ]
    pool.start("gsworker", "GS Base")
    pool.start("rvworker", "Heli One")
    pool.start("rvworker", "Heli Two")
    return vvs


def assert_exchanged(vvs: list[VirtualVehicle]) -> None:
    for vv, peer in zip(vvs, ("east", "west"), strict=True):
        vv.refresh_from_db()
        assert vv.status == VVStatus.FINISHED, vv.error
        assert vv.storage.get(key="got").value == [[peer, i, 36] for i in range(ROUNDS)]
        assert Message.objects.filter(sender=vv).count() == ROUNDS  # each sent once
        assert not Message.objects.filter(recipient=vv, received_s__isnull=True).exists()
        assert {t.vehicle.name for t in vv.tasks.all()} == {
            "west": {"Heli One"},
            "east": {"Heli Two"},
        }[vv.name]


def test_two_vvs_in_different_cells_exchange_ten_messages_each_way(
    workers,  # noqa: F811 - the fixture
) -> None:
    vvs = start_exchange(workers)
    wait_until(lambda: both_ended(vvs), timeout=120, what="both VVs to end", details=workers.logs)
    assert_exchanged(vvs)


def test_with_each_rv_worker_killed_mid_exchange_every_message_is_received_once_in_order(
    workers,  # noqa: F811 - the fixture
) -> None:
    vvs = start_exchange(workers)
    for name, after in (("Heli One", 4), ("Heli Two", 10)):
        wait_until(
            lambda after=after: received(vvs) >= after,
            timeout=60,
            what=f"{after} messages received",
            details=workers.logs,
        )
        assert not both_ended(vvs), "the exchange ended before the kill"
        workers.kill(name)
        workers.start("rvworker", name)
    wait_until(lambda: both_ended(vvs), timeout=180, what="both VVs to end", details=workers.logs)
    assert_exchanged(vvs)
