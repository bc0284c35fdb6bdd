"""The maps show the world: every map's background comes from the platform itself (the
simulated world's tiles, nothing from the internet), the view holds the fleet and not a point
no vehicle may fly to, and the staff map shows the last 15 minutes, or one VV's whole history.

The screenshots of the customer's and the staff's map are left in the test's tmp_path
(``--basetemp`` to keep them somewhere known)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import Page, expect

from fleet.models import Vehicle
from missions.models import Task, TaskStatus, TrackPoint, VirtualVehicle, VVStatus
from tests.browser.conftest import World
from tests.browser.pages import FIELD, log_in
from tests.browser.traffic import Traffic
from vvm_worker.live import publish_vehicle

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

# A task no vehicle may fly to: about 100 km north-east of the field, outside every area.
FAR = (48.95, 13.70)
SOUTH, WEST = FIELD[0]
NORTH, EAST = FIELD[2]


def _vv(world: World, customer: Any, name: str, status: str, at_s: float) -> VirtualVehicle:
    return VirtualVehicle.objects.create(
        customer=customer,
        name=name,
        program="// on the map",
        status=status,
        submitted_s=at_s,
        seed=1,
        start_ms=0,
        host_rv=world.heli if status == VVStatus.RUNNING else None,
        host_gs=None if status == VVStatus.RUNNING else world.station,
    )


def _task(vv: VirtualVehicle, q: int, at: tuple[float, float], status: str, at_s: float) -> None:
    Task.objects.create(
        vv=vv,
        q=q,
        lat=at[0],
        lng=at[1],
        alt=40.0,
        tolerance_m=2,
        sensors=[],
        requested_s=at_s - 30.0,
        status=status,
        done_s=at_s if status == TaskStatus.DONE else None,
    )


@pytest.fixture
def flown(world: World, feed) -> dict[str, VirtualVehicle]:
    """Customer A's "Survey", aboard Heli One now: two tasks done in the last two minutes, one
    open, and one rejected far away. Customer B's "Old", which ended two hours ago."""
    now = time.time()
    survey = _vv(world, world.customer_a, "Survey", VVStatus.RUNNING, now - 300)
    for q, (at, status, t) in enumerate(
        [
            ((48.1100, 12.8610), TaskStatus.DONE, now - 120),
            ((48.1110, 12.8630), TaskStatus.DONE, now - 60),
            (FAR, TaskStatus.REJECTED, now - 50),
            ((48.1125, 12.8660), TaskStatus.OPEN, now),
        ]
    ):
        _task(survey, q, at, status, t)
    for t, lat, lng in [(now - 150, 48.1135, 12.8600), (now - 120, 48.11, 12.861)]:
        TrackPoint.objects.create(vv=survey, t_s=t, lat=lat, lng=lng, alt=40.0)
    TrackPoint.objects.create(vv=survey, t_s=now - 60, lat=48.111, lng=12.863, alt=40.0)

    old = _vv(world, world.customer_b, "Old", VVStatus.FINISHED, now - 8000)
    _task(old, 0, (48.1130, 12.8600), TaskStatus.DONE, now - 7300)
    _task(old, 1, (48.1095, 12.8670), TaskStatus.DONE, now - 7200)
    for t, lat, lng in [(now - 7400, 48.1135, 12.86), (now - 7300, 48.113, 12.86)]:
        TrackPoint.objects.create(vv=old, t_s=t, lat=lat, lng=lng, alt=40.0)
    TrackPoint.objects.create(vv=old, t_s=now - 7200, lat=48.1095, lng=12.867, alt=40.0)

    heli: Vehicle = world.heli
    publish_vehicle(
        {
            "id": heli.pk,
            "name": heli.name,
            "lat": 48.1113,
            "lng": 12.8640,
            "alt": 40.0,
            "phase": "cruise",
            "status": "active",
            "battery": 0.8,
            "vvs": [{"id": str(survey.pk), "name": "Survey", "customer": world.customer_a.pk}],
            "route": [[48.1113, 12.8640], [48.1125, 12.8660]],
            "t": time.time() + 60,  # still fresh when the page asks, however slow the machine
        },
        client=feed,
    )
    return {"survey": survey, "old": old}


