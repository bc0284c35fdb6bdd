"""Names written as HTML stay text on every page that shows them: a VV, a customer, a vehicle
and a ground station named with markup (a picture whose error runs a script, a link off the
platform) are shown as those characters, on the maps (tooltips, the vehicles' labels, popups)
as in the pages around them; nothing of them becomes an element, and the pages' Content
Security Policy (no inline script, no inline style) is never breached (tests/browser/traffic.py
reports every breach, console error and request outside the platform).

With CPCC_SCREENSHOTS set to a folder, the tests leave screenshots there: the program editor,
the staff's map, the customer's map, the dashboard, the VV's page and the fleet overview."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from playwright.sync_api import Dialog, Page, expect

from accounts.models import Customer
from fleet.models import Vehicle
from missions.models import VirtualVehicle, VVStatus
from tests.browser.pages import log_in
from tests.browser.traffic import Traffic
from tests.conftest import PROGRAMS
from tests.factories import AREA_TWO, GroundStationFactory, VehicleFactory
from tests.live import Workers
from tests.polling import wait_until

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

HOSTILE = '<img src=x onerror=alert(1)><a href="//evil.example">link</a>'
CUSTOMER = '<a href="//evil.example" class="x">Customer A</a>'
VEHICLE = '<img src=x onerror=alert(2)><a href="//evil.example">RV</a>'
STATION = '<a href="//evil.example">GS</a><img src=x>'
LOG_LINE = '<img src=x onerror=alert(3)><a href="//evil.example">log</a>'
KEY = '<a href="//evil.example">key</a>'
# What any of them would become as HTML.
INJECTED = 'img[src="x"], a[href="//evil.example"]'
# VV 1 of the paper, which also logs a line and stores a value under names written as HTML.
PROGRAM = (
    f"VV.log('{LOG_LINE}');\nVV.storage.store('{KEY}', 'x');\n"
    + (PROGRAMS / "vv1-paper.js").read_text()
)
FLIGHT_MS = 90_000

# Every tooltip of a Leaflet map opened (as the pointer would), every popup opened in turn: what
# each shows as text, and whether any holds an element made of a name.
OPEN_EVERYTHING = """(map) => {
  const shown = [];
  const look = (overlay, kind) => {
    const el = overlay.getElement();
    if (!el) return;
    shown.push({kind, text: el.textContent,
                injected: el.querySelectorAll('img[src="x"], a[href="//evil.example"]').length});
  };
  map.eachLayer((layer) => {
    const tooltip = layer.getTooltip && layer.getTooltip();
    if (tooltip) {
      if (!layer.isTooltipOpen()) layer.openTooltip();
      look(tooltip, 'tooltip');
    }
  });
  map.eachLayer((layer) => {
    const popup = layer.getPopup && layer.getPopup();
    if (popup) {
      layer.openPopup();
      look(popup, 'popup');
      layer.closePopup();
    }
  });
  return shown;
}"""


def screenshot(page: Page, name: str) -> None:
    folder = os.environ.get("CPCC_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"{name}.png"), full_page=True)


def no_alerts(page: Page) -> list[str]:
    """The page's dialogs (an injected script's alert), each dismissed."""
    dialogs: list[str] = []

    def dialog(d: Dialog) -> None:
        dialogs.append(f"{d.type}: {d.message}")
        d.dismiss()

    page.on("dialog", dialog)
    return dialogs


def assert_text_only(page: Page, *watches: Traffic, dialogs: list[str] | None = None) -> None:
    """Nothing made of a name is an element, no dialog opened, and the browser has reported no
    problem so far (CSP breach, console error, failed request)."""
    assert page.locator(INJECTED).count() == 0, page.locator(INJECTED).evaluate_all(
        "els => els.map((e) => e.outerHTML)"
    )
    assert not dialogs, dialogs
    page.wait_for_timeout(50)  # the browser's reports on their way
    for watch in watches:
        assert not watch.problems, "\n".join(watch.problems)


def open_everything(page: Page, map_expression: str = "window.cpccMap.map") -> list[dict]:
    shown = page.evaluate(f"() => ({OPEN_EVERYTHING})({map_expression})")
    assert not [s for s in shown if s["injected"]], shown
    return shown


def texts(shown: list[dict], kind: str = "tooltip") -> list[str]:
    return [s["text"] for s in shown if s["kind"] == kind]


def submit(page: Page, name: str, program: str) -> str:
    """From the program editor, a new VV; its id, from its row on the dashboard."""
    page.get_by_role("navigation", name="Main").get_by_role("link", name="New VV").click()
    page.get_by_label("Name").fill(name)
    page.locator(".CodeMirror").click()
    page.keyboard.insert_text(program)
    screenshot(page, "editor")
    page.get_by_role("button", name="Submit").click()
    # Submitting one VV opens its page; then on to the dashboard, where its row is.
    page.wait_for_url(re.compile(r"/vvs/[0-9a-f-]{36}/$"))
    expect(page.locator(".messages")).to_contain_text(f"“{name}” is submitted.")
    vv_id = page.url.rstrip("/").rsplit("/", 1)[1]
    page.get_by_role("navigation", name="Main").get_by_role("link", name="Dashboard").click()
    row = page.locator("tr[data-vv]", has=page.get_by_role("link", name=name, exact=True))
    assert row.get_attribute("data-vv") == vv_id
    return vv_id


@pytest.mark.slow
def test_a_vv_named_with_markup_is_text_on_every_map_and_page(
    page, traffic, new_page, world, workers: Workers
) -> None:
    Customer.objects.filter(pk=world.customer_a.pk).update(name=CUSTOMER)
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    staff, staff_traffic = new_page()
    staff_dialogs = no_alerts(staff)
    log_in(staff, "operator", then="/map/")
    dialogs = no_alerts(page)
    log_in(page, "customer-a")
    expect(page.locator(".lead")).to_contain_text(f"{CUSTOMER}: what your programs are doing")
    vv_id = submit(page, HOSTILE, PROGRAM)
    dashboard = page

    # The customer's map and the VV's page, live, next to the dashboard.
    customer_map = page.context.new_page()
    map_dialogs = no_alerts(customer_map)
    customer_map.goto("/map/")
    vv_page = page.context.new_page()
    vv_dialogs = no_alerts(vv_page)
    vv_page.goto(f"/vvs/{vv_id}/")
    expect(vv_page.locator("h1")).to_contain_text(HOSTILE)

    # The vehicle's always-visible label, with the VV aboard: on the staff's map by the
    # vehicle's name, on the customer's maps anonymous.
    labels = {
        staff: f"Heli One · {HOSTILE}",
        customer_map: f"vehicle · {HOSTILE}",
        vv_page: f"vehicle · {HOSTILE}",
    }
    for shown_on, label in labels.items():
        expect(shown_on.locator(".leaflet-tooltip.vehicle-label")).to_have_text(
            label, timeout=FLIGHT_MS
        )
    screenshot(staff, "staff-map")
    screenshot(customer_map, "customer-map")
    staff_tips = texts(open_everything(staff))
    for shown_on in (customer_map, vv_page):
        tips = texts(open_everything(shown_on))
        assert f"vehicle · {HOSTILE}" in tips
        assert any(tip.startswith(f"{HOSTILE}: task ") for tip in tips), tips
    assert f"Heli One · {HOSTILE}" in staff_tips
    assert any(tip.startswith(f"{HOSTILE}: task ") for tip in staff_tips), staff_tips
    assert_text_only(staff, staff_traffic, dialogs=staff_dialogs)
    assert_text_only(customer_map, traffic, dialogs=map_dialogs)
    assert_text_only(vv_page, traffic, dialogs=vv_dialogs)

    wait_until(
        lambda: VirtualVehicle.objects.get(pk=vv_id).status == VVStatus.FINISHED,
        timeout=FLIGHT_MS / 1000,
        what="the VV to finish",
        details=workers.logs,
    )
    # The dashboard followed by itself (its rows fetched again): the name as text.
    row = dashboard.locator(f'tr[data-vv="{vv_id}"]')
    expect(row).to_have_attribute("data-status", "finished", timeout=30_000)
    expect(row.locator("td.name a")).to_have_text(HOSTILE)
    screenshot(dashboard, "dashboard")
    assert_text_only(dashboard, traffic, dialogs=dialogs)

    # The VV's page once it has ended: its mission replayed on its map, its log and storage.
    vv_page.goto(f"/vvs/{vv_id}/")
    expect(vv_page.locator("#vv-map")).to_have_attribute("data-tasks-done", "4")
    screenshot(vv_page, "vv-page")
    tips = texts(open_everything(vv_page))
    assert len([tip for tip in tips if tip.startswith(f"{HOSTILE}: task ")]) == 4, tips
    assert all(tip.endswith(" (done)") for tip in tips if tip.startswith(f"{HOSTILE}: task ")), tips
    assert HOSTILE in tips  # the green line of its path
    expect(vv_page.locator("h1")).to_contain_text(HOSTILE)
    expect(vv_page.locator("#log")).to_contain_text(LOG_LINE)
    expect(vv_page.locator("#storage td.key", has_text=KEY)).to_have_text(KEY)
    assert_text_only(vv_page, traffic, dialogs=vv_dialogs)

    # Staff: the customer's name on the VV's page and the dashboard, the tasks on the map.
    staff.goto(f"/vvs/{vv_id}/")
    expect(staff.locator(".lead")).to_contain_text(CUSTOMER)
    expect(staff.locator("#vv-map")).to_have_attribute("data-tasks-done", "4")
    assert f"{HOSTILE}: task " in " ".join(texts(open_everything(staff)))
    staff.goto("/")
    staff_row = staff.locator(f'tr[data-vv="{vv_id}"]')
    expect(staff_row.locator("td.name a")).to_have_text(HOSTILE)
    expect(staff_row.locator('td[data-label="Customer"]')).to_have_text(CUSTOMER)
    assert_text_only(staff, staff_traffic, dialogs=staff_dialogs)


def test_vehicles_and_stations_named_with_markup_are_text_on_the_staff_pages(
    page, traffic, world
) -> None:
    VehicleFactory(name=VEHICLE, area=AREA_TWO, depot_lng=12.866)
    GroundStationFactory(name=STATION, lat=48.1095, lng=12.8675)
    # Batteries at 75 % and 10 % (the overview's bars: green, red below 20 %).
    Vehicle.objects.filter(name="Heli One").update(battery_s=100, flight_s=25)
    Vehicle.objects.filter(name=VEHICLE).update(battery_s=100, flight_s=90)
    dialogs = no_alerts(page)
    log_in(page, "operator", then="/map/")

    # The live map: the areas by their vehicles' names, the ground stations.
    expect(page.locator("#live-map")).to_have_attribute("data-connected", "true")
    page.wait_for_function("() => window.cpccMap.layers.stations.getLayers().length === 2")
    tips = texts(open_everything(page))
    assert f"{VEHICLE} (active)" in tips and f"Ground station {STATION}" in tips, tips
    assert_text_only(page, traffic, dialogs=dialogs)

    # The fleet overview: every vehicle's label and popup, the station's label, the tables.
    page.goto("/admin/fleet/vehicle/overview/")
    fleet_map = page.locator("#fleet-map")
    expect(fleet_map).to_have_attribute("data-state", "ready")
    expect(fleet_map).to_have_attribute("data-vehicles", "2")
    expect(page.locator(".cpcc-map-label", has_text="VVs")).to_have_count(2)
    screenshot(page, "fleet-overview")
    shown = open_everything(page, "window.CPCCFleetMap")
    labels = texts(shown)
    assert f"{VEHICLE} · 0 VVs" in labels and STATION in labels, labels
    assert f"{VEHICLE} (active)" in labels, labels  # its area
    assert any(p.startswith(VEHICLE) for p in texts(shown, "popup")), shown
    expect(page.locator("#fleet-vehicles th[scope=row]", has_text="<img")).to_have_text(VEHICLE)
    expect(page.locator("#fleet-ground-stations th[scope=row]", has_text="<a")).to_have_text(
        STATION
    )
    assert_text_only(page, traffic, dialogs=dialogs)
    # The batteries' bars, drawn by the stylesheet (no inline style).
    for name, charge in (("Heli One", "75"), (VEHICLE, "10")):
        row = page.locator("#fleet-vehicles tr[data-vehicle]").filter(
            has=page.get_by_role("link", name=name, exact=True)
        )
        expect(row.locator("meter.cpcc-battery")).to_have_attribute("value", charge)
        expect(row).to_contain_text(f"{charge} %")

    # Heli One's area widget: the other vehicle's area and the stations around it.
    page.goto("/admin/fleet/vehicle/")
    page.get_by_role("link", name="Heli One", exact=True).click()
    widget = page.locator("[data-area-map]")
    expect(widget).to_have_attribute("data-state", "ready")
    map_of = f"window.CPCCAreaWidgets[{widget.get_attribute('data-input')!r}].map"
    tips = texts(open_everything(page, map_of))
    assert f"{VEHICLE} (active)" in tips and STATION in tips and "depot" in tips, tips
    assert_text_only(page, traffic, dialogs=dialogs)
