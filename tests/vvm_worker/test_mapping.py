"""The vehicle mapper's rules (pure: no database)."""

from __future__ import annotations

from shapely.geometry import Polygon

from fleet.geo import Position
from vvm_worker.mapping import VehicleCaps, map_task
from vvm_worker.planning import TravelTime
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


def test_where_areas_overlap_the_rv_that_serves_the_task_soonest_gets_it() -> None:
    point = task(48.1111, 12.8619, 50.0)
    here = Position(48.1111, 12.8619, 50.0)
    # "Passing" is 37 m away with two stops to make, the first 7 m from the task: it serves
    # the task on the way, a second late for the stop after. "Idle" is 155 m away.
    passing = caps(
        "Passing",
        ONE,
        position=Position(48.1111, 12.8624, 50.0),
        open_tasks=2,
        route=(Position(48.1111, 12.8620, 50.0), Position(48.1130, 12.8600, 50.0)),
    )
    idle = caps("Idle", ONE, position=Position(48.1125, 12.8619, 50.0))
    assert passing.cost_s(point) < idle.cost_s(point)
    assert [v.name for v in map_task(point, [idle, passing]).candidates] == ["Passing", "Idle"]
    # Its route known, the cost is the task's own wait plus the delay of the stop after it.
    to_task = TravelTime(10.0, 3.0)(passing.position, here)
    assert to_task <= passing.cost_s(point) < to_task + 3.0
    # Ranked by distance plus 30 s per queued task, as the mapper once did, Idle would win.
    blind = caps("Passing", ONE, position=passing.position, open_tasks=2)
    assert blind.cost_s(point) > idle.cost_s(point)