def view_of(page: Page) -> dict[str, float]:
    return page.evaluate(
        """() => {
          const b = window.cpccMap.map.getBounds();
          return {south: b.getSouth(), west: b.getWest(), north: b.getNorth(), east: b.getEast()};
        }"""
    )


def wait_for_tiles(page: Page, selector: str) -> None:
    """Tiles have come, none is on its way (the next view change drops none) and every one has
    faded in."""
    page.wait_for_function(
        """(selector) => {
          const el = document.querySelector(selector);
          if (!el || !(Number(el.dataset.tilesLoaded) > 0) || el.dataset.tilesIdle === 'false') {
            return false;
          }
          return Array.from(el.querySelectorAll('img.leaflet-tile'))
            .every((img) => img.complete && getComputedStyle(img).opacity === '1');
        }""",
        arg=selector,
    )


def assert_tiles_from_the_platform(traffic: Traffic) -> None:
    tiles = [(status, url) for status, url in traffic.responses if "/tiles/" in url]
    assert tiles, "the map asked for tiles"
    assert all(status == 200 for status, _ in tiles), tiles
    # Anything from elsewhere, or failed, or refused by the page's policy: traffic's own check.


def test_a_customers_map_is_on_the_platforms_world_and_a_rejected_point_stays_out_of_view(
    page, traffic, flown, tmp_path: Path
) -> None:
    tiles: list[str] = []
    page.on("request", lambda r: tiles.append(r.url) if "/tiles/" in r.url else None)
    log_in(page, "customer-a", then="/map/")
    live = page.locator("#live-map")
    expect(live).to_have_attribute("data-connected", "true")
    expect(live).to_have_attribute("data-tasks-done", "2")
    expect(live).to_have_attribute("data-vehicles", "1")
    # The customer starts with the running VVs of the last hour; the rejected task is known to
    # the map and drawn where it is...
    assert page.locator("#map-window").input_value() == "3600"
    assert page.locator("#map-vv").input_value() == "running"
    expect(live).to_have_attribute("data-tasks-refused", "1")
    rejected = page.evaluate(
        """(id) => Object.values(window.cpccMap.vvs[id].tasks)
                     .filter((t) => t.status === 'rejected').map((t) => [t.lat, t.lng])""",
        str(flown["survey"].pk),
    )
    assert rejected == [list(FAR)]
    # ...and the view holds the operation area, not the ~100 km to it.
    view = view_of(page)
    assert view["south"] <= SOUTH and view["north"] >= NORTH
    assert view["west"] <= WEST and view["east"] >= EAST
    assert (view["north"] - view["south"]) * 111.0 < 3.0, f"the view spans {view}"
    assert not (view["south"] <= FAR[0] <= view["north"])

    wait_for_tiles(page, "#live-map")
    assert_tiles_from_the_platform(traffic)
    # At a fractional zoom Chromium left a hairline between some tiles (a faint thin
    # rectangle across every map): each tile is painted whole, with a transparent outline.
    assert (
        page.evaluate(
            "() => getComputedStyle(document.querySelector('img.leaflet-tile')).outlineStyle"
        )
        == "solid"
    )
    # Asked for in the view the map was fitted to only: none of the provisional world view.
    zoom = page.evaluate("() => window.cpccMap.tiles._tileZoom")
    assert tiles and all(f"/tiles/{zoom}/" in url for url in tiles), (zoom, tiles)
    page.screenshot(path=tmp_path / "customer-map.png")


