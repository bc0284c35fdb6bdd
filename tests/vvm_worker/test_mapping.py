"""The vehicle mapper's rules (pure: no database)."""

from __future__ import annotations

from shapely.geometry import Polygon

from fleet.geo import Position
from vvm_worker.mapping import Reserve, VehicleCaps, map_task
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


BULK, PREMIUM = 7, 8  # service class ids


def test_a_class_giving_way_leaves_half_the_rvs_free_unless_the_others_would_be_late() -> None:
    # Four RVs over one area, all equally near the task; two carry bulk work (Flood A, B),
    # one carries premium work, one is idle. Bulk gives way: its task goes to the RVs outside
    # the reserve (the two with the fewest bulk tasks: Idle and Premium's), the nearest first.
    here = Position(48.1111, 12.8619, 50.0)
    near = Position(48.1111, 12.8622, 50.0)
    flood_a = caps(
        "Flood A", ONE, position=near, open_tasks=2, route=(here, here), task_classes=(BULK, BULK)
    )
    flood_b = caps(
        "Flood B",
        ONE,
        position=Position(48.1100, 12.8600, 50.0),
        open_tasks=1,
        route=(here,),
        task_classes=(BULK,),
    )
    serving = caps(
        "Serving", ONE, position=here, open_tasks=1, route=(here,), task_classes=(PREMIUM,)
    )
    idle = caps("Idle", ONE, position=here)
    fleet = [flood_a, flood_b, serving, idle]
    reserve = Reserve(frozenset({BULK, None}))
    assert reserve.kept(fleet) == {serving.id, idle.id}

    def ranked(service_class, due_in_s=None, give_way=reserve):
        decision = map_task(
            task(here.lat, here.lng, here.alt),
            fleet,
            due_in_s=due_in_s,
            service_class=service_class,
            reserve=give_way,
        )
        return [v.name for v in decision.candidates]

    # Without the reserve an RV on the spot is the cheapest; bulk's task passes it by.
    by_cost = sorted(fleet, key=lambda v: (v.cost_s(task(here.lat, here.lng, here.alt)), v.name))
    assert by_cost[0].id in reserve.kept(fleet)
    assert ranked(BULK, give_way=Reserve(frozenset()))[0] == by_cost[0].name
    kept_back = [v.name for v in by_cost if v.id in reserve.kept(fleet)]
    others = [v.name for v in by_cost if v.id not in reserve.kept(fleet)]
    assert ranked(BULK) == others + kept_back
    # A customer without a class gives way too; premium (not giving way) takes the cheapest.
    assert ranked(None) == others + kept_back
    assert ranked(PREMIUM)[0] == by_cost[0].name
    # Giving way never makes a class late: where only the reserve reaches the task in time,
    # it goes there (Flood A and B have tasks to fly first: 1 s is too little for them).
    assert ranked(BULK, due_in_s=1.0)[:2] == ["Idle", "Serving"]


def test_one_rv_that_can_serve_the_task_is_never_kept_back() -> None:
    only = caps("Only", ONE, task_classes=())
    other_area = caps("Elsewhere", TWO)
    reserve = Reserve(frozenset({BULK}))
    assert reserve.kept([only]) == frozenset()
    decision = map_task(task(), [only, other_area], service_class=BULK, reserve=reserve)
    assert [v.name for v in decision.candidates] == ["Only"]
