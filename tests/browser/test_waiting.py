"""A VV's page says what the VV waits for, in the customer's words, and follows it while the
page stays open: parked while its only RV is in maintenance, on its way once the RV is back."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest
from django.db import connections
from playwright.sync_api import expect

from fleet.models import VehicleStatus
from fleet.simulation import SensorField
from tests.browser.pages import log_in
from vvm_worker.clock import SystemClock
from vvm_worker.services import VVM, vehicle_set_status, vv_advance, vv_submit

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

PROGRAM = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                 tolerance: 2, sensors: [co2]});
"""
NO_VEHICLE = (
    "no vehicle in service covers the next task at 48.111100, 12.861900, 50 m; "
    "it continues when one does"
)


class Told:
    """A dispatcher that tells no worker: the test itself does what a host would."""

    def vv_arrived(self, vv_id: Any, *, on: Any = None) -> None:
        pass

    def vv_wake_later(self, vv_id: Any, delay_s: float) -> None:
        pass

    def vehicle_changed(self, vehicle_id: int) -> None:
        pass

    def customer_slot_freed(self, customer_id: int) -> None:
        pass


def off_the_loop(work: Callable[[], Any]) -> Any:
    """Run platform work (VV steps in V8) in a thread of its own: Playwright's asyncio loop
    runs in the test's thread."""

    def run() -> Any:
        try:
            return work()
        finally:
            connections.close_all()

    with ThreadPoolExecutor(max_workers=1) as pool:
        return pool.submit(run).result(timeout=60)


def test_the_vv_page_says_why_it_waits_and_follows_it_when_it_goes_on(page, traffic, world) -> None:
    vvm = VVM(clock=SystemClock(), dispatcher=Told(), field=SensorField(0))

    def park() -> Any:
        vehicle_set_status(vehicle=world.heli, status=VehicleStatus.MAINTENANCE, vvm=vvm)
        vv = vv_submit(customer=world.customer_a, name="Waits", program=PROGRAM, vvm=vvm)
        vv_advance(vv_id=vv.pk, vvm=vvm)  # the ground station's step: its task, then parked
        return vv

    vv = off_the_loop(park)
    log_in(page, "customer-a", then=f"/vvs/{vv.pk}/")
    waiting = page.locator("#vv-waiting")
    expect(waiting).to_be_visible()
    expect(waiting).to_have_attribute("data-reason", "no_vehicle")
    expect(waiting).to_have_text(f"Waiting: {NO_VEHICLE}")
    expect(page.locator("#log")).to_contain_text(f"waiting: {NO_VEHICLE}")
    assert "Heli One" not in page.content()

    def back_in_service() -> None:
        vehicle_set_status(vehicle=world.heli, status=VehicleStatus.ACTIVE, vvm=vvm)
        vv_advance(vv_id=vv.pk, vvm=vvm)  # routed again: it moves to Heli One

    off_the_loop(back_in_service)
    # The open page reads it again by itself (static/js/vv.js).
    expect(waiting).to_have_attribute("data-reason", "flying", timeout=20_000)
    expect(waiting).to_have_text("On its way: flying to your task")
