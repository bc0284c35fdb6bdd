"""What the browser tests do on the platform's pages: log in, read the live map's state (the
attributes of #live-map and ``window.cpccMap``, static/js/map.js)."""

from __future__ import annotations

from typing import Any

from playwright.sync_api import Page

PASSWORD = "secret-pass-123"  # tests/factories.py's UserFactory
# The paper's field (Figures 2 and 3, both areas): Heli One can serve every point of VV 1.
FIELD = [[48.109, 12.859], [48.109, 12.868], [48.114, 12.868], [48.114, 12.859], [48.109, 12.859]]


def log_in(page: Page, username: str, password: str = PASSWORD, *, then: str = "/") -> None:
    """Through the real login form (/accounts/login/), then on to ``then``."""
    page.goto(f"/accounts/login/?next={then}")
    page.locator("input[name=username]").fill(username)
    page.locator("input[name=password]").fill(password)
    with page.expect_navigation():
        page.locator("main form [type=submit]").first.click()
    assert "/accounts/login/" not in page.url, f"{username} could not log in"


def map_state(page: Page) -> dict[str, Any]:
    """What the live map shows: its data- attributes, and the vehicles as drawn (each marker's
    position next to the state it was drawn from)."""
    return page.evaluate(
        """() => {
          const map = window.cpccMap;
          const vehicles = Object.values(map.vehicles).map((v) => {
            const marker = map.vehicleMarkers[v.id];
            const at = marker ? marker.getLatLng() : null;
            return {...v, marker: at ? [at.lat, at.lng] : null};
          });
          const vvs = Object.values(map.vvs).map((vv) => vv.name);
          return {...document.getElementById('live-map').dataset, vehicles, vvNames: vvs};
        }"""
    )