def test_the_staff_map_shows_the_last_15_minutes_or_one_vvs_whole_history(
    page, traffic, flown, tmp_path: Path
) -> None:
    survey, old = str(flown["survey"].pk), str(flown["old"].pk)
    log_in(page, "operator", then="/map/")
    live = page.locator("#live-map")
    expect(live).to_have_attribute("data-connected", "true")
    expect(live).to_have_attribute("data-vvs", "2")
    # The last 15 minutes: Survey's two tasks done and its open one; Old's are two hours old.
    expect(live).to_have_attribute("data-window", "900")
    expect(live).to_have_attribute("data-tasks-done", "2")
    expect(live).to_have_attribute("data-tasks-open", "1")
    expect(live).to_have_attribute("data-vvs-shown", "1")
    wait_for_tiles(page, "#live-map")
    page.screenshot(path=tmp_path / "staff-map.png")

    # All the map holds, of the running VVs: Old has ended, so still Survey alone.
    choice = page.get_by_label("Virtual vehicles")
    assert choice.input_value() == "running"
    page.get_by_label("History").select_option(label="all the map holds")
    expect(live).to_have_attribute("data-vvs-shown", "1")
    # Every one: Old's path too, two hours old, drawn faint; Survey's of the last minutes not.
    choice.select_option(label="every one")
    expect(live).to_have_attribute("data-tasks-done", "4")
    expect(live).to_have_attribute("data-vvs-shown", "2")
    opacities = page.evaluate(
        "() => window.cpccMap.layers.carried.getLayers().map((l) => l.options.opacity)"
    )
    assert sorted(opacities) == [0.35, 1.0], opacities
    page.get_by_label("History").select_option(label="the last hour")
    expect(live).to_have_attribute("data-tasks-done", "2")

    # One VV: Old alone, its whole history fetched from the server, the map on it.
    expect(choice.locator(f'option[value="{old}"]')).to_have_text("Old (finished)")
    expect(choice.locator(f'option[value="{survey}"]')).to_have_text("Survey")
    choice.select_option(old)
    expect(live).to_have_attribute("data-history-of", old)
    expect(live).to_have_attribute("data-window", "")
    expect(live).to_have_attribute("data-vvs-shown", "1")
    expect(live).to_have_attribute("data-tasks-done", "2")
    expect(live).to_have_attribute("data-tasks-open", "0")
    expect(page.locator("#map-vv-status")).to_have_text("its whole history")
    assert page.evaluate("(id) => window.cpccMap.vvs[id].track.length", old) == 3, (
        "its path as the server keeps it"
    )
    view = view_of(page)
    assert view["south"] <= 48.1095 and view["north"] >= 48.1135
    assert view["west"] <= 12.86 and view["east"] >= 12.867

    # Every VV again (once the tiles of this view are in: a view that changes drops the tiles
    # still on their way).
    wait_for_tiles(page, "#live-map")
    choice.select_option("")
    expect(live).to_have_attribute("data-vvs-shown", "2")
    wait_for_tiles(page, "#live-map")
    assert_tiles_from_the_platform(traffic)


def test_every_map_has_the_platforms_background(page, traffic, flown) -> None:
    """The VV page's map, and the admin's: the area widget and the fleet overview."""
    log_in(page, "customer-a", then=f"/vvs/{flown['survey'].pk}/")
    expect(page.locator("#vv-map")).to_have_attribute("data-connected", "true")
    wait_for_tiles(page, "#vv-map")
    view = view_of(page)
    assert (view["north"] - view["south"]) * 111.0 < 3.0, f"the VV's map spans {view}"

    page.context.clear_cookies()
    log_in(page, "operator", then=f"/admin/fleet/vehicle/{flown['survey'].host_rv_id}/change/")
    wait_for_tiles(page, "[data-area-map]")
    page.goto("/admin/fleet/vehicle/overview/")
    wait_for_tiles(page, "#fleet-map")
    assert_tiles_from_the_platform(traffic)
