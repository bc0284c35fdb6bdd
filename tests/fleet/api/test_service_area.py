"""GET /api/v1/service-area/: where the platform can serve, for customers, naming no vehicle."""

from __future__ import annotations

from shapely.geometry import Polygon, shape
from shapely.ops import unary_union

from fleet.models import NoFlyZone, VehicleStatus
from tests.factories import AREA_ONE, AREA_TWO, VehicleFactory

NORTH = [[48.115, 12.859], [48.115, 12.864], [48.12, 12.864], [48.12, 12.859], [48.115, 12.859]]
FAR = [[47.0, 11.0], [47.0, 11.01], [47.01, 11.01], [47.01, 11.0], [47.0, 11.0]]


def _polygon(area: list[list[float]]) -> Polygon:
    return Polygon([(lng, lat) for lat, lng in area])


def test_the_service_area_is_the_vehicles_in_service_by_altitude(api_a, api_b) -> None:
    VehicleFactory(name="Heli One", area=AREA_ONE, min_altitude_m=0, max_altitude_m=120)
    VehicleFactory(name="Heli Two", area=AREA_TWO, min_altitude_m=20, max_altitude_m=60)
    # Recharging comes back by itself: in service. Maintenance and removed: not.
    VehicleFactory(name="Heli North", area=NORTH, status=VehicleStatus.CHARGING)
    VehicleFactory(name="Heli Resting", area=FAR, status=VehicleStatus.MAINTENANCE)
    VehicleFactory(name="Heli Gone", area=FAR, status=VehicleStatus.REMOVED)
    NoFlyZone.objects.create(
        name="Airfield",
        area=[[48.11, 12.86], [48.11, 12.861], [48.111, 12.861], [48.11, 12.86]],
        max_altitude_m=50,
    )
    response = api_a.get("/api/v1/service-area/")
    assert response.status_code == 200, response.content
    text = response.content.decode()
    assert "Heli" not in text and "Airfield" not in text, "no vehicle or zone is named"
    collection = response.json()
    assert collection["type"] == "FeatureCollection"
    bands = {
        (f["properties"]["min_altitude_m"], f["properties"]["max_altitude_m"]): shape(f["geometry"])
        for f in collection["features"]
        if f["properties"]["kind"] == "service"
    }
    one, two, north = _polygon(AREA_ONE), _polygon(AREA_TWO), _polygon(NORTH)
    assert list(bands) == [(0.0, 20.0), (20.0, 60.0), (60.0, 120.0)]
    assert bands[(0.0, 20.0)].equals(unary_union([one, north]))
    assert bands[(20.0, 60.0)].equals(unary_union([one, two, north]))
    assert bands[(60.0, 120.0)].equals(unary_union([one, north]))
    (zone,) = [f for f in collection["features"] if f["properties"]["kind"] == "no_fly"]
    assert zone["properties"] == {"kind": "no_fly", "min_altitude_m": 0.0, "max_altitude_m": 50.0}
    # Every customer sees the same service area.
    assert api_b.get("/api/v1/service-area/").json() == collection


def test_the_service_area_needs_a_login(client) -> None:
    assert client.get("/api/v1/service-area/").status_code in (401, 403)
