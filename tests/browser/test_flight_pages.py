"""A flight's page and an RV's logbook in the browser (issue 58): where it flew on the map
with a replay along its track, its altitude and battery over the flight, the tasks it served;
the logbook's totals and flights, each linked to its page."""

from __future__ import annotations

import datetime as dt

import pytest
from django.utils import timezone
from playwright.sync_api import expect

from fleet.models import Flight, FlightEnd
from missions.models import Task, TaskStatus, VirtualVehicle
from tests.browser.pages import log_in
from tests.browser.test_fleet_page import screenshot

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

# Take-off at the depot, out to two points over the field, home: (t_s, lat, lng, alt, battery).
TRACK = [
    [1000.0, 48.1135, 12.8600, 0.0, 97.0],
    [1004.0, 48.1135, 12.8600, 20.0, 96.5],
    [1060.0, 48.1111, 12.8619, 50.0, 92.0],
    [1110.0, 48.1102, 12.8655, 50.0, 88.5],
    [1180.0, 48.1135, 12.8600, 20.0, 84.0],
    [1186.0, 48.1135, 12.8600, 0.0, 83.5],
]


def test_a_flight_page_replays_the_flight_and_the_logbook_lists_it(page, traffic, world) -> None:
    started = timezone.now() - dt.timedelta(hours=1)
    vv = VirtualVehicle.objects.create(
        customer=world.customer_a, name="Survey", program="x", seed=1, start_ms=0, submitted_s=0.0
    )
    flight = Flight.objects.create(
        vehicle=world.heli,
        pilot_name="pia",
        started=started,
        started_s=1000.0,
        ended=started + dt.timedelta(seconds=186),
        ended_s=1186.0,
        ended_how=FlightEnd.LANDED_HOME,
        duration_s=186.0,
        distance_m=1220.0,
        max_alt_m=50.0,
        battery_start_pct=97.0,
        battery_end_pct=83.5,
        tasks_served=1,
        customers=[{"id": world.customer_a.pk, "name": "Customer A"}],
        vvs=[{"id": str(vv.pk), "name": "Survey"}],
        track=TRACK,
    )
    Task.objects.create(
        vv=vv, q=1, lat=48.1111, lng=12.8619, alt=50.0, tolerance_m=2.0, sensors=["CO2"],
        status=TaskStatus.DONE, vehicle=world.heli, requested_s=990.0, done_s=1060.0,
    )  # fmt: skip
    log_in(page, "operator", then=f"/admin/fleet/flight/{flight.pk}/change/")
    drawn = page.locator("#flight-map")
    expect(drawn).to_have_attribute("data-state", "ready")
    expect(drawn).to_have_attribute("data-points", str(len(TRACK)))
    expect(page.locator("#flight-altitude")).to_have_attribute("data-points", str(len(TRACK)))
    expect(page.locator("#flight-battery")).to_have_attribute("data-points", str(len(TRACK)))
    expect(page.locator(".cpcc-facts")).to_contain_text("pia")
    expect(page.locator(".cpcc-facts")).to_contain_text("3 min 06 s")
    expect(page.locator("#flight-tasks")).to_contain_text("Customer A")
    # The replay: the slider moves the marker along the track, the label says when and how high.
    slider = page.locator("#flight-replay input[type=range]")
    slider.fill("60")
    expect(page.locator("[data-replay-time]")).to_have_text("1:00 · 50.0 m")
    page.get_by_role("button", name="Play").click()  # on from there, until Pause
    expect(page.locator("[data-replay-time]")).not_to_have_text("1:00 · 50.0 m")
    page.get_by_role("button", name="Pause").click()
    slider.fill("186")
    expect(page.locator("[data-replay-time]")).to_have_text("3:06 · 0.0 m")
    screenshot(page, "flight-page")
    page.get_by_role("link", name="Heli One's logbook").click()
    expect(page.locator("#logbook-totals")).to_contain_text("0.05 h")  # 186 s
    expect(page.locator("#logbook-totals")).to_contain_text("1.22 km")
    screenshot(page, "vehicle-logbook")
    page.locator("#logbook-flights a").first.click()
    expect(page.locator("#flight-map")).to_have_attribute("data-state", "ready")
