"""The vehicle mapper's rules (pure: no database)."""

from __future__ import annotations

from shapely.geometry import Polygon

from fleet.geo import Position
from vvm_worker.mapping import VehicleCaps, map_task
from vvm_worker.runtime import TaskRequest

ONE = Polygon([(12.859, 48.109), (12.864, 48.109), (12.864, 48.114), (12.859, 48.114)])
TWO = Polygon([(12.864, 48.109), (12.868, 48.109), (12.868, 48.114), (12.864, 48.114)])
SENSORS = frozenset({"CO2", "Thermometer", "GPS"})
# One id per vehicle name, numbered in the order the names first appear: distinct, and the same
# whatever PYTHONHASHSEED is.
IDS: dict[str, int] = {}


def caps(name: str, area: Polygon, **kw) -> VehicleCaps:
    base = {
        "id": IDS.setdefault(name, len(IDS) + 1),
        "name": name,
        "area": area,
        "min_altitude_m": 0.0,
        "max_altitude_m": 120.0,
        "sensors": SENSORS,
        "active": True,
        "position": Position(48.1135, 12.86, 0),
        "max_speed_mps": 10.0,
    }
    base.update(kw)
    return VehicleCaps(**base)


def task(lat=48.1111, lng=12.8619, alt=50.0, sensors=("CO2",)) -> TaskRequest:
    return TaskRequest(lat, lng, alt, 2.0, tuple(sensors))


def test_the_rv_whose_area_holds_the_point_serves_it() -> None:
    one, two = caps("Heli One", ONE), caps("Heli Two", TWO)
    assert [v.name for v in map_task(task(lng=12.8619), [one, two]).candidates] == ["Heli One"]
    assert [v.name for v in map_task(task(lng=12.8667), [one, two]).candidates] == ["Heli Two"]


def test_a_point_outside_every_area_is_rejected_with_a_reason() -> None:
    decision = map_task(task(lat=48.2), [caps("Heli One", ONE)])
    assert decision.rejected
    assert decision.reason is not None and "outside every operation area" in decision.reason


def test_an_altitude_above_every_ceiling_is_rejected() -> None:
    decision = map_task(task(alt=300), [caps("Heli One", ONE)])
    assert decision.rejected
    assert decision.reason is not None and "0 to 120 m" in decision.reason


def test_a_sensor_no_rv_carries_is_rejected_naming_it() -> None:
    decision = map_task(task(sensors=("CO2", "NOx")), [caps("Heli One", ONE)])
    assert decision.reason is not None and "'NOx'" in decision.reason


def test_sensors_must_all_be_on_one_rv() -> None:
    a = caps("A", ONE, sensors=frozenset({"CO2"}))
    b = caps("B", ONE, sensors=frozenset({"NOx"}))
    decision = map_task(task(sensors=("CO2", "NOx")), [a, b])
    assert decision.reason is not None and "all of" in decision.reason


def test_only_rvs_in_maintenance_could_serve_it_so_the_vv_parks() -> None:
    decision = map_task(task(), [caps("Heli One", ONE, active=False)])
    assert decision.parked and not decision.rejected and decision.candidates == ()


def test_candidates_are_ranked_by_time_to_get_there_and_queue() -> None:
    near = caps("Near", ONE, position=Position(48.1111, 12.8619, 50))
    far = caps("Far", ONE, position=Position(48.1135, 12.86, 0))
    busy = caps("Busy", ONE, position=Position(48.1111, 12.8619, 50), open_tasks=20)
    assert [v.name for v in map_task(task(), [far, busy, near]).candidates] == [
        "Near",
        "Far",
        "Busy",
    ]
