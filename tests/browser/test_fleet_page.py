"""Operators run the fleet from the browser (issue 26): the fleet overview follows the RVs live
over the map's socket (no Refresh), and an operator sends a flying RV home from it; the page
asks first, the RV flies home and lands (the page shows it as it happens), and the audit log
says who asked."""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest
from auditlog.models import LogEntry
from django.db import connections
from playwright.sync_api import Page, expect

from fleet.geo import Position, ground_distance_m
from fleet.models import Vehicle, VehicleStatus
from tests.browser.pages import log_in
from tests.conftest import PROGRAMS
from vvm_worker.platform import platform_vvm
from vvm_worker.services import vv_submit

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

VV1 = (PROGRAMS / "vv1-paper.js").read_text()
FLIGHT_MS = 90_000
MOVING = re.compile(r"^[1-9][0-9]*\.[0-9] m/s$")


def screenshot(page: Page, name: str, *, full_page: bool = True) -> None:
    """The page as a PNG in $CPCC_SCREENSHOTS (when set), for people to look at."""
    folder = os.environ.get("CPCC_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"{name}.png"), full_page=full_page)


def off_the_loop(work: Callable[[], Any]) -> Any:
    """Platform work (a VV's syntax check in V8) in a thread of its own: Playwright's asyncio
    loop runs in the test's thread."""

    def run() -> Any:
        try:
            return work()
        finally:
            connections.close_all()

    with ThreadPoolExecutor(max_workers=1) as pool:
        return pool.submit(run).result(timeout=60)


def test_an_operator_sends_a_flying_rv_home_from_the_live_fleet_page(
    page, traffic, world, workers
) -> None:
    workers.env["CPCC_SIM_SPEED"] = "3"  # flights long enough to watch
    workers.start("gsworker", "GS Base")
    workers.start("rvworker", "Heli One")
    off_the_loop(
        lambda: vv_submit(customer=world.customer_a, name="VV 1", program=VV1, vvm=platform_vvm())
    )
    log_in(page, "operator", then="/admin/fleet/vehicle/overview/")
    live = page.locator("#fleet-live")
    expect(live).to_have_attribute("data-live", "true")
    row = page.locator('#fleet-vehicles tr[data-vehicle="Heli One"]')
    actions = page.locator('#fleet-vehicles tr[data-actions-for="Heli One"]')
    cell = {name: row.locator(f'[data-cell="{name}"]') for name in (
        "doing", "next", "altitude", "speed", "battery", "link", "vvs", "lease")}  # fmt: skip

    # The page follows the RV as its worker reports, without being loaded again.
    page.evaluate("window.__sameDocument = true")
    expect(cell["doing"]).to_have_text("flying to a task · cruise", timeout=FLIGHT_MS)
    expect(cell["next"]).to_contain_text("VV 1, about")
    expect(cell["next"]).to_contain_text("48.111")
    expect(cell["vvs"]).to_have_attribute("data-vvs-aboard", "1")
    expect(cell["speed"]).to_have_text(MOVING)
    expect(cell["link"]).to_have_text("link simulated")
    expect(cell["battery"]).to_contain_text("n/a")
    expect(cell["battery"]).to_contain_text("simulated without a battery (no battery_s set)")
    expect(cell["lease"]).to_have_text("fresh, live")
    assert page.evaluate("window.__sameDocument") is True
    screenshot(page, "fleet-page-live")

    # Return home now: the page asks first; Cancel does nothing.
    actions.get_by_role("button", name="Return home now").click()
    dialog = page.locator("#fleet-confirm")
    expect(dialog).to_be_visible()
    expect(page.locator("#fleet-confirm-title")).to_have_text("Return home now: Heli One")
    expect(page.locator("#fleet-confirm-text")).to_contain_text("Send Heli One home now?")
    dialog.get_by_role("button", name="Cancel").click()
    expect(dialog).to_be_hidden()
    assert Vehicle.objects.get(name="Heli One").status == VehicleStatus.ACTIVE
    actions.get_by_role("button", name="Return home now").click()
    expect(dialog).to_be_visible()
    screenshot(page, "fleet-page-confirm", full_page=False)  # a dialog over the window
    with page.expect_navigation():
        dialog.get_by_role("button", name="Return home now").click()
    expect(page.locator(".messagelist .success")).to_have_text(
        "Heli One: return home now, sent to its worker"
    )
    expect(row).to_have_attribute("data-status", "maintenance")
    expect(row.locator("[data-status-reason]")).to_contain_text(
        "return home now: asked by operator on the fleet overview"
    )

    # It flies home and lands; the open page shows it as it happens.
    page.evaluate("window.__sameDocument = true")
    # (the same words whether the worker took it before the page was served or after)
    expect(row.locator("[data-command-state]")).to_have_text(
        re.compile(r"^taken by its worker \d\d:\d\d:\d\d$"), timeout=30_000
    )
    expect(cell["doing"]).to_contain_text("returning home", timeout=30_000)
    expect(cell["next"]).to_have_text("none")
    expect(cell["doing"]).to_have_text("landed", timeout=FLIGHT_MS)
    expect(cell["altitude"]).to_have_text("0 m")
    expect(cell["speed"]).to_have_text("0.0 m/s")
    expect(cell["vvs"]).to_have_attribute("data-vvs-aboard", "0")
    expect(actions.get_by_role("button", name="Maintenance")).to_be_disabled()
    expect(actions.get_by_role("button", name="Return to service")).to_be_enabled()
    assert page.evaluate("window.__sameDocument") is True, "updated without loading again"
    screenshot(page, "fleet-page-home")
    heli = Vehicle.objects.get(name="Heli One")
    assert heli.status == VehicleStatus.MAINTENANCE and heli.command_taken is not None
    assert heli.phase == "landed"
    assert ground_distance_m(Position(heli.lat, heli.lng, 0.0), heli.depot) < 1.0

    # The audit log says who asked: in the database and on its admin page.
    (entry,) = [
        e
        for e in LogEntry.objects.get_for_object(heli).filter(action=LogEntry.Action.UPDATE)
        if e.changes_dict.get("command") == ["", "return_home"]
    ]
    assert entry.actor is not None and entry.actor.username == "operator"
    page.goto(f"/admin/auditlog/logentry/{entry.pk}/change/")
    expect(page.locator("#content")).to_contain_text("operator")
    expect(page.locator("#content")).to_contain_text("return_home")
