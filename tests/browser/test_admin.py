"""The provider's admin in the browser: an operation area drawn on the vehicle's map and saved,
an RV put into maintenance with the admin action, the fleet overview showing both."""

from __future__ import annotations

import json

import pytest
from playwright.sync_api import Page, expect

from fleet.models import Vehicle, VehicleStatus
from tests.browser.pages import log_in
from tests.factories import AREA_TWO, VehicleFactory

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

# A triangle inside the field, away from its border, the depot and the ground station (the
# widget snaps corners within 15 px of them).
TRIANGLE = [[48.1100, 12.8605], [48.1102, 12.8665], [48.1128, 12.8630]]
TOLERANCE = 5e-5  # degrees, about 5 m: a few pixels at the widget's zoom


def draw_polygon(page: Page, points: list[list[float]]) -> None:
    """With the widget's polygon tool: a click on each corner, then on the first to close."""
    widget = page.locator("[data-area-map]")
    expect(widget).to_have_attribute("data-state", "ready")
    widget.scroll_into_view_if_needed()
    page.get_by_title("Draw Polygons").click()
    box = widget.bounding_box()
    assert box is not None
    pixels = page.evaluate(
        """([id, points]) => points.map((p) => {
             const at = window.CPCCAreaWidgets[id].map.latLngToContainerPoint(p);
             return [at.x, at.y];
           })""",
        [widget.get_attribute("data-input"), points],
    )
    for x, y in pixels:
        page.mouse.click(box["x"] + x, box["y"] + y)
    page.get_by_role("button", name="Finish").click()


def assert_ring(ring: list[list[float]], points: list[list[float]]) -> None:
    assert ring[0] == ring[-1], "a closed ring"
    assert len(ring) == len(points) + 1
    for got, want in zip(ring, points, strict=False):
        assert got[0] == pytest.approx(want[0], abs=TOLERANCE), (ring, points)
        assert got[1] == pytest.approx(want[1], abs=TOLERANCE), (ring, points)


def test_an_admin_draws_an_operation_area_and_saves_it(page, traffic, world) -> None:
    log_in(page, "operator", then="/admin/")
    page.get_by_role("link", name="Vehicles", exact=True).first.click()
    page.get_by_role("link", name="Heli One", exact=True).click()
    widget = page.locator("[data-area-map]")
    expect(widget).to_have_attribute("data-points", "4")  # the field, as loaded

    draw_polygon(page, TRIANGLE)
    expect(widget).to_have_attribute("data-points", "3")
    expect(widget).to_have_attribute("data-valid", "true")
    assert_ring(json.loads(page.locator("textarea[name=area]").input_value()), TRIANGLE)

    page.get_by_role("button", name="Save", exact=True).click()
    expect(page.locator(".messagelist .success")).to_contain_text("Heli One")
    assert_ring(Vehicle.objects.get(name="Heli One").area, TRIANGLE)

    # Drawn again from what was saved.
    page.locator("#result_list").get_by_role("link", name="Heli One", exact=True).click()
    expect(widget).to_have_attribute("data-points", "3")
    expect(widget).to_have_attribute("data-valid", "true")


def test_an_admin_puts_an_rv_into_maintenance_and_the_fleet_overview_shows_it(
    page, traffic, world
) -> None:
    VehicleFactory(name="Heli Two", area=AREA_TWO, depot_lng=12.866)
    log_in(page, "operator", then="/admin/fleet/vehicle/")
    page.locator("tr", has=page.get_by_role("link", name="Heli One", exact=True)).locator(
        "input[name=_selected_action]"
    ).check()
    page.locator("select[name=action]").select_option("put_into_maintenance")
    page.get_by_role("button", name="Go").click()
    expect(page.locator(".messagelist .success")).to_have_text("Heli One: in maintenance")
    assert Vehicle.objects.get(name="Heli One").status == VehicleStatus.MAINTENANCE
    assert Vehicle.objects.get(name="Heli Two").status == VehicleStatus.ACTIVE

    page.get_by_role("link", name="Fleet overview").click()
    fleet_map = page.locator("#fleet-map")
    expect(fleet_map).to_have_attribute("data-state", "ready")
    expect(fleet_map).to_have_attribute("data-vehicles", "2")
    expect(fleet_map).to_have_attribute("data-stations", "1")
    rows = page.locator("#fleet-vehicles tr[data-vehicle]")
    expect(rows).to_have_count(2)
    expect(page.locator('tr[data-vehicle="Heli One"]')).to_have_attribute(
        "data-status", "maintenance"
    )
    expect(page.locator('tr[data-vehicle="Heli Two"]')).to_have_attribute("data-status", "active")
    expect(page.locator('tr[data-vehicle="Heli One"]')).to_contain_text("In maintenance")
