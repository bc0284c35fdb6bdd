"""Planning before flying, in the program editor: the map of where the platform serves (no
vehicle named), a click on it that writes a point into the program, and a dry run that finds
the point no vehicle could serve, with its line, before anything flies (no worker runs)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from playwright.sync_api import Page, expect

from missions.models import Task, VirtualVehicle
from tests.browser.pages import log_in

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

START = "var co2 = VV.sensor.get('CO2');\nvar p = "
# After the point the map gives (line 2): one more in the field, then one 70 km away (line 5).
REST = (
    ";\nVV.task.execute({position: p, sensors: [co2]});\n"
    "VV.task.execute({position: new VV.types.LatLngAlt(48.112, 12.862, 30), sensors: [co2]});\n"
    "VV.task.execute({position: new VV.types.LatLngAlt(47.5, 11.9, 30), sensors: [co2]});\n"
)
DRY_RUN_MS = 90_000  # a process of its own on a busy machine; the copy itself takes a second


def screenshot(page: Page, name: str) -> None:
    folder = os.environ.get("CPCC_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"{name}.png"), full_page=True)


def click_on_map(page: Page, lat: float, lng: float) -> None:
    x, y = page.evaluate(
        "([lat, lng]) => { const p = window.cpccServiceMap.map.latLngToContainerPoint([lat, lng]);"
        " return [p.x, p.y]; }",
        [lat, lng],
    )
    page.locator("#service-map").click(position={"x": x, "y": y})


def test_a_customer_plans_on_the_map_and_a_dry_run_finds_the_point_out_of_reach(
    world, page: Page, traffic
) -> None:
    log_in(page, "customer-a", then="/vvs/new/")
    service_map = page.locator("#service-map")
    expect(service_map).to_have_attribute("data-state", "ready")
    # Heli One's area, 0-120 m, as one band; no name of a vehicle anywhere on the page.
    expect(service_map).to_have_attribute("data-bands", "1")
    assert "Heli One" not in page.content()
    # How to click is said once, under the map; the status line says what is where.
    expect(page.get_by_text("Click the map")).to_have_count(1)
    expect(page.locator("#service-map-status")).to_have_text(
        "Point at the map to see the altitudes served there."
    )
    # The view holds the service area.
    assert page.evaluate(
        "() => window.cpccServiceMap.map.getBounds().contains([[48.109, 12.859], [48.114, 12.868]])"
    )

    page.get_by_label("Name").fill("plan")
    page.locator(".CodeMirror").click()
    page.keyboard.insert_text(START)
    click_on_map(page, 48.1115, 12.8635)
    program = page.evaluate("window.cpccEditor.getValue()")
    match = re.fullmatch(
        r"var co2 = VV\.sensor\.get\('CO2'\);\nvar p = "
        r"new VV\.types\.LatLngAlt\((48\.11\d+), (12\.86\d+), 30\)",
        program,
    )
    assert match, program
    assert abs(float(match[1]) - 48.1115) < 1e-4 and abs(float(match[2]) - 12.8635) < 1e-4
    expect(page.locator("#service-map-status")).to_contain_text("Served here at 0–120 m")
    # The editor kept the cursor after the point: typing goes on there.
    page.keyboard.insert_text(REST)
    assert page.evaluate("window.cpccEditor.getValue()") == program + REST

    form = page.locator("#editor-form")
    page.get_by_role("button", name="Dry run").click()
    expect(form).to_have_attribute("data-dry-run", "done", timeout=DRY_RUN_MS)
    report = page.locator("#dry-run")
    expect(report.locator("#dry-run-summary")).to_contain_text(
        "3 tasks, 1 that no vehicle in service could serve"
    )
    # What its duration assumes, in words under it.
    expect(report.locator("#dry-run-assumes")).to_contain_text("each vehicle starts where it is")
    rows = report.locator("#dry-run-tasks tr")
    expect(rows).to_have_count(3)
    expect(report.locator("#dry-run-tasks tr.unservable")).to_have_count(1)
    unservable = report.locator("#dry-run-verdicts li.bad").first
    expect(unservable).to_contain_text("outside every operation area")
    column = (program + REST).splitlines()[4].index("execute") + 1
    link = unservable.get_by_role("button", name=f"line 5:{column}")
    expect(service_map).to_have_attribute("data-tasks", "3")
    screenshot(page, "editor-dry-run")
    # A click on the line shows it in the program, with the cursor there.
    link.click()
    assert (
        page.evaluate("window.cpccEditor.getCursor()")
        == {
            "line": 4,
            "ch": column - 1,
            "sticky": None,
        }
        or page.evaluate("window.cpccEditor.getCursor().line") == 4
    )
    expect(page.locator(".CodeMirror .cm-dry-run-line")).to_have_count(1)
    # Nothing was submitted, nothing flew.
    assert not VirtualVehicle.objects.exists() and not Task.objects.exists()
