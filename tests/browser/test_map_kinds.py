"""Every map draws each vehicle with its kind's symbol (issue 28): a copter, a rover, a boat and
a submarine, whose label says its depth. The staff's live map names them; a customer's map shows
the carrier of its VV anonymous, but as what it is; the fleet overview draws them too and says
each RV's kind in its table.

The staff's map is left in /tmp/map_kinds.png for people to look at."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import Page, expect

from fleet.kinds import AERIAL, GROUND, SURFACE, UNDERWATER
from fleet.models import Vehicle
from missions.models import VirtualVehicle, VVStatus
from tests.browser.conftest import World
from tests.browser.pages import FIELD, log_in
from tests.factories import VehicleFactory
from vvm_worker.live import publish_vehicle

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

SCREENSHOT = Path("/tmp/map_kinds.png")
# Where each vehicle is on the paper's field, and how high (the sub 5 m under the surface).
AT = {
    "Heli One": (48.1128, 12.8605, 40.0),
    "Rover": (48.1100, 12.8610, 0.0),
    "Boat": (48.1122, 12.8650, 0.0),
    "Sub": (48.1106, 12.8660, -5.0),
}
KINDS = {"Heli One": AERIAL, "Rover": GROUND, "Boat": SURFACE, "Sub": UNDERWATER}


def _state(vehicle: Vehicle, vvs: list[VirtualVehicle]) -> dict[str, Any]:
    """What the vehicle's worker says of it (vvm_worker/hosts.py, HostedRV.beacon)."""
    lat, lng, alt = AT[vehicle.name]
    return {
        "id": vehicle.pk,
        "name": vehicle.name,
        "kind": vehicle.kind,
        "lat": lat,
        "lng": lng,
        "alt": alt,
        "phase": "cruise",
        "status": "active",
        "battery": 0.8,
        "vvs": [{"id": str(vv.pk), "name": vv.name, "customer": vv.customer_id} for vv in vvs],
        "route": [[lat, lng]],
        "t": time.time() + 60,  # still fresh when the page asks, however slow the machine
    }


@pytest.fixture
def fleet(world: World, feed) -> dict[str, Vehicle]:
    """Heli One (aerial) and a rover, a boat and a sub on the field, each where its worker
    says; Customer A's "Dive" aboard the sub."""
    vehicles = {
        "Heli One": world.heli,
        "Rover": VehicleFactory(
            name="Rover", kind=GROUND, area=FIELD, min_altitude_m=0, max_altitude_m=0
        ),
        "Boat": VehicleFactory(
            name="Boat", kind=SURFACE, area=FIELD, min_altitude_m=0, max_altitude_m=0
        ),
        "Sub": VehicleFactory(
            name="Sub", kind=UNDERWATER, area=FIELD, min_altitude_m=-30, max_altitude_m=0
        ),
    }
    dive = VirtualVehicle.objects.create(
        customer=world.customer_a,
        name="Dive",
        program="// under the lake",
        status=VVStatus.RUNNING,
        submitted_s=time.time() - 60,
        seed=1,
        start_ms=0,
        host_rv=vehicles["Sub"],
    )
    for name, vehicle in vehicles.items():
        publish_vehicle(_state(vehicle, [dive] if name == "Sub" else []), client=feed)
    return vehicles


def drawn(page: Page, *, fleet_page: bool = False) -> dict[str, dict[str, Any]]:
    """The vehicles' markers on the live map (or the fleet overview's), by the text of their
    label: the symbol each is drawn with (its kind) and where."""
    return page.evaluate(
        """(fleetPage) => {
          const markers = fleetPage ? window.CPCCFleetPage.map.markers
            : window.cpccMap.vehicleMarkers;
          const shown = {};
          Object.values(markers).forEach((m) => {
            const at = m.getLatLng();
            const label = m.getTooltip().getContent().textContent;
            shown[label] = {kind: m.options.kind, at: [at.lat, at.lng]};
          });
          return shown;
        }""",
        fleet_page,
    )


def test_the_staff_map_draws_each_vehicle_with_its_kinds_symbol(page, traffic, fleet) -> None:
    log_in(page, "operator", then="/map/")
    live = page.locator("#live-map")
    expect(live).to_have_attribute("data-connected", "true")
    expect(live).to_have_attribute("data-vehicles", "4")
    expect(live).to_have_attribute("data-vehicle-kinds", "aerial:1,ground:1,surface:1,underwater:1")
    shown = drawn(page)
    # Each by its name, the sub with its depth and the VV aboard.
    assert {label: s["kind"] for label, s in shown.items()} == {
        "Heli One": AERIAL,
        "Rover": GROUND,
        "Boat": SURFACE,
        "Sub · -5 m · Dive": UNDERWATER,
    }
    assert shown["Rover"]["at"] == list(AT["Rover"][:2])
    labels = page.locator(".leaflet-tooltip.vehicle-label")
    expect(labels).to_have_count(4)
    expect(labels.filter(has_text="Sub")).to_have_text("Sub · -5 m · Dive")
    # Zoomed in on the vehicles, for whoever looks at the picture.
    page.evaluate(
        """(points) => window.cpccMap.map.fitBounds(points, {padding: [60, 60], animate: false})""",
        [list(at[:2]) for at in AT.values()],
    )
    page.wait_for_function(
        """() => {
          const el = document.getElementById('live-map');
          return el.dataset.tilesIdle === 'true' && Array.from(el.querySelectorAll('img.leaflet-tile'))
            .every((img) => img.complete && getComputedStyle(img).opacity === '1');
        }"""
    )
    page.screenshot(path=SCREENSHOT)


def test_a_customer_sees_its_carrier_as_what_it_is_and_nothing_of_the_others(
    page, traffic, fleet
) -> None:
    log_in(page, "customer-a", then="/map/")
    live = page.locator("#live-map")
    expect(live).to_have_attribute("data-connected", "true")
    expect(live).to_have_attribute("data-vehicles", "1")
    expect(live).to_have_attribute("data-vehicle-kinds", "underwater:1")
    shown = drawn(page)
    assert {label: s["kind"] for label, s in shown.items()} == {"vehicle · -5 m · Dive": UNDERWATER}


def test_the_fleet_overview_draws_and_lists_each_rvs_kind(page, traffic, fleet) -> None:
    log_in(page, "operator", then="/admin/fleet/vehicle/overview/")
    element = page.locator("[data-fleet-map]")
    expect(element).to_have_attribute("data-state", "ready")
    expect(element).to_have_attribute(
        "data-vehicle-kinds", "aerial:1,ground:1,surface:1,underwater:1"
    )
    for name, kind in KINDS.items():
        cell = page.locator(f'#fleet-vehicles tr[data-vehicle="{name}"] [data-cell="kind"]')
        expect(cell).to_have_attribute("data-kind", kind)
        expect(cell).to_have_text(Vehicle.objects.get(name=name).get_kind_display())
    # Once the workers' reports are in, the sub's label says how deep it is.
    expect(page.locator("#fleet-live")).to_have_attribute("data-live", "true")
    shown = drawn(page, fleet_page=True)
    assert {label: s["kind"] for label, s in shown.items()} == {
        "Heli One · 0 VVs": AERIAL,
        "Rover · 0 VVs": GROUND,
        "Boat · 0 VVs": SURFACE,
        "Sub · -5 m · 1 VV": UNDERWATER,
    }
